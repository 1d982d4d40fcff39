"""Strict readers of the file formats users hand the twin: PLY points and meshes, STL, OBJ.

Each reader refuses a file whose structure disagrees with itself (a count that does not match
the body, a non-finite coordinate, a face that references a missing vertex) before any
processing can drop or repair what is wrong, naming the file and the element or line.
"""

from twin.formats.mesh_files import check_obj, check_stl
from twin.formats.meshes import MESH_EXTENSIONS, MeshArrays, read_mesh
from twin.formats.ply import PlyData, read_ply

__all__ = ["MESH_EXTENSIONS", "MeshArrays", "PlyData", "check_obj", "check_stl", "read_mesh", "read_ply"]
