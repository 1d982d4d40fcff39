"""Geometry: SE(3) poses, DH kinematics, the exact mesh index (closest points, normals, ray casts)."""
