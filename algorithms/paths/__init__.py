"""Process paths from scan lines (document 004): point clouds, splines, normals, tool frames."""
