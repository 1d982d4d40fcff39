"""Loading a user's workpiece mesh file (STL, OBJ or PLY) in metres or millimetres."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import trimesh

from twin.errors import TwinError
from twin.formats import check_obj, check_stl, read_ply

__all__ = ["MESH_EXTENSIONS", "load_mesh"]

MESH_EXTENSIONS: tuple[str, ...] = (".stl", ".obj", ".ply")
"""File extensions accepted by :func:`load_mesh` (case-insensitive)."""

#: A workpiece in a cell lies within this distance of its file's origin [m].
MAX_COORDINATE_M = 100.0
#: A face is degenerate below this area, relative to the squared size of the model.
AREA_TOL_REL = 1e-12


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
        TwinError: bad units, unsupported extension, missing or unreadable file, a file whose
            structure disagrees with itself (:mod:`twin.formats`: counts, non-finite
            coordinates, faces referencing missing vertices), or a model no workpiece can be
            (no face with an area, coordinates beyond ``MAX_COORDINATE_M``).
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
        raw = p.read_bytes()
    except OSError as exc:
        raise TwinError(f"cannot read mesh file {str(p)!r}: {exc.strerror}") from None
    if ext == ".ply":
        data = read_ply(p)
        if data.faces is None:
            raise TwinError(f"mesh file {str(p)!r} has no faces")
        vertices, faces = data.vertices, data.faces
    else:
        (check_stl if ext == ".stl" else check_obj)(p, raw)
        vertices, faces = _parse(p, raw, ext)
    if units == "mm":
        vertices = vertices * 1e-3
    _check_model(p, vertices, faces)
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=True)


def _parse(p: Path, raw: bytes, ext: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of a checked STL or OBJ file, as stored (nothing dropped or merged)."""
    try:
        loaded = trimesh.load(io.BytesIO(raw), file_type=ext[1:], process=False)
    except Exception as exc:  # noqa: BLE001 - any parser failure is an unreadable file
        raise TwinError(f"could not read mesh file {str(p)!r}: {_one_line(exc)}") from None
    if isinstance(loaded, trimesh.Scene):
        geometries = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if not geometries:
            raise TwinError(f"mesh file {str(p)!r} has no faces")
        # Trimesh parts concatenate into one Trimesh.
        loaded = trimesh.util.concatenate(geometries) if len(geometries) > 1 else geometries[0]
    if not isinstance(loaded, trimesh.Trimesh):
        raise TwinError(f"mesh file {str(p)!r} has no faces (it holds a {type(loaded).__name__})")
    return np.asarray(loaded.vertices, dtype=np.float64), np.asarray(loaded.faces, dtype=np.int64)


def _check_model(p: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Refuse a model no workpiece can be: no faces, non-finite or absurd coordinates, no area."""
    if len(faces) == 0:
        raise TwinError(f"mesh file {str(p)!r} has no faces")
    if not np.all(np.isfinite(vertices)):
        raise TwinError(f"mesh file {str(p)!r} has non-finite vertex coordinates")
    reach = float(np.max(np.abs(vertices)))
    if reach > MAX_COORDINATE_M:
        raise TwinError(f"bad model {str(p)!r}: coordinates reach {reach:.3g} m, more than {MAX_COORDINATE_M:g} m "
                        "from the origin: not a workpiece in a cell (wrong --units?)")
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    size = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    if not size > 0 or not np.any(area > AREA_TOL_REL * size**2):
        raise TwinError(f"bad model {str(p)!r}: none of its {len(faces)} faces has a non-zero area")
