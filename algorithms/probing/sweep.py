"""Is a straight move of a CMM probe free of the part? A swept check against the exact mesh.

The probe is five solids rigidly placed relative to its ball centre (:class:`ProbeGeometry`):
the ball, the stylus stem, the probe body (module and extension), the probe head and the ram
above it. A move translates them together along a straight segment (a CMM's axes move, the
head does not turn). The check is conservative advancement (Mirtich's method for a translating
body): at a position whose distance to the part is ``d``, no point of the probe moves more
than the step, so a step of ``d - clearance`` cannot bring it closer than ``clearance``; the
sweep advances by that much (at least ``step_floor_m``) until it reaches the end or finds
the probe closer than ``clearance``. Nothing between two checked positions is skipped: the
guarantee is a distance of at least ``clearance - step_floor_m`` along the whole segment.

Distances are exact primitive-to-triangle distances from python-fcl (the Flexible Collision
Library's BVH of the real triangles, built once; primitives moved with ``setTranslation``),
not trimesh's collision manager (it rebuilds its query object on every call) nor fcl's own
continuous collision (it crashed for a sphere against a BVH model); the timings are in
``benchmarks/results_history_symmetric_paths.md``. A distance query cannot see a probe wholly
inside the material (no triangle near it), so the start of every move is also tested for
lying inside the closed mesh (the project's exact signed distance,
:class:`algorithms.geometry.mesh_index.MeshIndex`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import fcl
import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray
from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex

#: The parts of a probe, in the order they are reported.
PROBE_PARTS = ("ball", "stylus", "body", "head", "ram")
#: Smallest advance of the sweep [m]: the clearance is guaranteed to within this.
STEP_FLOOR_M = 1e-5
#: Length of the ram modelled above the head [m] (it reaches out of any part on a table).
RAM_LENGTH_M = 0.6


def _unit(v: ArrayLike, what: str) -> FloatArray:
    a = np.asarray(v, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(a))
    if not np.isfinite(n) or n == 0.0:
        raise AlgorithmError(f"{what} must be a non-zero vector, got {v!r}")
    return a / n


def frame_with_z(z: FloatArray) -> FloatArray:
    """A rotation whose third column is the unit vector ``z``."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


