"""A CMM measurement program: what the planners produce, a DMIS file holds and a CMM runs.

Frame and units: every position is the probe's ball centre (GOTO) or a nominal surface point
(a measured point) in the part's coordinate system, in metres; DMIS files carry millimetres
(:mod:`algorithms.probing.dmis` converts). A measured point is probed along ``-normal``: the
machine moves to the approach point ``point + (ball radius + approach) * normal``, probes
towards the point until it triggers (or ``search`` past it: a miss), and retracts to
``point + (ball radius + retract) * normal``.

Statements, in program order:

* :class:`Goto`: a straight move of the ball centre to a via point (DMIS ``GOTO``);
* :class:`SelectStylus`: the probe head indexes to a stylus (DMIS ``SNSLCT``);
* :class:`MeasurePoint`: one point feature measured by one touch (DMIS ``F(label)=FEAT/POINT``,
  ``MEAS/POINT``, ``PTMEAS``, ``ENDMES``); the move to its approach point is straight from
  wherever the probe is.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray
from algorithms.errors import AlgorithmError

#: A DMIS label: letters, digits and underscores, starting with a letter (at most 20 characters).
LABEL_PATTERN = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,19}")


def check_label(label: str, what: str) -> str:
    """``label`` if it is a valid DMIS label, else an AlgorithmError naming ``what``."""
    if not isinstance(label, str) or not LABEL_PATTERN.fullmatch(label):
        raise AlgorithmError(f"{what} label {label!r} is not a DMIS label (a letter, then up to 19 letters, "
                             "digits or underscores)")
    return label


#: Positions are held on the grid a DMIS file writes them on (1 nm: 6 decimals of a millimetre)
#: and normals to 9 decimals, so that writing a program and reading it back gives it exactly.
POSITION_DECIMALS_MM = 6
NORMAL_DECIMALS = 9


def _vec3(v: ArrayLike, what: str) -> FloatArray:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise AlgorithmError(f"{what} must be three finite numbers, got {v!r}")
    return a


def _position(v: ArrayLike, what: str) -> tuple[float, float, float]:
    """A position [m] snapped to the DMIS grid (1 nm)."""
    a = _vec3(v, what)
    return tuple(round(float(x) * 1e3, POSITION_DECIMALS_MM) / 1e3 for x in a)  # type: ignore[return-value]


@dataclass(frozen=True)
class Goto:
    """A straight move of the ball centre to ``xyz_m`` (part frame) [m]."""

    xyz_m: tuple[float, float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "xyz_m", _position(self.xyz_m, "GOTO position"))


@dataclass(frozen=True)
class SelectStylus:
    """The probe head indexes to stylus ``name`` (the machine defines its styli)."""

    name: str

    def __post_init__(self) -> None:
        check_label(self.name, "stylus")


@dataclass(frozen=True)
class MeasurePoint:
    """A point feature ``label`` measured by one touch at ``point_m`` (part frame) [m], probed
    along ``-normal`` (``normal``: the unit outward surface normal there); ``settings``: the
    probing distances of this touch where they differ from the program's (a DMIS program may set
    ``SNSET`` again between touches), else None."""

    label: str
    point_m: tuple[float, float, float]
    normal: tuple[float, float, float]
    settings: ProbeSettings | None = None

    def __post_init__(self) -> None:
        check_label(self.label, "feature")
        object.__setattr__(self, "point_m", _position(self.point_m, f"point {self.label}"))
        n = _vec3(self.normal, f"normal of {self.label}")
        norm = float(np.linalg.norm(n))
        if norm == 0.0:
            raise AlgorithmError(f"normal of {self.label} must be a unit vector, got a zero vector")
        on_grid = np.all(np.round(n, NORMAL_DECIMALS) == n) and abs(norm - 1.0) <= 2e-9
        if not on_grid:  # a normal already unit on the 9-decimal grid is kept as it is
            n = np.round(n / norm, NORMAL_DECIMALS)
        object.__setattr__(self, "normal", tuple(float(x) for x in n))
        if self.settings is not None and not isinstance(self.settings, ProbeSettings):
            raise AlgorithmError(f"settings of {self.label} must be ProbeSettings or None, got "
                                 f"{type(self.settings).__name__}")

    def approach_centre(self, ball_radius_m: float, approach_m: float) -> FloatArray:
        """The ball centre at the start of the probing move [m]."""
        return np.asarray(self.point_m) + (ball_radius_m + approach_m) * np.asarray(self.normal)


Statement = Goto | SelectStylus | MeasurePoint


@dataclass(frozen=True)
class ProbeSettings:
    """The probing distances of a program (DMIS ``SNSET``), all [m] and positive.

    Attributes:
        approach_m: the probing move starts this far off the surface (``APPRCH``).
        retract_m: after the touch the probe backs off this far (``RETRCT``).
        search_m: a probing move goes this far past the nominal point before it is a miss (``SEARCH``).
        clearance_m: the clearance plane distance the program was planned with (``CLRSRF``):
            the safe distance above the safety plane.
    """

    approach_m: float = 0.002
    retract_m: float = 0.002
    search_m: float = 0.005
    clearance_m: float = 0.030

    def __post_init__(self) -> None:
        for name in ("approach_m", "retract_m", "search_m", "clearance_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise AlgorithmError(f"probe setting {name} must be a positive number of metres, got {v!r}")
            snapped = round(float(v) * 1e3, POSITION_DECIMALS_MM) / 1e3  # the DMIS grid, as positions
            if snapped <= 0:
                raise AlgorithmError(f"probe setting {name} must be at least 1 nm, got {v!r}")
            object.__setattr__(self, name, snapped)


@dataclass(frozen=True)
class Program:
    """A measurement program: its name, its probing settings and its statements in order."""

    name: str
    settings: ProbeSettings
    statements: tuple[Statement, ...]

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name or "'" in self.name or "\n" in self.name:
            raise AlgorithmError(f"program name {self.name!r} must be a non-empty line without quotes")
        object.__setattr__(self, "statements", tuple(self.statements))
        labels = [s.label for s in self.statements if isinstance(s, MeasurePoint)]
        seen: set[str] = set()
        for lab in labels:
            if lab.upper() in seen:
                raise AlgorithmError(f"feature label {lab!r} is used twice in program {self.name!r}")
            seen.add(lab.upper())

    @property
    def measurements(self) -> list[MeasurePoint]:
        """The program's measured points, in order."""
        return [s for s in self.statements if isinstance(s, MeasurePoint)]

    @property
    def gotos(self) -> list[Goto]:
        """The program's GOTOs, in order."""
        return [s for s in self.statements if isinstance(s, Goto)]
