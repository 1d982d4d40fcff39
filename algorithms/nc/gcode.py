"""A 3-axis G-code program: written from tool-tip passes, read back into moves.

Written: ``G21`` (mm), ``G90`` (absolute), ``G17``; a rapid ``G0`` to the safe height, then per
pass a rapid over its first point, a ``G1`` plunge at the plunge feed, ``G1`` moves through the
pass at the feed, a rapid back to the safe height; ``M30`` at the end. A word is written only
where its value changes. Coordinates are printed
with ``decimals`` digits in mm (3: 1 um, ten times finer than document 004's 0.01 mm).

Read: the words of ISO 6983 that such a program holds: ``G0``/``G00``, ``G1``/``G01`` (modal),
``G20``/``G21``, ``G90``/``G91``, ``G17``, ``G94``, ``G40``/``G49``/``G80`` (cancels), ``G43`` with
its ``H`` (tool length compensation: the program's coordinates stay those of the tool tip),
``X Y Z F``, ``N`` line numbers, ``O`` program numbers, ``S``, ``T``, ``M`` (spindle, coolant, tool
change, end), comments in parentheses or after ``;``, ``%`` tape marks. A word it cannot execute as a straight 3-axis
move (arcs ``G2``/``G3``, other planes, cutter compensation on, canned cycles, axes A-C or U-W)
is refused with its line: a program run half-understood would be a wrong program.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
_IGNORED_G = {17.0, 40.0, 43.0, 49.0, 80.0, 94.0}
_ALLOWED_LETTERS = set("GXYZFNOSTMH")


class GCodeError(ValueError):
    """A program the reader refuses, with the line and what is allowed."""


@dataclass(frozen=True)
class Move:
    """One straight move: ``rapid`` (G0) or feed (G1), its end point [mm], feed [mm/min] (G1),
    the program line it comes from, and ``axes``: the axes its line names (``"Z"`` for a
    retract), all three when it ends where X, Y and Z are all known."""

    rapid: bool
    xyz_mm: tuple[float, float, float]
    feed_mm_min: float
    line: int
    axes: str = "XYZ"

    @property
    def complete(self) -> bool:
        """Whether the end point is known in all three axes (not a move of the start's axes alone)."""
        return self.axes == "XYZ"


def write_gcode(passes_mm: Sequence[ArrayLike], *, feed_mm_min: float = 1000.0, plunge_feed_mm_min: float = 300.0,
                safe_z_mm: float, decimals: int = 3, title: str = "") -> str:
    """The program machining each pass in turn (module docstring).

    Args:
        passes_mm: each an (N, 3) array of tool-tip positions [mm], machine frame.
        feed_mm_min: the cutting feed [mm/min].
        plunge_feed_mm_min: the plunging feed [mm/min].
        safe_z_mm: the rapid height [mm]; must be above every point.
        decimals: digits after the point of every coordinate.
        title: a comment line (parentheses are removed from it).
    """
    passes = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in passes_mm]
    if not passes or any(len(p) == 0 or not np.all(np.isfinite(p)) for p in passes):
        raise GCodeError("every pass needs at least one finite (x, y, z) point")
    top = max(float(p[:, 2].max()) for p in passes)
    if safe_z_mm <= top:
        raise GCodeError(f"safe_z_mm {safe_z_mm:g} is not above the highest point of the passes ({top:g} mm)")
    moves = [Move(True, (0.0, 0.0, safe_z_mm), 0.0, 0, "Z")]
    for p in passes:
        x, y, z = p[0]
        moves += [Move(True, (x, y, safe_z_mm), 0.0, 0), Move(False, (x, y, z), plunge_feed_mm_min, 0)]
        moves += [Move(False, (a, b, c), feed_mm_min, 0) for a, b, c in p[1:]]
        moves.append(Move(True, (p[-1][0], p[-1][1], safe_z_mm), 0.0, 0))
    return program_text(moves, decimals=decimals, title=title)


