"""The automatic multi-pass planner (``scan.passes = "auto"``): views picked greedily on the CAD model.

Candidate views are straight down and tilted cones at evenly spaced azimuths
(:func:`candidate_views`), each a fixed-beam pass over the whole part whose lines come from
:func:`twin.plan.lines.pass_runs`. Each round adds the view whose new lines raise the smallest
relative eigenvalue of the predicted information the most (the top view first), if the scan's
IK follows its moves from where the passes before left the arm (:func:`_unreachable`).

Frames: views, points and normals in the workpiece frame; sensor poses in the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import mujoco
import mujoco.batch
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from algorithms.arraytypes import FloatArray, Pose
from twin.cell import Cell
from twin.errors import TwinError
from twin.plan.lines import (
    PassInfo,
    _climb,
    _interp_poses,
    _part_top_world_m,
    _pass_lines,
    _predicted,
    _Run,
    _view3,
    pass_runs,
)
from twin.robot import HOME_Q
from twin.scenario import AutoPlanSpec, PassSpec, ScanSpec

if TYPE_CHECKING:
    from twin.ik import IKSolver

# Auto planner: a candidate view's line is new when at least NEW_FRACTION of its points have
# no point of an earlier pass within one line spacing whose normal is within NEW_NORMAL_DEG.
NEW_FRACTION = 0.5
NEW_NORMAL_DEG = 30.0
# Reachability check of a view: the scan's IK follows its moves in steps of at most these.
REACH_STEP_M = 0.01
REACH_STEP_RAD = 0.1
REACH_ITERATIONS = 200


@dataclass(frozen=True)
class AutoPlan:
    """The automatic planner's choice: passes, their lines (runs) and why each was chosen."""

    passes: tuple[PassSpec, ...]
    runs: tuple[list[_Run], ...]
    infos: tuple[PassInfo, ...]
    notes: tuple[str, ...]


_AZIMUTH_LABELS = {0: "+x", 45: "+x+y", 90: "+y", 135: "-x+y", 180: "-x", 225: "-x-y", 270: "-y", 315: "+x-y"}


def candidate_views(spec: ScanSpec, auto: AutoPlanSpec) -> list[PassSpec]:
    """Straight down, then each tilt at evenly spaced azimuths, as fixed-beam passes over the
    whole part (workpiece frame). A tilted view's lines run level, across its azimuth, so that
    they follow the edges of the faces it looks at."""
    top_axis = (1.0, 0.0, 0.0) if spec.line_axis == "x" else (0.0, 1.0, 0.0)
    views = [("top view", np.array([0.0, 0.0, -1.0]), np.array(top_axis))]
    for tilt in auto.tilts_deg:
        t = np.radians(tilt)
        for k in range(auto.azimuths):
            deg = 360.0 * k / auto.azimuths
            a = np.radians(deg)
            label = _AZIMUTH_LABELS.get(int(round(deg)), f"azimuth {deg:g} deg") \
                if abs(deg - round(deg)) < 1e-9 else f"azimuth {deg:g} deg"
            view = np.array([-np.sin(t) * np.cos(a), -np.sin(t) * np.sin(a), -np.cos(t)])
            views.append((f"tilted {tilt:g} deg from {label}", view, np.array([-np.sin(a), np.cos(a), 0.0])))
    return [PassSpec(name, "fixed", view, None, axis, spec.line_spacing_m, spec.speed_m_s, spec.transit_speed_m_s,
                     spec.standoff_m, spec.retract_m, 0.001, spec.max_lines) for name, view, axis in views]


def _new_runs(runs: list[_Run], tree: cKDTree, normals: np.ndarray, radius_m: float) -> list[_Run]:
    """The runs that mostly see surface no earlier pass saw (a point is seen when an earlier
    point lies within ``radius_m`` with a normal within NEW_NORMAL_DEG)."""
    out = []
    cos_max = np.cos(np.radians(NEW_NORMAL_DEG))
    for r in runs:
        dist, idx = tree.query(r.points_wp, k=8, distance_upper_bound=radius_m)
        near = np.isfinite(dist)
        idx = np.where(near, idx, 0)
        similar = near & (np.einsum("nkj,nj->nk", normals[idx], r.smooth_normals_wp) >= cos_max)
        if np.mean(~similar.any(axis=1)) >= NEW_FRACTION:
            out.append(r)
    return out


@dataclass
class _ReachState:
    """Where the reachability check of the chosen passes left the arm (nominal cell)."""

    solver: IKSolver
    T_world_sensor: Pose | None = None


@dataclass(frozen=True)
class _Reached:
    """The end of a reachable view's moves: the solver's joints [rad] and the last sensor pose (world)."""

    q: FloatArray
    T_world_sensor: Pose


