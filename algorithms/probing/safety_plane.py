"""Document 002's definitions: the safety plane, safe positions, penetrations of a taught path.

A taught program (:class:`Teach`) is what an operator does at the machine, in order: moves of
the probe's ball centre, touches on features, stylus changes. Its path is the polyline of
ball centres (:func:`taught_path`): each move's position, and for each touch the approach
centre (the point lifted by the ball radius and the approach distance along the normal),
where the probe stands before and after the touch.

Definitions (document 002, section 2):

* **safety plane**: a plane with nothing of the part above it along its normal; unless given,
  the plane through the part's highest point, parallel to the table (:meth:`SafetyPlane.through_highest_point`);
* **safe distance**: the extra lift above the plane;
* **safe position point** of a point: its projection on the plane, lifted by the safe distance
  along the normal (:func:`safe_position`);
* **penetration**: the probe tip crosses the plane; the tip is below the plane when the angle
  between the vector from the tip to its projection on the plane and the plane's normal is
  acute (:meth:`SafetyPlane.below`);
* **effective penetration**: the tip goes below and measures at least once before it comes
  back above; **ineffective**: it goes below and returns without measuring;
* **penetration point**: where the path crosses the plane going down; **penetration line**:
  the line through it along the normal (:class:`Penetration`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray
from algorithms.errors import AlgorithmError
from algorithms.probing.program import MeasurePoint, ProbeSettings, check_label


def _unit(v: ArrayLike, what: str) -> FloatArray:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    n = float(np.linalg.norm(a)) if a.shape == (3,) else 0.0
    if a.shape != (3,) or not np.isfinite(n) or n == 0.0:
        raise AlgorithmError(f"{what} must be a non-zero 3-vector, got {v!r}")
    return a / n


@dataclass(frozen=True)
class SafetyPlane:
    """A plane through ``point_m`` with unit normal ``normal`` (pointing away from the part)."""

    point_m: FloatArray
    normal: FloatArray

    def __post_init__(self) -> None:
        p = np.asarray(self.point_m, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise AlgorithmError(f"safety plane point must be three finite numbers, got {self.point_m!r}")
        object.__setattr__(self, "point_m", p)
        object.__setattr__(self, "normal", _unit(self.normal, "safety plane normal"))

    @staticmethod
    def through_highest_point(vertices: ArrayLike, normal: ArrayLike = (0.0, 0.0, 1.0)) -> SafetyPlane:
        """The plane with the given normal through the part's highest vertex (of (V, 3) [m]) along it."""
        v = np.asarray(vertices, dtype=np.float64)
        n = _unit(normal, "safety plane normal")
        return SafetyPlane(v[int(np.argmax(v @ n))], n)

    def height(self, p: ArrayLike) -> FloatArray | float:
        """Signed height [m] of points (N, 3) (or one point (3,)) above the plane, along its normal."""
        return (np.asarray(p, dtype=np.float64) - self.point_m) @ self.normal

    def project(self, p: ArrayLike) -> FloatArray:
        """Projection of points (N, 3) or (3,) on the plane [m]."""
        q = np.asarray(p, dtype=np.float64)
        return q - np.multiply.outer(self.height(q), self.normal)

    def below(self, p: ArrayLike) -> BoolArray | np.bool_:
        """Document 002's penetration test: the angle between the tip-to-projection vector and
        the normal is acute (the tip is below the plane). A tip on the plane is not below."""
        return (self.project(p) - np.asarray(p, dtype=np.float64)) @ self.normal > 0.0


def safe_position(p: ArrayLike, plane: SafetyPlane, safe_distance_m: float) -> FloatArray:
    """The safe position point of ``p``: its projection on the plane lifted by the safe distance."""
    if not (np.isfinite(safe_distance_m) and safe_distance_m > 0):
        raise AlgorithmError(f"safe distance must be positive, got {safe_distance_m!r}")
    return plane.project(p) + safe_distance_m * plane.normal


# ----------------------------------------------------------------------------- teaching
@dataclass(frozen=True)
class TeachMove:
    """The operator moves the ball centre straight to ``xyz_m`` (part frame) [m]."""

    xyz_m: tuple[float, float, float]


@dataclass(frozen=True)
class TeachTouch:
    """The operator touches point ``label`` of ``feature`` at ``point_m`` with outward normal
    ``normal`` (part frame): the probe comes to the approach centre, touches, backs off."""

    label: str
    feature: str
    point_m: tuple[float, float, float]
    normal: tuple[float, float, float]

    def measure(self) -> MeasurePoint:
        """The touch as a program statement."""
        return MeasurePoint(self.label, self.point_m, self.normal)


@dataclass(frozen=True)
class TeachStylus:
    """The operator indexes the head to stylus ``name``."""

    name: str


TeachStep = TeachMove | TeachTouch | TeachStylus


