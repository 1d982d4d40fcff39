"""Loading a user's workpiece mesh file (STL, OBJ or PLY) in metres or millimetres."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from twin.errors import TwinError

__all__ = ["MESH_EXTENSIONS", "load_mesh"]

MESH_EXTENSIONS: tuple[str, ...] = (".stl", ".obj", ".ply")
"""File extensions accepted by :func:`load_mesh` (case-insensitive)."""


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def load_mesh(path: str | Path, units: str) -> trimesh.Trimesh:
    """Load a user's workpiece mesh (STL, OBJ or PLY) and convert it to metres.

    A file holding several bodies (an OBJ with several objects, a scene) is concatenated
    into one mesh. The mesh is returned as stored (vertices merged, no repair); callers that
    need a closed solid check ``is_watertight``.

    Args:
        path: file path; the extension (case-insensitive) must be one of
            :data:`MESH_EXTENSIONS`.
        units: length unit of the file's coordinates, "m" or "mm".

    Returns:
        Mesh with vertices in metres, in the file's own frame.

    Raises:
        TwinError: bad units, unsupported extension, missing or unreadable file, or a file
            that holds no triangles.
    """
    if units not in ("m", "mm"):
        raise TwinError(f"units must be 'm' or 'mm', got {units!r}")
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in MESH_EXTENSIONS:
        raise TwinError(
            f"unsupported mesh file extension {p.suffix or '(none)'!r} for {str(p)!r}; "
            f"allowed: {', '.join(MESH_EXTENSIONS)}"
        )
    if not p.exists():
        raise TwinError(f"mesh file not found: {str(p)!r}")
    if not p.is_file():
        raise TwinError(f"mesh path is not a file: {str(p)!r}")
    try:
        loaded = trimesh.load(str(p), file_type=ext[1:], process=True)
    except Exception as exc:  # noqa: BLE001 - any parser failure is an unreadable file
        raise TwinError(f"could not read mesh file {str(p)!r}: {_one_line(exc)}") from exc
    if isinstance(loaded, trimesh.Scene):
        geometries = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if not geometries:
            raise TwinError(f"mesh file {str(p)!r} has no faces")
        mesh = trimesh.util.concatenate(geometries) if len(geometries) > 1 else geometries[0]
    elif isinstance(loaded, trimesh.Trimesh):
        mesh = loaded
    else:
        raise TwinError(
            f"mesh file {str(p)!r} has no faces (it holds a {type(loaded).__name__})"
        )
    if len(mesh.faces) == 0:
        raise TwinError(f"mesh file {str(p)!r} has no faces")
    if not np.all(np.isfinite(mesh.vertices)):
        raise TwinError(f"mesh file {str(p)!r} has non-finite vertex coordinates")
    if units == "mm":
        mesh.apply_scale(1e-3)
    return mesh