def _densify(T_a: Pose, T_b: Pose) -> FloatArray:
    """Poses from ``T_a`` (excluded) to ``T_b`` at most REACH_STEP_M / REACH_STEP_RAD apart."""
    length = float(np.linalg.norm(T_b[:3, 3] - T_a[:3, 3]))
    ang = float(np.linalg.norm(Rotation.from_matrix(T_a[:3, :3].T @ T_b[:3, :3]).as_rotvec()))
    n = max(1, int(np.ceil(max(length / REACH_STEP_M, ang / REACH_STEP_RAD))))
    return _interp_poses(np.stack([T_a, T_b]), np.array([0.0, 1.0]), np.arange(1, n + 1) / n)


def _view_key_poses(cell: Cell, p: PassSpec, runs: list[_Run]) -> list[Pose]:
    """Every line's approach, ends and retract (world), in the order the scan visits them."""
    keys = []
    for ln in _pass_lines(cell, p, 0, runs, 0):
        above = ln.T_world_sensor[0].copy()
        above[:3, 3] -= ln.retract_m * above[:3, 2]
        retract = ln.T_world_sensor[-1].copy()
        retract[:3, 3] -= ln.retract_m * retract[:3, 2]
        keys.extend([above, ln.T_world_sensor[0], ln.T_world_sensor[-1], retract])
    return keys


def _unreachable(cell: Cell, p: PassSpec, runs: list[_Run], state: _ReachState) -> str | _Reached:
    """Follow the view's moves with the scan's IK on the nominal cell, from where the passes
    before it left the arm: the transit over the part, then every line's approach, ends and
    retract (in steps of REACH_STEP_M / REACH_STEP_RAD, each warm-started from the last).

    Returns:
        The solver's joints and the last key pose when every key pose is reached, else why
        not (the solver is then left where it started).
    """
    from twin.ik import reachable

    solver = state.solver
    q_before = solver.q
    keys = _view_key_poses(cell, p, runs)
    if state.T_world_sensor is None:
        # The first pose of the scan is solved from the home configuration, as the scan does.
        solver.set_q(HOME_Q)
        path = [(keys[0], True)]
        pe, oe, _ = solver.solve(keys[0], dt=0.05, max_iterations=1000, velocity_limited=False)
        prev = keys[0]
    else:
        prev = state.T_world_sensor
        height = max(_part_top_world_m(cell) + cell.scenario.scan.transit_clearance_m, prev[2, 3], keys[0][2, 3])
        up, down = _climb(prev, height), _climb(keys[0], height)
        path = [(up, False), (down, False)]
    path.extend((T, True) for T in keys)
    for T_key, is_key in path:
        for T in _densify(prev, T_key):
            pe, oe, _ = solver.solve(T, dt=0.05, max_iterations=REACH_ITERATIONS, velocity_limited=False)
        prev = T_key
        if is_key and not reachable(pe, oe):
            solver.set_q(q_before)
            x, y, z = T_key[:3, 3]
            return (f"the arm cannot reach its sensor pose at world ({x:.3f}, {y:.3f}, {z:.3f}) m "
                    f"({pe * 1e3:.2f} mm / {np.degrees(oe):.2f} deg off)")
    q_after = solver.q
    solver.set_q(q_before)
    return _Reached(q_after, keys[-1])


# A candidate view scored in one round: (smallest relative eigenvalue with it, the view, its
# new runs, the coordinate directions fixed with it).
_Scored = tuple[float, PassSpec, list[_Run], tuple[str, ...]]


@dataclass
class _Greedy:
    """The automatic planner's state between rounds (points and normals in the workpiece frame)."""

    cands: list[tuple[PassSpec, list[_Run]]]
    reach: _ReachState
    passes: list[PassSpec] = field(default_factory=list)
    chosen_runs: list[list[_Run]] = field(default_factory=list)
    infos: list[PassInfo] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    points: FloatArray = field(default_factory=lambda: np.empty((0, 3)))
    normals: FloatArray = field(default_factory=lambda: np.empty((0, 3)))
    rel_now: float = 0.0
    fixed_now: tuple[str, ...] = ()


def _candidate_runs(cell: Cell, spec: ScanSpec, auto: AutoPlanSpec) -> list[tuple[PassSpec, list[_Run]]]:
    """The candidate views that see the part, with their lines."""
    batch = mujoco.batch.Batch(cell.model, 1, nthread=1)
    index = cell.index
    cands = []
    for p in candidate_views(spec, auto):
        runs = pass_runs(cell, batch, p, index)
        if runs:
            cands.append((p, runs))
    if not cands:
        raise TwinError("scan.passes = \"auto\": no candidate view sees the part within the sensor's incidence limit")
    return cands


