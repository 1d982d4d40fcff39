"""DMIS text into statements: the file's encoding, ``$$`` comments, ``$`` continuation lines, and
each statement split into its label assignment, major word and fields.

What real part programs hold, as measurement software writes them: UTF-8 (with or without a
byte-order mark) or Latin-1 text (accented feature names and comments); ``\\r\\n`` line ends;
``$$`` comments on their own lines or after a statement; a statement continued on the next line
when its line ends in a single ``$``; jump targets as ``(label)`` lines; free-text separator lines
(rows of ``*`` or ``=``). A statement is ``[X(label)=]WORD[/field,field,...]``; fields are split
at commas outside quotes and parentheses, so ``F(A,B)``-style references and ``'a, b'`` strings
stay whole.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from algorithms.errors import AlgorithmError

#: The share of control bytes (other than tab, line ends, form feed and the DOS end-of-file byte)
#: above which a file is taken as binary, not text.
BINARY_CONTROL_SHARE = 0.01

_CONTROL_OK = frozenset(b"\t\n\r\f\x1a")
_HEAD = re.compile(r"\s*(?:([A-Za-z]+)\s*\(\s*([^()]*?)\s*\)\s*=\s*)?([A-Za-z][A-Za-z0-9]*)\s*")
_JUMP_LABEL = re.compile(r"\(\s*([^()]+?)\s*\)")


@dataclass(frozen=True)
class Statement:
    """One DMIS statement.

    Attributes:
        source: the file it came from; line: its first physical line (1-based).
        label_kind: the label type of a label assignment (``F``, ``FA``, ``T``, ``D``, ...), upper case,
            or None; label: that label's name as written.
        word: the major word, upper case (``FEAT``, ``GOTO``, ...); ``(`` for a ``(label)`` jump target.
        rest: the text after the first ``/`` (empty when there is none); fields: ``rest`` split at the
            top-level commas, each stripped.
        text: the whole statement as read (continuations joined, comment removed).
    """

    source: str
    line: int
    label_kind: str | None
    label: str | None
    word: str
    rest: str
    fields: tuple[str, ...]
    text: str

    def where(self) -> str:
        return f"{self.source}:{self.line}"


def decode(data: bytes, source: str) -> tuple[str, str]:
    """The text of a DMIS file's bytes and the encoding read: ``utf-8-sig`` (a byte-order mark),
    ``utf-8`` or ``latin-1``.

    Raises:
        AlgorithmError: an empty file, or bytes that are not text (NUL bytes, or more than
            :data:`BINARY_CONTROL_SHARE` control bytes).
    """
    if not data.strip():
        raise AlgorithmError(f"{source}: the file is empty: a DMIS program starts with DMISMN/'name',05.3 and ends "
                             "with ENDFIL")
    controls = sum(1 for b in data if b < 32 and b not in _CONTROL_OK)
    if b"\x00" in data or controls > BINARY_CONTROL_SHARE * len(data):
        raise AlgorithmError(f"{source}: the file is binary, not DMIS text ({controls} control bytes of {len(data)}): "
                             "a DMIS program is a text file (UTF-8 or Latin-1)")
    if data.startswith(b"\xef\xbb\xbf"):
        try:
            return data.decode("utf-8-sig"), "utf-8-sig"
        except UnicodeDecodeError as e:
            raise AlgorithmError(f"{source}: the file starts with a UTF-8 byte-order mark but is not UTF-8 (byte "
                                 f"{e.start}: {e.reason})") from None
    try:
        return data.decode("utf-8"), "utf-8"
    except UnicodeDecodeError:
        return data.decode("latin-1"), "latin-1"


def read_bytes(path: str | os.PathLike[str]) -> bytes:
    """The bytes of the DMIS file ``path``.

    Raises:
        AlgorithmError: no such file, or it cannot be read.
    """
    source = os.fspath(path)
    if not Path(path).is_file():
        raise AlgorithmError(f"no DMIS file at {source!r}: give the path of an existing file")
    try:
        return Path(path).read_bytes()
    except OSError as e:
        raise AlgorithmError(f"cannot read DMIS file {source!r}: {e.strerror or e}") from e


def strip_comment(line: str) -> str:
    """``line`` without its ``$$`` comment (a ``$$`` inside a quoted string is text)."""
    quoted = False
    for k, ch in enumerate(line):
        if ch == "'":
            quoted = not quoted
        elif ch == "$" and not quoted and line.startswith("$$", k):
            return line[:k]
    return line


def logical_lines(text: str) -> list[tuple[int, str]]:
    """Each statement's first line number and its text: comments removed, ``$`` continuations
    joined, blank lines dropped."""
    out: list[tuple[int, str]] = []
    pending: tuple[int, str] | None = None
    for number, raw in enumerate(text.split("\n"), start=1):
        line = strip_comment(raw.removesuffix("\r")).strip()
        if pending is not None:
            first, before = pending
            line = before + line
            number = first
            pending = None
        if line.endswith("$"):
            pending = (number, line[:-1].rstrip())  # DMIS joins a continued line to the next as it stands
            continue
        if line:
            out.append((number, line))
    if pending is not None and pending[1].strip():
        out.append((pending[0], pending[1].strip()))
    return out


def _top_level(text: str):
    """(index, character) of each character of ``text`` outside quotes and parentheses."""
    depth, quoted = 0, False
    for k, ch in enumerate(text):
        if ch == "'":
            quoted = not quoted
        elif quoted:
            continue
        elif ch == "(":
            depth += 1
        elif ch == ")":
            depth -= 1
        elif depth == 0:
            yield k, ch


def split_fields(rest: str) -> tuple[str, ...]:
    """``rest`` split at commas outside quotes and parentheses, each field stripped."""
    if not rest.strip():
        return ()
    cuts = [k for k, ch in _top_level(rest) if ch == ","]
    starts, ends = [0, *(k + 1 for k in cuts)], [*cuts, len(rest)]
    return tuple(rest[a:b].strip() for a, b in zip(starts, ends, strict=True))


def _slash(text: str) -> int:
    """The index of the first ``/`` outside quotes and parentheses, or -1."""
    return next((k for k, ch in _top_level(text) if ch == "/"), -1)


def statement(text: str, line: int, source: str) -> Statement | None:
    """The statement in one logical line, or None for a line that is not a statement (free text)."""
    jump = _JUMP_LABEL.fullmatch(text)
    if jump:
        return Statement(source, line, None, jump.group(1), "(", "", (), text)
    k = _slash(text)
    head, rest = (text, "") if k < 0 else (text[:k], text[k + 1:])
    m = _HEAD.fullmatch(head)
    if m is None:
        return None
    kind = m.group(1).upper() if m.group(1) else None
    return Statement(source, line, kind, m.group(2), m.group(3).upper(), rest.strip(), split_fields(rest), text)


def statements(text: str, source: str) -> tuple[list[Statement], list[tuple[int, str]]]:
    """The statements of a DMIS text, and the lines that are not statements (line, text)."""
    out: list[Statement] = []
    other: list[tuple[int, str]] = []
    for number, line in logical_lines(text):
        st = statement(line, number, source)
        if st is None:
            other.append((number, line))
        else:
            out.append(st)
    return out, other
