"""Reach and base placement: can the arm reach every scan and path pose from its base, and
where on the table should the base stand so that it can?

The test is the UR5e's closed-form inverse kinematics (``algorithms.geometry.kinematics.
ur_inverse``) on the flange poses, on one branch: the branch of ``HOME_Q`` (shoulder, elbow
and wrist on the same side as the home posture), which is the branch the mink IK of the scan
and the paths starts from and stays on as long as no singularity is crossed. A pose is
reachable when that branch has a solution with both the elbow and the wrist-1 joint above the
table; its margin is the smallest of

* ``|sin q3|`` (0 with the arm stretched to its reach, or folded),
* ``|sin q5|`` (0 at the wrist singularity),
* the wrist centre's distance from the shoulder-singular cylinder over ``SHOULDER_SCALE_M``.

The margin does not depend on the base's yaw (turning the base about its z axis only shifts
q1), so the search runs over x and y on a grid around the part and then refines the best
cells; the yaw is kept unless the part lies behind the base (then the base turns to face it,
so that the arm starts from its home posture towards the part).

Targets: the scan plan's sensor poses (``twin.plan.plan_scan`` on the nominal cell; the plan is
in the world frame and does not depend on the base) and the CAD raster path's flange poses
(``twin.process_paths.cad_path`` moved by the nominal pose), as flange poses in the world.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

from algorithms.errors import AlgorithmError
from algorithms.geometry.kinematics import dh_forward, ur_inverse
from algorithms.geometry.se3 import inv_pose
from algorithms.paths.toolpath import flange_poses, transform_path
from twin.errors import TwinError
from twin.robot import HOME_Q, UR5E_DH
from twin.scenario import Scenario

#: A pose counts as reachable only with at least this margin (about 6 deg from the elbow and
#: wrist singularities, 10 mm from the shoulder one).
MIN_MARGIN = 0.1
#: Margins above this are all equally good: beyond it the search prefers the smaller move.
COMFORT_MARGIN = 0.3
SHOULDER_SCALE_M = 0.1
#: The elbow and the wrist-1 joint stay this high above the table plane [m].
TABLE_CLEARANCE_M = 0.06
#: The base's centre stays this far from the part's footprint [m] (base radius 75 mm + room).
BASE_CLEARANCE_M = 0.15
#: Search: grid around the part centre, then a finer grid around the best cells.
SEARCH_HALF_WIDTH_M = 0.9
COARSE_STEP_M = 0.1
FINE_STEP_M = 0.025
REFINE_BEST = 6
#: Scan poses are taken every this many plan steps (1 ms each), plus every line's ends.
SCAN_STRIDE = 20
COARSE_POSES = 300
FINE_POSES = 1000
BATCH_BASES = 64
#: Score = min(margin, COMFORT_MARGIN) - MOVE_COST_PER_M * move - YAW_COST_PER_RAD * turn.
MOVE_COST_PER_M = 0.1
YAW_COST_PER_RAD = 0.01
SAME_BASE_M = 1e-3
#: Distance [m] of the planning base from the part centre when an automatic plan must be redone.
PLANNING_DISTANCE_M = 0.45
SAME_BASE_RAD = np.radians(0.1)


def _home_branch() -> int:
    sol = ur_inverse(dh_forward(HOME_Q, UR5E_DH), UR5E_DH)
    dq = np.abs(np.angle(np.exp(1j * (sol.q[0] - HOME_Q))))
    return int(np.nanargmin(np.nanmax(dq, axis=1)))


#: The ``ur_inverse`` branch of the home posture (the branch the mink IK stays on).
HOME_BRANCH = _home_branch()


@dataclass(frozen=True)
class ReachTargets:
    """Flange poses the arm must reach, in the world frame.

    Attributes:
        T_world_flange: (N, 4, 4).
        source: (N,) "scan" or "path", where each pose comes from.
        T_world_workpiece: (4, 4) the nominal part pose.
        footprint_world_m: (M, 2) the part's footprint hull in the world xy plane [m].
        notes: what could not be included (a path that could not be built), one phrase each.
    """

    T_world_flange: np.ndarray
    source: np.ndarray
    T_world_workpiece: np.ndarray
    footprint_world_m: np.ndarray
    notes: tuple[str, ...] = ()

    def __len__(self) -> int:
        return len(self.T_world_flange)

    def subset(self, n: int) -> ReachTargets:
        """About ``n`` poses spread evenly over the targets."""
        if len(self) <= n:
            return self
        idx = np.unique(np.linspace(0, len(self) - 1, n).round().astype(int))
        return dataclasses.replace(self, T_world_flange=self.T_world_flange[idx], source=self.source[idx])


@dataclass(frozen=True)
class Reach:
    """The reach test of one base pose.

    Attributes:
        reachable: (N,) bool, the home branch reaches the pose with ``MIN_MARGIN`` and above the table.
        margin: (N,) the pose's margin (module docstring); -inf where there is no solution.
        q: (N, 6) the home-branch joint angles [rad], NaN where there is none.
    """

    reachable: np.ndarray
    margin: np.ndarray
    q: np.ndarray

    @property
    def all_reachable(self) -> bool:
        return bool(self.reachable.all())

    @property
    def min_margin(self) -> float:
        return float(self.margin.min()) if len(self.margin) else np.inf


@dataclass(frozen=True)
class BaseSuggestion:
    """A base pose on the table that reaches every target.

    Attributes:
        T_world_base: (4, 4) on the table plane (z = 0, yaw only).
        margin: the smallest margin over the targets.
        description: one phrase, e.g. "x = 0.120 m, y = -0.300 m, yaw = 30.0 deg".
        candidates: how many base poses were tested.
        time_s: search time [s].
    """

    T_world_base: np.ndarray
    margin: float
    description: str
    candidates: int
    time_s: float


def base_pose(x_m: float, y_m: float, yaw_rad: float) -> np.ndarray:
    """``T_world_base`` on the table plane: at (x, y, 0), turned by ``yaw_rad`` about z."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = x_m, y_m
    return T