def _score_views(st: _Greedy, line_spacing_m: float, target: float) -> list[_Scored]:
    """Every remaining candidate with the lines that see new surface, scored by the union's
    smallest relative eigenvalue: the top view first (while it is a candidate), then the best."""
    scored = []
    tree = cKDTree(st.points) if len(st.points) else None
    for p, runs in st.cands:
        new = runs if tree is None else _new_runs(runs, tree, st.normals, line_spacing_m)
        if not new:
            continue
        rel, fixed = _predicted(np.concatenate([st.points] + [r.points_wp for r in new]),
                                np.concatenate([st.normals] + [r.smooth_normals_wp for r in new]), target)
        scored.append((rel, p, new, fixed))
    scored.sort(key=lambda sc: (sc[1].name != "top view", -sc[0]))
    return scored


def _first_reachable(cell: Cell, st: _Greedy, scored: list[_Scored]) -> _Scored | None:
    """The first scored view that raises the eigenvalue and that the arm reaches (the arm then
    left at its end); the unreachable ones before it are dropped and noted."""
    for rel, p, new, fixed in scored:
        if st.passes and rel <= st.rel_now * (1.0 + 1e-6):
            return None
        result = _unreachable(cell, p, new, st.reach)
        if isinstance(result, _Reached):
            st.reach.solver.set_q(result.q)
            st.reach.T_world_sensor = result.T_world_sensor
            return rel, p, new, fixed
        st.notes.append(f"{p.name}: skipped, {result}")
        st.cands = [c for c in st.cands if c[0] is not p]
    return None


def _pass_reason(st: _Greedy, p: PassSpec, rel: float, gained: list[str]) -> str:
    """Why the view is added: the first view, the directions it fixes, or the raise it gives."""
    if not st.passes:
        first = "covers the part from above" if p.name == "top view" else "the first view the arm reaches"
        return f"{p.name}: {first}" + (f"; fixes {', '.join(gained)}" if gained else "")
    if gained:
        return f"{p.name}: fixes {', '.join(gained)}"
    return f"{p.name}: raises the smallest relative eigenvalue from {st.rel_now:.2g} to {rel:.2g}"


def _add_pass(st: _Greedy, pick: _Scored) -> None:
    """Add the picked view to the plan and its points to the union."""
    rel, p, new, fixed = pick
    st.cands = [c for c in st.cands if c[0] is not p]
    gained = [f for f in fixed if f not in st.fixed_now]
    st.infos.append(PassInfo(p.name, p.beam, _view3(p.view), 0, 0, _pass_reason(st, p, rel, gained), rel, fixed))
    st.passes.append(p)
    st.chosen_runs.append(new)
    st.points = np.concatenate([st.points] + [r.points_wp for r in new])
    st.normals = np.concatenate([st.normals] + [r.smooth_normals_wp for r in new])
    st.rel_now, st.fixed_now = rel, fixed


def plan_auto_passes(cell: Cell, spec: ScanSpec, auto: AutoPlanSpec) -> AutoPlan:
    """Pick views greedily until the predicted points fix all six pose directions.

    The top view comes first (it covers what a process from above works on). Then, each round,
    every remaining candidate view keeps the lines that see new surface, and the one whose
    points raise the union's smallest relative eigenvalue the most is added, if the arm
    reaches it from where the passes before left it (else it is skipped and noted; an
    unreachable top view leaves the first place to the best view the arm reaches), until that eigenvalue reaches
    ``auto.min_relative_eigenvalue``, no view adds anything, or ``auto.max_passes`` are planned.

    Raises:
        TwinError: no candidate view sees the part, or the arm reaches none.
    """
    cands = _candidate_runs(cell, spec, auto)
    from twin.ik import IKSolver

    st = _Greedy(cands, _ReachState(IKSolver(cell.model, cell.sensor.site, 1e-6, 1e-5)))
    target = auto.min_relative_eigenvalue
    while len(st.passes) < auto.max_passes and st.rel_now < target and st.cands:
        pick = _first_reachable(cell, st, _score_views(st, spec.line_spacing_m, target))
        if pick is None:
            break
        _add_pass(st, pick)
    if not st.passes:
        raise TwinError("scan.passes = \"auto\": the arm reaches no candidate view (" + "; ".join(st.notes) + ")")
    if st.rel_now < target:
        weak = [c for c in ("x", "y", "z", "rx", "ry", "rz") if c not in st.fixed_now]
        st.notes.append(f"the planned views reach a smallest relative eigenvalue of {st.rel_now:.2g}, below the "
                        f"target {target:g}" + (f"; {', '.join(weak)} stay weak" if weak else ""))
    return AutoPlan(tuple(st.passes), tuple(st.chosen_runs), tuple(st.infos), tuple(st.notes))