@dataclass(frozen=True)
class Teach:
    """A taught program: the steps in order, the first stylus, the planning settings.

    Attributes:
        name: the program's name.
        stylus: the stylus selected at the start.
        steps: what the operator did, in order; the first is a move (where the probe starts).
        safe_distance_m: the safe distance above the safety plane [m].
        settings: approach, retract and search distances (the clearance there is the safe distance).
        plane: the safety plane, or None for the plane through the part's highest point.
    """

    name: str
    stylus: str
    steps: tuple[TeachStep, ...]
    safe_distance_m: float
    settings: ProbeSettings = field(default_factory=ProbeSettings)
    plane: SafetyPlane | None = None

    def __post_init__(self) -> None:
        check_label(self.stylus, "stylus")
        object.__setattr__(self, "steps", tuple(self.steps))
        if not (np.isfinite(self.safe_distance_m) and self.safe_distance_m > 0):
            raise AlgorithmError(f"safe_distance_m must be positive, got {self.safe_distance_m!r}")
        if not self.steps or not isinstance(self.steps[0], TeachMove):
            raise AlgorithmError("a teach starts with a move: where the probe is when teaching begins")
        if not any(isinstance(s, TeachTouch) for s in self.steps):
            raise AlgorithmError("a teach needs at least one touch")
        for s in self.steps:
            if isinstance(s, TeachStylus):
                check_label(s.name, "stylus")
            elif isinstance(s, TeachTouch):
                s.measure()  # validates the label, point and normal

    @property
    def touches(self) -> list[TeachTouch]:
        """The touches, in order."""
        return [s for s in self.steps if isinstance(s, TeachTouch)]


@dataclass(frozen=True)
class Station:
    """A vertex of the taught path: a ball centre [m], the stylus then, and what happened there.

    ``step`` is the index of the teach step; ``touch`` the touch made there (its approach
    centre), or None for a move or a stylus change (where the ball centre jumps to the new
    stylus's ball with the head standing still).
    """

    position_m: FloatArray
    stylus: str
    step: int
    touch: TeachTouch | None = None


def taught_path(teach: Teach, reach: dict[str, tuple[FloatArray, float]], ball_radius_m: dict[str, float]
                ) -> list[Station]:
    """The taught path as stations.

    Args:
        teach: the taught program.
        reach: per stylus, (direction from head to ball (3,), head-to-ball distance [m]).
        ball_radius_m: per stylus, the ball radius [m].
    """
    stylus = teach.stylus
    for name in [teach.stylus] + [s.name for s in teach.steps if isinstance(s, TeachStylus)]:
        if name not in reach or name not in ball_radius_m:
            raise AlgorithmError(f"stylus {name!r} is not one of the machine's styli: {', '.join(sorted(reach))}")
    out: list[Station] = []
    for k, step in enumerate(teach.steps):
        if isinstance(step, TeachMove):
            out.append(Station(np.asarray(step.xyz_m, dtype=np.float64), stylus, k))
        elif isinstance(step, TeachTouch):
            m = step.measure()
            c = m.approach_centre(ball_radius_m[stylus], teach.settings.approach_m)
            out.append(Station(c, stylus, k, step))
        else:
            d0, l0 = reach[stylus]
            d1, l1 = reach[step.name]
            head = out[-1].position_m - l0 * np.asarray(d0)
            stylus = step.name
            out.append(Station(head + l1 * np.asarray(d1), stylus, k))
    return out


@dataclass(frozen=True)
class Penetration:
    """One excursion of the taught path below the safety plane.

    Attributes:
        entry_m: the penetration point (where the path crosses the plane going down) [m].
        entry_after: index of the station before the crossing.
        exit_m: where it comes back above, or None when the teach ends below [m].
        exit_after: index of the station before that crossing (None likewise).
        touches: indices of the stations (touches) measured below.
        stylus: the stylus in use.
    """

    entry_m: FloatArray
    entry_after: int
    exit_m: FloatArray | None
    exit_after: int | None
    touches: tuple[int, ...]
    stylus: str

    @property
    def effective(self) -> bool:
        """Measures at least once before coming back above (document 002)."""
        return len(self.touches) > 0


def _crossing(a: FloatArray, b: FloatArray, plane: SafetyPlane) -> FloatArray:
    ha, hb = float(plane.height(a)), float(plane.height(b))
    t = ha / (ha - hb) if ha != hb else 0.0
    return a + t * (b - a)


def penetrations(stations: list[Station], plane: SafetyPlane) -> list[Penetration]:
    """Every penetration of the taught path, effective or not, in order.

    Raises:
        AlgorithmError: the teach starts below the plane, or changes the stylus below it.
    """
    if plane.below(stations[0].position_m):
        raise AlgorithmError("the teach starts below the safety plane: start with the probe above it")
    out: list[Penetration] = []
    below = False
    entry, entry_after = np.zeros(3), 0
    touches: list[int] = []
    for i in range(1, len(stations)):
        a, b = stations[i - 1], stations[i]
        b_below = bool(plane.below(b.position_m))
        if b.touch is None and b.stylus != a.stylus:
            if below or b_below:
                raise AlgorithmError(f"teach step {b.step + 1} changes the stylus below the safety plane: "
                                     "index the head above it")
            continue
        if not below and b_below:
            below, entry, entry_after, touches = True, _crossing(a.position_m, b.position_m, plane), i - 1, []
        elif below and not b_below:
            below = False
            out.append(Penetration(entry, entry_after, _crossing(a.position_m, b.position_m, plane), i - 1,
                                   tuple(touches), a.stylus))
        if below and b.touch is not None:
            touches.append(i)
    if below:
        out.append(Penetration(entry, entry_after, None, None, tuple(touches), stations[-1].stylus))
    return out
