"""Structure checks of STL and OBJ files, made before a mesh library parses them.

- STL: a binary file's size must be 84 + 50 n bytes for the n triangles its header declares;
  a file that is not that must be ASCII text that starts with ``solid`` and holds ``facet``
  and ``vertex`` lines, each ``vertex`` line with three finite numbers.
- OBJ: every ``v`` line holds at least three finite numbers; every index of every ``f`` line
  refers to an existing vertex (1-based, or negative: counted back from the last ``v`` line).
"""

from __future__ import annotations

import math
from pathlib import Path

from twin.errors import TwinError

__all__ = ["check_obj", "check_stl"]


def _bad(path: Path, kind: str, what: str) -> TwinError:
    return TwinError(f"{path}: not a valid {kind} file: {what}")


def _finite_numbers(tokens: list[str]) -> bool:
    try:
        return all(math.isfinite(float(t)) for t in tokens)
    except ValueError:
        return False


def check_stl(path: Path, raw: bytes) -> None:
    """Refuse an STL file that is neither a consistent binary nor a readable ASCII STL."""
    if not raw.strip():
        raise _bad(path, "STL", "the file is empty: no faces")
    if len(raw) >= 84:
        n = int.from_bytes(raw[80:84], "little")
        if len(raw) == 84 + 50 * n:
            if n == 0:
                raise _bad(path, "STL", "the header declares 0 triangles: no faces")
            return
    if not raw.lstrip().lower().startswith(b"solid"):
        declared = int.from_bytes(raw[80:84], "little") if len(raw) >= 84 else 0
        raise _bad(path, "STL", f"{len(raw)} bytes, where a binary STL declaring {declared} triangles has "
                                f"{84 + 50 * declared}, and no ASCII 'solid' header")
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise _bad(path, "STL", "it starts with 'solid' but is not ASCII text, and its size does not "
                                "match a binary STL") from None
    n_vertex = 0
    for no, line in enumerate(text.splitlines(), start=1):
        tok = line.split()
        if tok and tok[0].lower() == "vertex":
            if len(tok) != 4 or not _finite_numbers(tok[1:]):
                raise _bad(path, "STL", f"line {no}: a vertex needs three finite numbers, got {line.strip()!r}")
            n_vertex += 1
    if n_vertex == 0:
        raise _bad(path, "STL", "no faces (no vertex lines)")
    if n_vertex % 3:
        raise _bad(path, "STL", f"{n_vertex} vertex lines: triangles need a multiple of 3")


def check_obj(path: Path, raw: bytes) -> None:
    """Refuse an OBJ file with non-finite vertices or faces that reference missing vertices."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise _bad(path, "OBJ", "it is not UTF-8 text") from None
    n_v = 0
    n_f = 0
    for no, line in enumerate(text.splitlines(), start=1):
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "v":
            if len(tok) < 4 or not _finite_numbers(tok[1:4]):
                raise _bad(path, "OBJ", f"line {no}: a vertex needs three finite numbers, got {line.strip()!r}")
            n_v += 1
        elif tok[0] == "f":
            if len(tok) < 4:
                raise _bad(path, "OBJ", f"line {no}: a face needs at least three vertices")
            for t in tok[1:]:
                head = t.split("/")[0]
                try:
                    k = int(head)
                except ValueError:
                    raise _bad(path, "OBJ", f"line {no}: face index {t!r} is not an integer") from None
                if k == 0 or k > n_v or k < -n_v:
                    raise _bad(path, "OBJ", f"line {no}: face index {k} refers to a vertex that does not "
                                            f"exist ({n_v} vertices so far)")
            n_f += 1
    if n_f == 0:
        raise _bad(path, "OBJ", "no faces (no 'f' line)")
