"""Loading a user's workpiece mesh file (STL, OBJ or PLY) or STEP part in metres, as a trimesh."""

from __future__ import annotations

from pathlib import Path

import trimesh

from twin.formats.meshes import MESH_EXTENSIONS, read_mesh

__all__ = ["MESH_EXTENSIONS", "load_mesh"]


def load_mesh(path: str | Path, units: str) -> trimesh.Trimesh:
    """Load a user's workpiece mesh (STL, OBJ or PLY) or STEP part and convert it to metres.

    A file holding several bodies (an OBJ with several objects, a scene) is concatenated
    into one mesh. The mesh is returned as stored (vertices merged, no repair); callers that
    need a closed solid check ``is_watertight``. The arrays alone, without importing trimesh:
    :func:`twin.formats.meshes.read_mesh`.

    Args:
        path: file path; the extension (case-insensitive) must be one of
            :data:`MESH_EXTENSIONS`.
        units: length unit of the file's coordinates, "m" or "mm".

    Returns:
        Mesh with vertices in metres, in the file's own frame.

    Raises:
        TwinError: as :func:`twin.formats.meshes.read_mesh`.
    """
    vertices, faces = read_mesh(path, units)
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