def _yaw(T: np.ndarray) -> float:
    return float(np.arctan2(T[1, 0], T[0, 0]))


def describe_base(T_world_base: np.ndarray) -> str:
    return (f"x = {T_world_base[0, 3]:.3f} m, y = {T_world_base[1, 3]:.3f} m, "
            f"yaw = {np.degrees(_yaw(T_world_base)):.1f} deg")


def reach(T_world_base: np.ndarray, T_world_flange: np.ndarray, branch: int = HOME_BRANCH) -> Reach:
    """Reach test of flange poses (world) from one base pose (module docstring)."""
    reachable, margin, q = _reach_many(np.asarray(T_world_base)[None], np.asarray(T_world_flange), branch)
    return Reach(reachable[0], margin[0], q[0])


def _reach_many(T_world_bases: np.ndarray, T_world_flange: np.ndarray, branch: int = HOME_BRANCH):
    """(reachable, margin, q) of N flange poses from C base poses: (C, N), (C, N), (C, N, 6)."""
    c, n = len(T_world_bases), len(T_world_flange)
    T_base_flange = np.einsum("cij,njk->cnik", inv_poses(T_world_bases), T_world_flange).reshape(-1, 4, 4)
    sol = ur_inverse(T_base_flange, UR5E_DH, branches=(branch,))
    q = sol.q[:, branch]
    ok = sol.valid[:, branch]
    a2, a3, d1 = UR5E_DH.a[1], UR5E_DH.a[2], UR5E_DH.d[0]
    # Heights of the elbow (DH frame 2) and of the wrist-1 joint (frame 3) above the base plane;
    # the base stands on the table (z = 0, turned about z only).
    with np.errstate(invalid="ignore"):
        z_elbow = d1 + a2 * np.sin(q[:, 1])
        z_wrist = z_elbow + a3 * np.sin(q[:, 1] + q[:, 2])
        above = (z_elbow >= TABLE_CLEARANCE_M) & (z_wrist >= TABLE_CLEARANCE_M)
    margin = np.minimum(np.minimum(sol.elbow_sin[:, branch], sol.wrist_sin[:, branch]),
                        sol.shoulder_m / SHOULDER_SCALE_M)
    margin = np.where(ok, margin, -np.inf)
    reachable = ok & above & (margin >= MIN_MARGIN)
    return reachable.reshape(c, n), margin.reshape(c, n), q.reshape(c, n, 6)