def program_text(moves: Sequence[Move], *, decimals: int = 3, title: str = "") -> str:
    """G-code of ``moves`` (mm, absolute): each its G0 or G1 and the axes it names, a feed
    where it changes; ``M30`` at the end."""
    f = f"{{:.{decimals}f}}"
    lines = ["%", f"({title.replace('(', '').replace(')', '')})" if title else "(program)", "G21 G90 G17"]
    feed, last = None, None
    for m in moves:
        words = ["G0" if m.rapid else "G1"]
        words += [f"{a}{f.format(v)}" for a, v in zip("XYZ", m.xyz_mm, strict=True) if a in m.axes
                  and (last is None or not m.complete or f.format(v) != f.format(last[a]))]
        if not m.rapid and m.feed_mm_min != feed:
            words.append(f"F{m.feed_mm_min:g}")
            feed = m.feed_mm_min
        if len(words) > 1:
            lines.append(" ".join(words))
        last = dict(zip("XYZ", m.xyz_mm, strict=True)) if m.complete else None
    return "\n".join([*lines, "M30", "%"]) + "\n"


def read_gcode(text: str) -> list[Move]:
    """The straight moves of a program (module docstring), end points in mm, absolute."""
    pos = np.zeros(3)
    known = ""
    mm, absolute, rapid, feed = 1.0, True, True, 0.0
    moves: list[Move] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = re.sub(r"\([^)]*\)", " ", raw).split(";", 1)[0].strip()
        if not line or line == "%":
            continue
        words = _words(line, number)
        axes: dict[str, float] = {}
        for letter, value in words:
            if letter == "G":
                mm, absolute, rapid = _g_word(value, number, mm, absolute, rapid)
            elif letter in "XYZ":
                axes[letter] = value
            elif letter == "F":
                feed = value * mm
        if axes:
            new = np.array([axes.get(a, pos[i] if absolute else 0.0) * (mm if a in axes else 1.0)
                            for i, a in enumerate("XYZ")])
            pos = new if absolute else pos + new
            if not rapid and feed <= 0:
                raise GCodeError(f"line {number}: a G1 move with no feed (F) set before it")
            known = "".join(a for a in "XYZ" if a in known or a in axes)
            moves.append(Move(rapid, (float(pos[0]), float(pos[1]), float(pos[2])), 0.0 if rapid else feed, number,
                              known))
    return moves


def _words(line: str, number: int) -> list[tuple[str, float]]:
    words = [(m.group(1).upper(), float(m.group(2))) for m in _WORD.finditer(line)]
    rest = _WORD.sub("", line).strip()
    if rest:
        raise GCodeError(f"line {number}: {rest!r} is not a G-code word (a letter and a number)")
    for letter, value in words:
        if letter == "G":
            _g_word(value, number, 1.0, True, True)  # refuses what it cannot execute, before its arguments
    for letter, _ in words:
        if letter not in _ALLOWED_LETTERS:
            raise GCodeError(f"line {number}: word {letter} is refused: only straight 3-axis moves are read "
                             f"(words {', '.join(sorted(_ALLOWED_LETTERS))})")
    return words


def _g_word(value: float, number: int, mm: float, absolute: bool, rapid: bool) -> tuple[float, bool, bool]:
    """The modal state after one G word: (unit scale to mm, absolute, rapid)."""
    if value in (0.0, 1.0):
        return mm, absolute, value == 0.0
    if value in (20.0, 21.0):
        return (25.4 if value == 20.0 else 1.0), absolute, rapid
    if value in (90.0, 91.0):
        return mm, value == 90.0, rapid
    if value in _IGNORED_G:
        return mm, absolute, rapid
    raise GCodeError(f"line {number}: G{value:g} is refused: only G0, G1, G17, G20, G21, G40, G43, G49, G80, G90, "
                     "G91 and G94 are read (no arcs, other planes, cutter compensation, work offsets or cycles)")
