"""A strict PLY reader: the header's counts, the body's size, finite vertices, valid faces.

General readers (trimesh's included) read what they can: an ASCII body with more or fewer lines
than the header declares is read partially, and vertices with NaN are dropped with their
faces before anyone can check them. A measurement or a CAD model read that way is silently
wrong, so this reader refuses, naming the file and the element or line:

- a header that is not PLY 1.0 (ascii, binary_little_endian or binary_big_endian), or an
  element ``vertex`` without ``x``, ``y``, ``z``;
- a body that holds fewer or more lines (ASCII) or bytes (binary) than the header declares;
- a vertex with a non-finite coordinate; a face that references a vertex that does not exist.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twin.errors import TwinError

__all__ = ["PlyData", "read_ply"]

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_FACE_LISTS = ("vertex_indices", "vertex_index")


@dataclass(frozen=True)
class PlyData:
    """The vertices (N, 3) float64 and, if the file has faces, their indices (M, k) int64."""

    vertices: np.ndarray
    faces: np.ndarray | None


@dataclass
class _Element:
    name: str
    count: int
    props: list[tuple[str, str, str | None]]  # (name, value type, list count type or None)


def _bad(path: Path, what: str) -> TwinError:
    return TwinError(f"{path}: not a valid PLY file: {what}")


def _header(path: Path, raw: bytes) -> tuple[str, list[_Element], int]:
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise _bad(path, "it must start with 'ply' and have an 'end_header' line")
    nl = raw.find(b"\n", end)
    body_start = len(raw) if nl < 0 else nl + 1
    try:
        lines = raw[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise _bad(path, "the header is not ASCII text") from None
    fmt, elements = None, []
    for no, line in enumerate(lines[1:], start=2):
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "format":
            if len(tok) != 3 or tok[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise _bad(path, f"header line {no}: unknown format {' '.join(tok[1:])!r}")
            fmt = tok[1]
        elif tok[0] == "element":
            if len(tok) != 3 or not tok[2].isdigit():
                raise _bad(path, f"header line {no}: 'element NAME COUNT' with a non-negative count expected")
            elements.append(_Element(tok[1], int(tok[2]), []))
        elif tok[0] == "property":
            if not elements:
                raise _bad(path, f"header line {no}: a property before any element")
            if len(tok) == 5 and tok[1] == "list" and tok[2] in _TYPES and tok[3] in _TYPES:
                elements[-1].props.append((tok[4], _TYPES[tok[3]], _TYPES[tok[2]]))
            elif len(tok) == 3 and tok[1] in _TYPES:
                elements[-1].props.append((tok[2], _TYPES[tok[1]], None))
            else:
                raise _bad(path, f"header line {no}: unknown property {' '.join(tok[1:])!r}")
        else:
            raise _bad(path, f"header line {no}: unknown keyword {tok[0]!r}")
    if fmt is None:
        raise _bad(path, "the header has no 'format' line")
    return fmt, elements, body_start


# Each element's columns by property name: a list of values (or of index lists), or, for a
# binary element without list properties, an array.
_Body = dict[str, Mapping[str, list | np.ndarray]]


def _ascii_body(path: Path, body: bytes, elements: list[_Element]) -> _Body:
    try:
        lines = [ln for ln in body.decode("ascii").splitlines() if ln.strip()]
    except UnicodeDecodeError:
        raise _bad(path, "the ASCII body holds non-ASCII bytes") from None
    declared = sum(e.count for e in elements)
    if len(lines) != declared:
        counts = ", ".join(f"{e.count} {e.name}" for e in elements)
        raise _bad(path, f"the header declares {counts} ({declared} lines) but the body holds {len(lines)} lines")
    out: _Body = {}
    row = 0
    for e in elements:
        cols: dict[str, list] = {name: [] for name, _, _ in e.props}
        for k in range(e.count):
            tok = lines[row].split()
            row += 1
            pos = 0
            try:
                for name, _, count_type in e.props:
                    if count_type is None:
                        cols[name].append(float(tok[pos]))
                        pos += 1
                    else:
                        n = int(tok[pos])
                        cols[name].append([int(t) for t in tok[pos + 1: pos + 1 + n]])
                        if len(cols[name][-1]) != n:
                            raise IndexError
                        pos += 1 + n
            except (ValueError, IndexError):
                raise _bad(path, f"{e.name} {k} (body line {row}): cannot read {len(e.props)} value(s)") from None
            if pos != len(tok):
                raise _bad(path, f"{e.name} {k} (body line {row}): {len(tok)} values where {pos} are declared")
        out[e.name] = cols
    return out


def _binary_body(path: Path, body: bytes, elements: list[_Element], order: str) -> _Body:
    out: _Body = {}
    pos = 0
    for e in elements:
        if all(ct is None for _, _, ct in e.props):
            dt = np.dtype([(name, order + t) for name, t, _ in e.props])
            need = dt.itemsize * e.count
            if pos + need > len(body):
                raise _bad(path, f"the file ends inside element {e.name!r} ({len(body) - pos} of {need} bytes)")
            arr = np.frombuffer(body, dtype=dt, count=e.count, offset=pos)
            out[e.name] = {name: arr[name] for name, _, _ in e.props}
            pos += need
            continue
        cols: dict[str, list] = {name: [] for name, _, _ in e.props}
        for k in range(e.count):
            for name, t, count_type in e.props:
                size = np.dtype(t).itemsize
                if count_type is None:
                    if pos + size > len(body):
                        raise _bad(path, f"the file ends inside {e.name} {k}")
                    cols[name].append(np.frombuffer(body, order + t, 1, pos)[0])
                    pos += size
                else:
                    csize = np.dtype(count_type).itemsize
                    if pos + csize > len(body):
                        raise _bad(path, f"the file ends inside {e.name} {k}")
                    n = int(np.frombuffer(body, order + count_type, 1, pos)[0])
                    pos += csize
                    if n < 0 or pos + n * size > len(body):
                        raise _bad(path, f"the file ends inside {e.name} {k}")
                    cols[name].append(np.frombuffer(body, order + t, n, pos).tolist())
                    pos += n * size
        out[e.name] = cols
    if pos != len(body):
        raise _bad(path, f"{len(body) - pos} bytes after the last element the header declares")
    return out


def read_ply(path: str | Path) -> PlyData:
    """Read and check a PLY file's vertices (and faces, if any)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise TwinError(f"cannot read {p}: {exc.strerror}") from None
    fmt, elements, start = _header(p, raw)
    body = raw[start:]
    if fmt == "ascii":
        data = _ascii_body(p, body, elements)
    else:
        data = _binary_body(p, body, elements, "<" if fmt == "binary_little_endian" else ">")
    if "vertex" not in data or not all(c in data["vertex"] for c in "xyz"):
        raise _bad(p, "no element 'vertex' with properties x, y, z")
    v = np.column_stack([np.asarray(data["vertex"][c], dtype=np.float64) for c in "xyz"])
    v = v.reshape(-1, 3)
    bad = np.flatnonzero(~np.all(np.isfinite(v), axis=1))
    if len(bad):
        raise _bad(p, f"vertex {bad[0]} has a non-finite coordinate ({len(bad)} such vertices)")
    faces = None
    face_cols = data.get("face", {})
    key = next((k for k in _FACE_LISTS if k in face_cols), None)
    if key is not None and len(face_cols[key]):
        lists = face_cols[key]
        sizes = {len(f) for f in lists}
        if min(sizes) < 3:
            raise _bad(p, "a face with fewer than 3 vertices")
        if len(sizes) == 1:
            faces = np.asarray(lists, dtype=np.int64)
        else:  # polygons: fan triangulation
            faces = np.asarray([[f[0], f[i], f[i + 1]] for f in lists for i in range(1, len(f) - 1)], dtype=np.int64)
        wrong = np.flatnonzero(np.any((faces < 0) | (faces >= len(v)), axis=1))
        if len(wrong):
            raise _bad(p, f"face {wrong[0]} references a vertex that does not exist ({len(v)} vertices)")
    return PlyData(v, faces)