def inv_poses(T: np.ndarray) -> np.ndarray:
    """Inverses of (C, 4, 4) rigid transforms."""
    out = np.zeros_like(T)
    R_t = np.swapaxes(T[:, :3, :3], 1, 2)
    out[:, :3, :3] = R_t
    out[:, :3, 3] = -np.einsum("cij,cj->ci", R_t, T[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


def reach_targets(scenario: Scenario, realized=None) -> ReachTargets:
    """The flange poses of the scenario's scan plan and CAD path, in the world frame.

    A fixed plan is in the world frame and does not depend on the base. An automatic plan
    (``scan.passes = "auto"``) skips the views the arm cannot reach from the base; when it
    skips some or fails, it is planned again from a base at ``PLANNING_DISTANCE_M`` in front
    of the part (on the side of the scenario's base, facing the part), and the plan with more
    passes is kept.
    """
    from twin.process_paths import cad_path
    from twin.realize import realize

    if realized is None:
        realized = realize(scenario)
    T_wp = scenario.workpiece.T_world_workpiece_nominal
    xy = (realized.workpiece.mesh.vertices @ T_wp[:3, :3].T + T_wp[:3, 3])[:, :2]
    hull = xy[ConvexHull(xy).vertices]
    plan = _plan_for_reach(realized, hull.mean(axis=0))
    keep = np.zeros(len(plan.t), dtype=bool)
    keep[::SCAN_STRIDE] = True
    keep[-1] = True
    change = np.flatnonzero(np.diff(plan.line) != 0)
    keep[change] = keep[np.minimum(change + 1, len(keep) - 1)] = True
    T_scan = plan.T_world_sensor[keep] @ inv_pose(scenario.sensor.T_flange_sensor)
    parts, sources, notes = [T_scan], [np.full(len(T_scan), "scan")], []
    try:
        path = transform_path(T_wp, cad_path(realized))
        T_path = flange_poses(path.T_tool, scenario.path.T_flange_tool)
        parts.append(T_path)
        sources.append(np.full(len(T_path), "path"))
    except (TwinError, AlgorithmError) as exc:
        notes.append(f"the CAD path was left out ({exc})")
    return ReachTargets(np.concatenate(parts), np.concatenate(sources), T_wp.copy(), hull, tuple(notes))


def _plan_for_reach(realized, center: np.ndarray):
    """The scan plan on the nominal cell; for an automatic plan that skipped views or failed,
    the plan from a base in front of the part when it has more passes (see reach_targets)."""
    from twin.cell import build_cell
    from twin.plan import plan_scan

    scenario = realized.scenario
    error: TwinError | None = None
    try:
        plan = plan_scan(build_cell(realized, "nominal"))
    except TwinError as exc:
        plan, error = None, exc
    if plan is not None and not plan.notes:
        return plan
    to_base = scenario.T_world_base[:2, 3] - center
    norm = float(np.linalg.norm(to_base))
    u = to_base / norm if norm > 1e-6 else np.array([-1.0, 0.0])
    xy = center + PLANNING_DISTANCE_M * u
    T = base_pose(xy[0], xy[1], float(np.arctan2(-u[1], -u[0])))
    moved = dataclasses.replace(realized, scenario=with_base(scenario, T))
    try:
        other = plan_scan(build_cell(moved, "nominal"))
    except TwinError:
        other = None
    if other is not None and (plan is None or len(other.passes) > len(plan.passes)):
        return other
    if plan is None:
        assert error is not None  # the first plan failed
        raise error
    return plan


def _distance_to_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Distance [m] of 2-D points from a convex polygon (0 inside)."""
    a = polygon
    b = np.roll(polygon, -1, axis=0)
    ab = b - a
    ap = points[:, None, :] - a[None]
    t = np.clip(np.einsum("pkj,kj->pk", ap, ab) / np.einsum("kj,kj->k", ab, ab), 0.0, 1.0)
    d = np.linalg.norm(ap - t[..., None] * ab[None], axis=2).min(axis=1)
    cross = ab[None, :, 0] * ap[..., 1] - ab[None, :, 1] * ap[..., 0]
    inside = np.all(cross >= 0, axis=1) | np.all(cross <= 0, axis=1)
    return np.where(inside, 0.0, d)


def _facing_yaw(xy: np.ndarray, yaw_rad: float, center: np.ndarray) -> float:
    """The scenario's yaw, unless the part lies behind the base: then the yaw that faces it."""
    to_part = center - xy
    heading = np.array([np.cos(yaw_rad), np.sin(yaw_rad)])
    if float(to_part @ heading) >= 0.0:
        return yaw_rad
    return float(np.arctan2(to_part[1], to_part[0]))


def _score(margin: float, T_world_base: np.ndarray, T_from: np.ndarray) -> float:
    move = float(np.linalg.norm(T_world_base[:2, 3] - T_from[:2, 3]))
    turn = abs(float(np.angle(np.exp(1j * (_yaw(T_world_base) - _yaw(T_from))))))
    return min(margin, COMFORT_MARGIN) - MOVE_COST_PER_M * move - YAW_COST_PER_RAD * turn


def _evaluate(xy: np.ndarray, targets: ReachTargets, T_from: np.ndarray, center: np.ndarray):
    """(score, margin, T_world_base) of each candidate position; score -inf where a pose fails."""
    yaw0 = _yaw(T_from)
    bases = np.array([base_pose(p[0], p[1], _facing_yaw(p, yaw0, center)) for p in xy]).reshape(-1, 4, 4)
    out = []
    for i0 in range(0, len(bases), BATCH_BASES):
        ok, margin, _ = _reach_many(bases[i0:i0 + BATCH_BASES], targets.T_world_flange)
        for T, ok_c, m_c in zip(bases[i0:i0 + BATCH_BASES], ok, margin, strict=True):
            m = float(m_c.min())
            out.append((_score(m, T, T_from) if ok_c.all() else -np.inf, m, T))
    return out


def _grid(center: np.ndarray, half_width: float, step: float) -> np.ndarray:
    u = np.arange(-half_width, half_width + 1e-9, step)
    gx, gy = np.meshgrid(center[0] + u, center[1] + u, indexing="ij")
    return np.column_stack([gx.ravel(), gy.ravel()])


def suggest_base(scenario: Scenario, targets: ReachTargets | None = None) -> BaseSuggestion | None:
    """A base pose on the table plane that reaches every scan and path pose with the most
    margin (up to ``COMFORT_MARGIN``) and the least move from the scenario's base; None if no
    position on the table within ``SEARCH_HALF_WIDTH_M`` of the part reaches them all."""
    t0 = time.perf_counter()
    if targets is None:
        targets = reach_targets(scenario)
    T_from = scenario.T_world_base
    center = targets.footprint_world_m.mean(axis=0)
    coarse = targets.subset(COARSE_POSES)

    xy = _grid(center, SEARCH_HALF_WIDTH_M, COARSE_STEP_M)
    xy = np.vstack([T_from[:2, 3], xy])
    xy = xy[_distance_to_polygon(xy, targets.footprint_world_m) >= BASE_CLEARANCE_M]
    reach_m = abs(UR5E_DH.a[1]) + abs(UR5E_DH.a[2]) + UR5E_DH.d[4] + UR5E_DH.d[5]
    flange_xy = coarse.T_world_flange[:, :2, 3]
    far = np.linalg.norm(xy[:, None] - flange_xy[None], axis=2).max(axis=1)
    xy = xy[far <= reach_m + 0.05]
    n_tested = len(xy)
    scored = _evaluate(xy, coarse, T_from, center)
    order = np.argsort([-s for s, _, _ in scored])
    best = [xy[i] for i in order[:REFINE_BEST] if np.isfinite(scored[i][0])]
    if not best:
        return None

    candidates = [T_from[:2, 3]] + [p + d for p in best for d in _grid(np.zeros(2), 2 * FINE_STEP_M, FINE_STEP_M)]
    fine = np.unique(np.round(np.array(candidates), 9), axis=0)
    fine = fine[_distance_to_polygon(fine, targets.footprint_world_m) >= BASE_CLEARANCE_M]
    n_tested += len(fine)
    scored = [s for s in _evaluate(fine, targets.subset(FINE_POSES), T_from, center) if np.isfinite(s[0])]
    # The best on the sample, checked on every pose (in order, until one passes).
    for _, _, T in sorted(scored, key=lambda s: -s[0]):
        r = reach(T, targets.T_world_flange)
        if r.all_reachable:
            return BaseSuggestion(T, r.min_margin, describe_base(T), n_tested, time.perf_counter() - t0)
    return None


def same_base(T_a: np.ndarray, T_b: np.ndarray) -> bool:
    turn = abs(float(np.angle(np.exp(1j * (_yaw(T_a) - _yaw(T_b))))))
    return bool(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]) < SAME_BASE_M and turn < SAME_BASE_RAD)


