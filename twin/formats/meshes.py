"""A user's workpiece mesh file (STL, OBJ or PLY) or STEP part read into checked arrays, in metres.

STL and triangle PLY files are read here with numpy; OBJ files (and PLY polygons of more than
three corners) go through trimesh's parsers. Whatever the format, the result is the one
``trimesh.Trimesh(vertices, faces, process=True)`` would hold: vertices closer than 1e-8 m in
every coordinate merged (trimesh's ``tol.merge``), the first of each group kept, in the order
of first use, unreferenced vertices dropped. A STEP part is meshed by :mod:`twin.formats.step`
(units from the file, a stated chordal tolerance). Reading an STL this way keeps trimesh (and the
half second its import takes) out of the commands that only need the arrays, ``twin localize``
among them (``benchmarks/results_startup.md``).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from twin.errors import TwinError
from twin.formats.mesh_files import check_obj, check_stl
from twin.formats.ply import read_ply

__all__ = ["MESH_EXTENSIONS", "MeshArrays", "merge_vertices", "read_mesh"]

MESH_EXTENSIONS: tuple[str, ...] = (".stl", ".obj", ".ply", ".step", ".stp")
"""File extensions accepted by :func:`read_mesh` (case-insensitive)."""

#: A workpiece in a cell lies within this distance of its file's origin [m].
MAX_COORDINATE_M = 100.0
#: A face is degenerate below this area, relative to the squared size of the model.
AREA_TOL_REL = 1e-12
#: Vertices are merged when equal after rounding to this many decimals [m] (trimesh's tol.merge).
MERGE_DIGITS = 8

_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


class MeshArrays(NamedTuple):
    """A triangle mesh as arrays: what :class:`algorithms.geometry.mesh_index.MeshIndex` takes."""

    vertices: np.ndarray  # (V, 3) float64 [m]
    faces: np.ndarray  # (F, 3) int64 vertex indices


def read_mesh(path: str | Path, units: str) -> MeshArrays:
    """Read a user's workpiece mesh (STL, OBJ or PLY) or STEP part, convert it to metres and merge
    vertices.

    A file holding several bodies (an OBJ with several objects) is concatenated into one mesh;
    nothing is repaired.

    Args:
        path: file path; the extension (case-insensitive) must be one of :data:`MESH_EXTENSIONS`.
        units: length unit of the file's coordinates, "m" or "mm" (a STEP file states its own
            units, which are used instead).

    Raises:
        TwinError: bad units, unsupported extension, missing or unreadable file, a file whose
            structure disagrees with itself (counts, non-finite coordinates, faces referencing
            missing vertices), or a model no workpiece can be (no face with an area,
            coordinates beyond ``MAX_COORDINATE_M``).
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
    if ext in (".step", ".stp"):
        from twin.formats.step import read_step

        vertices, faces = read_step(p)
        units = "m"
    elif ext == ".ply":
        data = read_ply(p)
        if data.faces is None:
            raise TwinError(f"mesh file {str(p)!r} has no faces")
        vertices, faces = data.vertices, data.faces
        if faces.shape[1] != 3:
            vertices, faces = _with_trimesh(p, vertices, faces)
    elif ext == ".stl":
        check_stl(p, raw)
        vertices, faces = _stl_arrays(raw)
    else:
        check_obj(p, raw)
        vertices, faces = _obj_arrays(p, raw)
    if units == "mm":
        vertices = vertices * 1e-3
    _check_model(p, vertices, faces)
    return MeshArrays(*merge_vertices(vertices, faces))


def merge_vertices(vertices: np.ndarray, faces: np.ndarray,
                   digits: int = MERGE_DIGITS) -> tuple[np.ndarray, np.ndarray]:
    """The referenced vertices with equal rounded coordinates merged into the first of each
    group, in the order of first use (trimesh's ``merge_vertices``), and the faces renumbered."""
    referenced = np.zeros(len(vertices), dtype=bool)
    referenced[faces] = True
    used = np.flatnonzero(referenced)
    keys = np.round(vertices[used] * 10.0**digits).astype(np.int64)
    order = np.lexsort(keys.T[::-1])  # rows sorted, equal rows in file order (lexsort is stable)
    sorted_keys = keys[order]
    starts = np.ones(len(order), dtype=bool)
    starts[1:] = np.any(sorted_keys[1:] != sorted_keys[:-1], axis=1)
    first = order[starts]  # each group's first vertex
    group = np.empty(len(order), dtype=np.int64)
    group[order] = np.cumsum(starts) - 1
    by_first_use = np.argsort(first, kind="stable")
    rank = np.empty_like(by_first_use)
    rank[by_first_use] = np.arange(len(by_first_use))
    renumber = np.full(len(vertices), -1, dtype=np.int64)
    renumber[used] = rank[group]
    return vertices[used[first[by_first_use]]], renumber[faces]


def _stl_arrays(raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (three per triangle, as stored) and faces of a checked binary or ASCII STL."""
    n = int.from_bytes(raw[80:84], "little") if len(raw) >= 84 else -1
    if len(raw) == 84 + 50 * n:  # binary: check_stl decides the same way
        corners = np.frombuffer(raw, dtype=_STL_RECORD, count=n, offset=84)["corners"]
    else:
        words = (line.split() for line in raw.decode("ascii").splitlines())
        corners = np.array([w[1:4] for w in words if w and w[0].lower() == "vertex"], dtype=np.float64)
    vertices = np.asarray(corners, dtype=np.float64).reshape(-1, 3)
    return vertices, np.arange(len(vertices), dtype=np.int64).reshape(-1, 3)


def _obj_arrays(p: Path, raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of a checked OBJ file through trimesh's parser, its bodies concatenated."""
    import io

    import trimesh

    try:
        loaded = trimesh.load(io.BytesIO(raw), file_type="obj", process=False)
    except Exception as exc:  # noqa: BLE001 - any parser failure is an unreadable file
        raise TwinError(f"could not read mesh file {str(p)!r}: {_one_line(exc)}") from None
    if isinstance(loaded, trimesh.Scene):
        geometries = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if not geometries:
            raise TwinError(f"mesh file {str(p)!r} has no faces")
        loaded = trimesh.util.concatenate(geometries) if len(geometries) > 1 else geometries[0]
    if not isinstance(loaded, trimesh.Trimesh):
        raise TwinError(f"mesh file {str(p)!r} has no faces (it holds a {type(loaded).__name__})")
    return np.asarray(loaded.vertices, dtype=np.float64), np.asarray(loaded.faces, dtype=np.int64)


def _with_trimesh(p: Path, vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Polygons of more than three corners triangulated the way trimesh does."""
    import trimesh

    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


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