@dataclass(frozen=True)
class ProbeGeometry:
    """A probe on a CMM's ram, in the part frame, relative to its ball centre [m].

    Attributes:
        direction: unit vector from the probe head towards the ball (the stylus direction).
        ball_radius_m, stylus_radius_m: the ball and the stem.
        stylus_length_m: from the probe module's face to the ball centre.
        body_radius_m, body_length_m: the probe body (module, body, extension) from the head
            centre to the module's face.
        head_radius_m: the probe head, a sphere about the head centre.
        ram_half_width_m: the ram, a square box of this half width rising from the head centre
            along ``up``.
        up: unit vector of the machine's z axis (the ram's axis).
    """

    direction: FloatArray
    ball_radius_m: float
    stylus_radius_m: float
    stylus_length_m: float
    body_radius_m: float
    body_length_m: float
    head_radius_m: float
    ram_half_width_m: float
    up: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    def __post_init__(self) -> None:
        object.__setattr__(self, "direction", _unit(self.direction, "probe direction"))
        object.__setattr__(self, "up", _unit(self.up, "machine up"))
        for name in ("ball_radius_m", "stylus_radius_m", "stylus_length_m", "body_radius_m", "body_length_m",
                     "head_radius_m", "ram_half_width_m"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise AlgorithmError(f"probe {name} must be positive, got {v!r}")
        if self.stylus_radius_m >= self.ball_radius_m:
            raise AlgorithmError("probe stylus_radius_m must be smaller than ball_radius_m")

    @property
    def reach_m(self) -> float:
        """Head centre to ball centre [m]."""
        return self.body_length_m + self.stylus_length_m

    def head_centre(self, ball_centre: ArrayLike) -> FloatArray:
        """The head centre for a ball centre (part frame) [m]."""
        return np.asarray(ball_centre, dtype=np.float64) - self.reach_m * self.direction

    def ball_centre(self, head_centre: ArrayLike) -> FloatArray:
        """The ball centre for a head centre (part frame) [m]."""
        return np.asarray(head_centre, dtype=np.float64) + self.reach_m * self.direction

    def _placements(self) -> list[tuple[str, fcl.CollisionGeometry, FloatArray, FloatArray]]:
        """(part, fcl shape, offset of its centre from the ball centre, rotation) of each solid."""
        d, up = self.direction, self.up
        R_d, R_up = frame_with_z(d), frame_with_z(up)
        head = -self.reach_m * d
        return [
            ("ball", fcl.Sphere(self.ball_radius_m), np.zeros(3), np.eye(3)),
            ("stylus", fcl.Cylinder(self.stylus_radius_m, self.stylus_length_m), -0.5 * self.stylus_length_m * d, R_d),
            ("body", fcl.Cylinder(self.body_radius_m, self.body_length_m),
             -(self.stylus_length_m + 0.5 * self.body_length_m) * d, R_d),
            ("head", fcl.Sphere(self.head_radius_m), head, np.eye(3)),
            ("ram", fcl.Box(2 * self.ram_half_width_m, 2 * self.ram_half_width_m, RAM_LENGTH_M),
             head + 0.5 * RAM_LENGTH_M * up, R_up),
        ]


def _half_extent(shape: fcl.CollisionGeometry, R: FloatArray) -> FloatArray:
    """Half extents of the world-aligned box around a solid rotated by ``R``."""
    if isinstance(shape, fcl.Sphere):
        return np.full(3, shape.radius)
    if isinstance(shape, fcl.Cylinder):
        local = np.array([shape.radius, shape.radius, 0.5 * shape.lz])
    else:
        local = 0.5 * np.asarray(shape.side, dtype=np.float64)
    return np.abs(R) @ local


@dataclass(frozen=True)
class MoveCheck:
    """The outcome of a swept check of one straight move.

    Attributes:
        clear: the probe kept at least the clearance from the part all along.
        fraction: where along the move the probe first came closer (0..1), or None.
        ball_centre_m: (3,) the ball centre there, or None.
        part: which part of the probe came closer ("ball", "stylus", "body", "head", "ram").
        distance_m: its distance there (0 when touching or inside).
        queries: distance queries the sweep took.
    """

    clear: bool
    fraction: float | None = None
    ball_centre_m: FloatArray | None = None
    part: str | None = None
    distance_m: float | None = None
    queries: int = 0


class ProbeSweep:
    """Swept clearance checks of a probe's straight moves against one part.

    Args:
        vertices, faces: the part's closed triangle mesh, in the frame the moves are given in.
        clearance_m: the distance every solid of the probe must keep from the part [m] (> 0).
        step_floor_m: smallest advance of the sweep [m].
    """

    def __init__(self, vertices: ArrayLike, faces: ArrayLike, clearance_m: float,
                 step_floor_m: float = STEP_FLOOR_M) -> None:
        v = np.ascontiguousarray(vertices, dtype=np.float64)
        f = np.ascontiguousarray(faces, dtype=np.int64)
        if not (np.isfinite(clearance_m) and clearance_m > 0):
            raise AlgorithmError(f"clearance must be a positive distance, got {clearance_m!r}")
        if not (0 < step_floor_m < clearance_m):
            raise AlgorithmError(f"step_floor_m must lie in (0, clearance), got {step_floor_m!r}")
        self.clearance_m = float(clearance_m)
        self.step_floor_m = float(step_floor_m)
        self.index = MeshIndex(type("Mesh", (), {"vertices": v, "faces": f})())
        bvh = fcl.BVHModel()
        bvh.beginModel(len(v), len(f))
        bvh.addSubModel(v, f.astype(np.int32))
        bvh.endModel()
        self._part = fcl.CollisionObject(bvh, fcl.Transform())
        self._part_lo, self._part_hi = v.min(axis=0), v.max(axis=0)
        self._solids: dict[tuple, list] = {}

    def _probe_solids(self, probe: ProbeGeometry) -> list:
        # keyed by the geometry itself (an id could be reused by a later, different probe)
        key = (*probe.direction.tolist(), *probe.up.tolist(), probe.ball_radius_m, probe.stylus_radius_m,
               probe.stylus_length_m, probe.body_radius_m, probe.body_length_m, probe.head_radius_m,
               probe.ram_half_width_m)
        if key not in self._solids:
            self._solids[key] = [(name, fcl.CollisionObject(shape, fcl.Transform(R, np.zeros(3))), off,
                                  _half_extent(shape, R)) for name, shape, off, R in probe._placements()]
        return self._solids[key]

    def distance(self, ball_centre: ArrayLike, probe: ProbeGeometry) -> tuple[float, str]:
        """The smallest distance of the probe's solids to the part, and which solid [m].

        0 when a solid touches or overlaps the part's surface; a probe wholly inside the
        material is not seen here (see :meth:`inside`).
        """
        c = np.asarray(ball_centre, dtype=np.float64)
        best, which = np.inf, ""
        request = fcl.DistanceRequest()
        solids = self._probe_solids(probe)
        # A lower bound of each solid's distance: the gap between its box and the part's. A
        # solid whose bound is not below the best distance so far cannot change the minimum
        # (the ram and the head, costly against a fine mesh, are mostly skipped this way).
        bounds = [self._box_gap(c + off, half) for _, _, off, half in solids]
        for k in np.argsort(bounds):
            if bounds[k] >= best:
                break
            name, obj, off, _ = solids[k]
            obj.setTranslation(c + off)
            d = fcl.distance(obj, self._part, request, fcl.DistanceResult())
            d = max(float(d), 0.0)
            if d < best:
                best, which = d, name
                if d == 0.0:
                    break
        return best, which

    def solid_distances(self, ball_centre: ArrayLike, probe: ProbeGeometry) -> dict[str, float]:
        """Each solid's distance to the part (0: touching, overlapping or inside), or where the
        gap between its box and the part's is positive, that gap: a lower bound, enough to know
        it cannot touch and how far the probe may travel before it could."""
        c = np.asarray(ball_centre, dtype=np.float64)
        out = {}
        request = fcl.DistanceRequest()
        near = False
        for name, obj, off, half in self._probe_solids(probe):
            gap = self._box_gap(c + off, half)
            if gap > 0:
                out[name] = gap
                continue
            near = True
            obj.setTranslation(c + off)
            out[name] = max(float(fcl.distance(obj, self._part, request, fcl.DistanceResult())), 0.0)
        if near:  # a solid wholly inside the material has no triangle near it: test its centre
            for name in self.inside_all(c, probe):
                out[name] = 0.0
        return out

    def _box_gap(self, centre: FloatArray, half: FloatArray) -> float:
        gap = np.maximum(np.maximum(self._part_lo - (centre + half), (centre - half) - self._part_hi), 0.0)
        return float(np.linalg.norm(gap))

    def inside_all(self, ball_centre: ArrayLike, probe: ProbeGeometry) -> list[str]:
        """The solids whose centre lies inside the material."""
        c = np.asarray(ball_centre, dtype=np.float64)
        d = probe.direction
        h = probe.head_centre(c)
        pts = {"ball": c, "stylus": c - 0.5 * probe.stylus_length_m * d,
               "body": c - (probe.stylus_length_m + 0.5 * probe.body_length_m) * d, "head": h}
        sd = self.index.signed_distance(np.array(list(pts.values())))
        return [name for name, s in zip(pts, sd, strict=True) if s < 0]

    def inside(self, ball_centre: ArrayLike, probe: ProbeGeometry) -> str | None:
        """The first solid whose centre lies inside the material, or None."""
        found = self.inside_all(ball_centre, probe)
        return found[0] if found else None

    def check_position(self, ball_centre: ArrayLike, probe: ProbeGeometry) -> MoveCheck:
        """Is the probe at rest at ``ball_centre`` at least the clearance away from the part?"""
        c = np.asarray(ball_centre, dtype=np.float64)
        inside = self.inside(c, probe)
        if inside is not None:
            return MoveCheck(False, 0.0, c, inside, 0.0, 1)
        d, which = self.distance(c, probe)
        if d < self.clearance_m:
            return MoveCheck(False, 0.0, c, which, d, 1)
        return MoveCheck(True, queries=1)

    def check_move(self, start: ArrayLike, end: ArrayLike, probe: ProbeGeometry) -> MoveCheck:
        """Sweep the probe from ball centre ``start`` to ``end`` (part frame) [m]."""
        a = np.asarray(start, dtype=np.float64)
        b = np.asarray(end, dtype=np.float64)
        first = self.check_position(a, probe)
        if not first.clear:
            return first
        length = float(np.linalg.norm(b - a))
        s, queries = 0.0, 1
        while True:
            c = a + s * (b - a) if length > 0 else a
            d, which = self.distance(c, probe)
            queries += 1
            if d < self.clearance_m:
                return MoveCheck(False, s, c, which, d, queries)
            if s >= 1.0 or length == 0.0:
                return MoveCheck(True, queries=queries)
            s = min(1.0, s + max(d - self.clearance_m, self.step_floor_m) / length)

    def check_path(self, points: ArrayLike, probe: ProbeGeometry) -> tuple[int, MoveCheck] | None:
        """The first move of a polyline of ball centres that is not clear (its index and check)."""
        pts = np.asarray(points, dtype=np.float64)
        for i in range(len(pts) - 1):
            res = self.check_move(pts[i], pts[i + 1], probe)
            if not res.clear:
                return i, res
        return None