def with_base(scenario: Scenario, T_world_base: np.ndarray) -> Scenario:
    """A copy of the scenario with ``robot.base_pose`` replaced (the raw table too)."""
    raw = dict(scenario.raw)
    raw["robot"] = {**raw.get("robot", {}), "base_pose": {"matrix": T_world_base.tolist()}}
    return dataclasses.replace(scenario, T_world_base=T_world_base.copy(), raw=raw)


def place_base(scenario: Scenario, targets: ReachTargets | None = None) -> tuple[Scenario, dict]:
    """The scenario with its base moved to :func:`suggest_base`'s pose, and a dict for the
    report (old and new base, margins, search time). ``targets``: the scenario's
    :func:`reach_targets`, when the caller has them already.

    Raises:
        TwinError: the base is not on the table plane, or no position on the table reaches
            every scan and path pose.
    """
    T_old = scenario.T_world_base
    if abs(T_old[2, 3]) > 1e-9 or abs(T_old[2, 2] - 1.0) > 1e-9:
        raise TwinError("--place-base searches the table plane: robot.base_pose must be at z = 0 "
                        "and turned about z only")
    t0 = time.perf_counter()
    if targets is None:
        targets = reach_targets(scenario)
    old = reach(T_old, targets.T_world_flange)
    suggestion = suggest_base(scenario, targets)
    if suggestion is None:
        raise TwinError(f"no base position on the table within {SEARCH_HALF_WIDTH_M:g} m of the part reaches "
                        f"every scan and path pose ({len(targets)} poses tested)")
    info = {
        "old_base": describe_base(T_old),
        "new_base": suggestion.description,
        "T_world_base_old": T_old.tolist(),
        "T_world_base": suggestion.T_world_base.tolist(),
        "moved": not same_base(T_old, suggestion.T_world_base),
        "old_unreachable_poses": int((~old.reachable).sum()),
        "old_margin": float(old.min_margin) if np.isfinite(old.min_margin) else None,
        "margin": round(suggestion.margin, 4),
        "poses": len(targets),
        "scan_poses": int((targets.source == "scan").sum()),
        "path_poses": int((targets.source == "path").sum()),
        "candidates": suggestion.candidates,
        "notes": list(targets.notes),
        "time_s": round(time.perf_counter() - t0, 3),
    }
    return with_base(scenario, suggestion.T_world_base), info


def describe_unreachable_fix(scenario: Scenario, targets: ReachTargets | None = None) -> str | None:
    """One phrase suggesting a base that reaches every scan and path pose, or None (nothing on
    the table does, or the suggestion is the scenario's own base). ``targets`` as for
    :func:`place_base` (``reach_targets(scenario, realized)`` reuses a realized scenario)."""
    try:
        suggestion = suggest_base(scenario, targets)
    except (TwinError, AlgorithmError):
        return None
    if suggestion is None or same_base(suggestion.T_world_base, scenario.T_world_base):
        return None
    T = suggestion.T_world_base
    return (f"a base at x = {T[0, 3]:.3f} m, y = {T[1, 3]:.3f} m, yaw = {np.degrees(_yaw(T)):.1f} deg "
            "reaches every scan and path pose: run with --place-base")
