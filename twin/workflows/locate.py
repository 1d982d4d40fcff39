"""Locate-then-machine (document 001): a sparse laser pass, a coarse pose, planned touch
probing, document 001's fine stage, ``T = T_fine T_coarse``. Returns a frozen
:class:`LocateResult`; writes no files.

1. coarse laser pass: a level raster over the nominal footprint grown by
   ``locate.coarse_margin_m``, with ``[locate]``'s line spacing and speed (1 ms, true cell;
   :func:`twin.plan.plan_level_raster`); points within ``TABLE_BAND_M`` of the table plane are
   left out (the cell knows its table);
2. coarse pose, from no prior knowledge of the orientation (``locate.coarse``):
   ``multistart`` (document 000's Algorithm 5 with a Hong-Tan polish on the coarse points),
   ``ga`` (document 001's genetic algorithm with its constants, one run, its pose as it
   comes) or ``ga_restarts`` (up to ten runs, each checked by a short exact descent, then
   document 001's fine stage and a polish on the laser points);
3. probe qualification on the cell's reference sphere: the effective ball radius (which
   absorbs the mean sideways pre-travel) and the ball-centre offset (which absorbs the
   axial excess and any error of the probe's mount), as a CMM qualifies a stylus;
4. fine points planned on the CAD model moved by ``T_coarse``
   (:mod:`algorithms.probing.point_planning`): candidates on the part's surface that a
   straight-down stylus can touch along the normal, away from edges, with a clear approach
   and search, reachable by the arm; of those, ``probe.points`` chosen D-optimally (or
   spread, or at random, ``locate.planner``);
5. probing in the true cell (:mod:`twin.probing`);
6. document 001's fine stage (``fine_001``, variable iteration centre) on the compensated
   points from ``T_coarse``; the compensation's normals come from the CAD model at the
   current estimate, and are re-evaluated at the new estimate until it stops moving.

The covariance of the final pose combines the probe's repeatability, the pre-travel
variation left after qualification (a Type B term: uniform within the model's 3D pre-travel
variation), the encoders' noise propagated through the arm's Jacobian, and the
qualification's own uncertainty (effective radius and ball-centre offset: systematic, the
same for every point). Robot kinematic and hand-eye errors are not in it: a scenario that
switches them on is reported with that said.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from algorithms.geometry.kinematics import dh_forward
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.probing.point_planning import (
    d_optimal,
    feasible_candidates,
    predicted_pose_std,
    random_points,
    sample_candidates,
    spread_points,
)
from algorithms.probing.qualification import compensate
from algorithms.registration import global_localize
from algorithms.registration.global_search.search import GlobalLocalizationResult
from algorithms.registration.local import localize
from algorithms.registration.result import RegistrationResult
from algorithms.registration.uncertainty import information_rows, sym_inverse, systematic_covariance
from twin.cell import Cell, build_cell
from twin.errors import TwinError
from twin.plan import plan_level_raster
from twin.probing import (
    ProbeHit,
    ProbeTarget,
    ProbingLog,
    ProbingProgram,
    ReachCheck,
    build_probe_cell,
    safe_height_world,
)
from twin.qualification import Qualification, probe_sigma_m, qualification_targets, qualify
from twin.realize import Realized
from twin.robot import UR5E_DH
from twin.scan import Scan, run_scan
from twin.sensors.laser import sensor_sigma_m
from twin.sensors.touch_probe import probe_spec
from twin.stages import StageFailed, StageRunner

TABLE_BAND_M = 0.002
COARSE_POINTS = 400
COMPENSATION_ROUNDS = 5
COMPENSATION_TOL_M = 1e-10
MIN_FINE_POINTS = 6
# Planning attempts: a chosen point the arm cannot reach is removed and the choice made again.
MAX_PLANNING_ROUNDS = 20
RECORDING_GAP_S = 1.0
COARSE_SEED_SPACING_M = 0.002


@dataclass(frozen=True)
class FinePlan:
    """The planned fine points (workpiece frame of the CAD model; targets in the base frame).

    Attributes:
        targets: the probe targets at ``T_coarse``, in probing order.
        points_wp, normals_wp: (m, 3) the chosen points and normals on the CAD model.
        candidates: candidate points sampled; feasible: how many passed.
        rejected: rejected candidates by reason (faces_away, near_edge, ball_blocked,
            stylus_collision, unreachable).
        planner: "d_optimal", "spread" or "random".
        predicted_std: (6,) predicted standard deviations of the twist [omega (rad), v (m)].
    """

    targets: tuple
    points_wp: np.ndarray
    normals_wp: np.ndarray
    candidates: int
    feasible: int
    rejected: dict
    planner: str
    predicted_std: np.ndarray


@dataclass(frozen=True)
class LocateResult:
    """Everything the hierarchy produced (robot base frame, SI units).

    Attributes:
        realized: the realized scenario.
        scan: the coarse laser pass; coarse_points: the points the coarse stage used.
        coarse_method: "multistart", "ga" or "ga_restarts"; coarse: its result.
        T_coarse: (4, 4) the coarse pose (T_base_workpiece).
        qualification: the probe's qualification.
        plan: the fine points planned.
        probing: the whole probing program as it ran (qualification and part).
        hits: the part's probing moves (in the plan's order).
        fine_001: document 001's fine stage from ``T_coarse`` (its own convergence).
        fine: the final registration result (fine_001's pose, finished after re-compensation).
        T_final: (4, 4) ``T_fine @ T_coarse``; T_fine: (4, 4).
        covariance: (6, 6) of the final pose's twist [omega, v] (workpiece frame).
        sigma_point_m: the combined random standard uncertainty of one probed point [m].
        timings_s: wall time per stage [s]; stage_t_s: simulated time per stage [s].
        failure: None, or (stage, reason).
    """

    realized: Realized
    scan: Scan | None
    coarse_points: np.ndarray | None = field(repr=False, default=None)
    coarse_method: str = ""
    coarse: object = None
    T_coarse: np.ndarray | None = None
    qualification: Qualification | None = None
    plan: FinePlan | None = None
    probing: ProbingLog | None = None
    hits: tuple = ()
    fine: object = None
    fine_001: object = None
    T_final: np.ndarray | None = None
    T_fine: np.ndarray | None = None
    covariance: np.ndarray | None = field(repr=False, default=None)
    sigma_point_m: float = float("nan")
    timings_s: dict = field(default_factory=dict)
    stage_t_s: dict = field(default_factory=dict)
    failure: tuple[str, str] | None = None
    compensation_rounds: int = 0

    @property
    def complete(self) -> bool:
        return self.failure is None


@dataclass(frozen=True)
class CoarseScan:
    """Stage 1's record: the sparse laser pass and its points off the table (base frame)."""

    scan: Scan
    points: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class CoarsePose:
    """Stage 2's record: the coarse search's result and its pose ``T_coarse`` (T_base_workpiece)."""

    result: GlobalLocalizationResult
    T_coarse: np.ndarray


@dataclass(frozen=True)
class Probed:
    """Stage 5's record: the whole probing program as it ran, and the part's probing moves."""

    log: ProbingLog
    hits: tuple


@dataclass(frozen=True)
class FineFit:
    """Stage 6's record: document 001's fine stage, the final fit and its covariance."""

    fine_001: RegistrationResult
    fine: RegistrationResult
    compensation_rounds: int
    T_final: np.ndarray
    T_fine: np.ndarray
    covariance: np.ndarray = field(repr=False)
    sigma_point_m: float


@dataclass
class _Locate:
    """The hierarchy's cells and its stages' records as they are made (one slot per record)."""

    realized: Realized
    say: Callable[[str], None]
    runner: StageRunner = field(default_factory=StageRunner)
    stage_t_s: dict[str, float] = field(default_factory=dict)
    coarse_scan: CoarseScan | None = None
    coarse: CoarsePose | None = None
    qualification: Qualification | None = None
    plan: FinePlan | None = None
    probed: Probed | None = None
    fit: FineFit | None = None


def locate(realized: Realized, say: Callable[[str], None] = lambda m: None, coarse: str | None = None,
           points: int | None = None, planner: str | None = None) -> LocateResult:
    """Document 001's hierarchy in the twin (module docstring). ``coarse``, ``points`` and
    ``planner`` override the scenario's ``locate.coarse``, ``probe.points`` and
    ``locate.planner``. A failing stage ends the run with ``failure`` naming it."""
    sc = realized.scenario
    if sc.probe is None:
        raise TwinError(f"scenario {sc.name!r} has no [probe] table: locate needs the touch probe on the flange")
    coarse = sc.locate.coarse if coarse is None else coarse
    planner = sc.locate.planner if planner is None else planner
    m = sc.probe.points if points is None else int(points)
    if m < MIN_FINE_POINTS:
        raise TwinError(f"--points {m} is too few: at least {MIN_FINE_POINTS} points fix six pose directions")
    st = _Locate(realized, say)
    st.runner.run(lambda: _stages(st, coarse, planner, m))
    return _result(st, coarse)


def _result(st: _Locate, coarse_method: str) -> LocateResult:
    """The result from the records of the stages that finished."""
    cs, cp, pr, fit = st.coarse_scan, st.coarse, st.probed, st.fit
    return LocateResult(
        realized=st.realized, scan=cs.scan if cs else None, coarse_points=cs.points if cs else None,
        coarse_method=coarse_method, coarse=cp.result if cp else None, T_coarse=cp.T_coarse if cp else None,
        qualification=st.qualification, plan=st.plan, probing=pr.log if pr else None, hits=pr.hits if pr else (),
        fine=fit.fine if fit else None, fine_001=fit.fine_001 if fit else None, T_final=fit.T_final if fit else None,
        T_fine=fit.T_fine if fit else None, covariance=fit.covariance if fit else None,
        sigma_point_m=fit.sigma_point_m if fit else float("nan"), timings_s=st.runner.timings_s,
        stage_t_s=st.stage_t_s, failure=st.runner.failure, compensation_rounds=fit.compensation_rounds if fit else 0)


def coarse_scan(realized: Realized, nominal: Cell, true_cell: Cell) -> tuple[Scan, np.ndarray]:
    """The sparse coarse laser pass (:func:`twin.plan.plan_level_raster` over the nominal
    footprint grown by ``locate.coarse_margin_m``) and its points off the table (base frame)."""
    loc = realized.scenario.locate
    plan = plan_level_raster(nominal, loc.coarse_margin_m, loc.coarse_line_spacing_m, loc.coarse_speed_m_s)
    scan = run_scan(realized, nominal, true_cell, plan)
    pts = scan.line_points_base
    return scan, pts[transform_points(realized.scenario.T_world_base, pts)[:, 2] > TABLE_BAND_M]


def _stages(st: _Locate, coarse: str, planner: str, m: int) -> None:
    realized = st.realized
    with st.runner.within("coarse_scan"):
        t0 = time.perf_counter()
        nominal = build_cell(realized, "nominal")
        true_cell = build_cell(realized, "true")
        probe_cell = build_probe_cell(realized)
        st.runner.timings_s["build_cells_s"] = time.perf_counter() - t0
    cs = _coarse_scan(st, nominal, true_cell)
    T_coarse = _coarse_pose(st, cs, coarse).T_coarse
    with st.runner.within("qualification"):
        t_prog = float(cs.scan.t[-1]) + RECORDING_GAP_S
        prog = ProbingProgram(realized, nominal, probe_cell, realized.streams.generator("probe"), t_offset_s=t_prog)
        safe_z = safe_height_world(realized, realized.scenario.T_world_base @ T_coarse)
    qual_hits, qual = _qualification(st, prog, safe_z)
    with st.runner.stage("plan"):
        plan = st.plan = plan_fine_points(realized, nominal, T_coarse, m, planner, realized.streams.generator("plan"))
    st.say(f"planned {len(plan.targets)} probe points ({planner}) of {plan.feasible} feasible candidates")
    got = _probe(st, prog, plan, qual_hits, safe_z)
    _fine(st, got, qual, T_coarse)


def _coarse_scan(st: _Locate, nominal: Cell, true_cell: Cell) -> CoarseScan:
    """1. The sparse laser pass."""
    with st.runner.stage("coarse_scan"):
        scan, pts = coarse_scan(st.realized, nominal, true_cell)
    st.stage_t_s["coarse_scan_s"] = float(scan.t[-1] - scan.t[0])
    cs = st.coarse_scan = CoarseScan(scan, pts)
    st.say(f"coarse pass: {len(scan.t)} samples, {len(pts)} points on the part")
    if len(pts) < MIN_FINE_POINTS:
        raise StageFailed("coarse_scan", f"the coarse laser pass found {len(pts)} points off the table: the part "
                                         "is not under the scanned region")
    return cs


def _coarse_pose(st: _Locate, cs: CoarseScan, coarse: str) -> CoarsePose:
    """2. The coarse pose, from no prior knowledge of the orientation."""
    with st.runner.stage("coarse"):
        T_coarse, result = coarse_pose(cs.points, st.realized, coarse)
    cp = st.coarse = CoarsePose(result, T_coarse)
    st.say(f"coarse pose ({coarse}): {result.status.value}, "
           f"{st.runner.timings_s['coarse_s']:.1f} s")
    return cp


def _qualification(st: _Locate, prog: ProbingProgram, safe_z: float) -> tuple[tuple[ProbeHit, ...], Qualification]:
    """3. Qualification on the reference sphere. Returns its probing moves and the qualification."""
    with st.runner.stage("qualification"):
        qual_hits = prog.run(qualification_targets(st.realized), safe_z, st.say)
        misses = [h for h in qual_hits if not h.hit]
        if misses:
            raise StageFailed("qualification", f"{len(misses)} of {len(qual_hits)} probing moves on the reference "
                                               "sphere found no surface: is the sphere where probe.sphere_xyz_m says?")
        qual = st.qualification = qualify(qual_hits, st.realized)
    st.stage_t_s["qualification_s"] = float(prog.log(qual_hits).duration_s)
    st.say(f"qualified: effective ball radius {qual.effective_radius_m * 1e3:.6f} mm, fit rms "
           f"{qual.rms_m * 1e9:.1f} nm")
    return qual_hits, qual


def _probe(st: _Locate, prog: ProbingProgram, plan: FinePlan, qual_hits: tuple[ProbeHit, ...],
           safe_z: float) -> list[ProbeHit]:
    """5. Probe the planned points. Returns the hits (misses left out)."""
    with st.runner.stage("probe"):
        t_before = float(prog.log(qual_hits).t[-1])
        hits = prog.run(list(plan.targets), safe_z, st.say)
        prog.lift(safe_z)
        log = prog.log(qual_hits + hits)
        st.probed = Probed(log, hits)
    st.stage_t_s["probe_s"] = float(log.t[-1] - t_before)
    got = [h for h in hits if h.hit]
    if len(got) < MIN_FINE_POINTS:
        search_mm = probe_spec(st.realized.scenario).search_m * 1e3
        raise StageFailed("fine", f"only {len(got)} of {len(hits)} planned points were hit (the others found no "
                                  f"surface within the search distance of {search_mm:g} mm): the coarse pose is "
                                  "too far off for its planned points")
    return got


def _fine(st: _Locate, got: list[ProbeHit], qual: Qualification, T_coarse: np.ndarray) -> None:
    """6. Document 001's fine stage on the compensated points, and the final covariance."""
    with st.runner.stage("fine"):
        doc, fine, rounds, points_wp, normals_wp = fine_stage(got, qual, st.realized, T_coarse)
    with st.runner.within("fine"):
        cov, sigma_point = fine_covariance(got, points_wp, normals_wp, qual, st.realized)
    st.fit = FineFit(doc, fine, rounds, fine.T_world_workpiece, fine.T_world_workpiece @ inv_pose(T_coarse), cov,
                     sigma_point)
    st.say(f"fine stage: fine_001 {doc.status.value} after {doc.iterations} iterations, then {rounds} compensation "
           f"round(s): {fine.status.value}, rms {fine.rmse_m * 1e6:.2f} um over {len(got)} points")


def coarse_pose(points: np.ndarray, realized: Realized, method: str) -> tuple[np.ndarray, GlobalLocalizationResult]:
    """The coarse pose (T_base_workpiece) from the coarse points, and the search's result.

    The searches work on ``COARSE_POINTS`` farthest-point samples of the coarse cloud (150, the
    search's default, missed the basin of the bottle punch in 1 of 20 seeded trials; 400 found
    it). ``ga`` is document 001's algorithm as the document runs it: its pose is taken as it
    comes (nothing checks it: the probing will). The other methods verify their pose against
    the points; one the noise cannot explain (poor fit, ambiguous, failed) ends the run here.
    """
    sigma = sensor_sigma_m(realized.scenario)
    rng = realized.streams.generator("coarse")
    index = realized.workpiece.index
    if method == "ga":
        r = global_localize(points, index=index, method="genetic", rng=rng, noise_sigma_m=sigma, ga_restarts=1,
                            polish=None, n_coarse=COARSE_POINTS)
        genetic = r.diagnostics.genetic
        if genetic is None:
            raise StageFailed("coarse", f"the genetic search returned no run: {r.message}")
        return genetic.T_coarse, r
    if method == "multistart":
        r = global_localize(points, index=index, method="multistart", rng=rng, noise_sigma_m=sigma,
                            n_coarse=COARSE_POINTS)
    elif method == "ga_restarts":
        r = global_localize(points, index=index, method="genetic", rng=rng, noise_sigma_m=sigma,
                            n_coarse=COARSE_POINTS)
    else:
        raise TwinError(f"coarse method must be one of multistart, ga, ga_restarts; got {method!r}")
    if r.status.value not in ("ok", "unobservable"):
        raise StageFailed("coarse", f"the coarse search ({method}) found no pose the points confirm: {r.message}")
    return r.T_world_workpiece, r


def plan_fine_points(realized: Realized, nominal: Cell, T_coarse: np.ndarray, m: int, planner: str,
                     rng: np.random.Generator) -> FinePlan:
    """Fine probe points on the CAD model at ``T_coarse`` (module docstring, step 4)."""
    sc = realized.scenario
    p = probe_spec(sc)
    index = realized.workpiece.index
    cand = sample_candidates(realized.workpiece.mesh, p.candidate_spacing_m, rng)
    R_world_wp = sc.T_world_base[:3, :3] @ T_coarse[:3, :3]
    axis_wp = R_world_wp.T @ np.array([0.0, 0.0, -1.0])
    feas = feasible_candidates(index, cand.points, cand.normals, stylus_axis=axis_wp, ball_radius_m=p.ball_radius_m,
                               stylus_radius_m=p.stylus_radius_m, stylus_length_m=p.stylus_length_m,
                               body_radius_m=p.body_radius_m, body_length_m=p.body_length_m,
                               approach_m=p.approach_m, search_m=p.search_m, edge_margin_m=p.edge_margin_m,
                               clearance_m=p.clearance_m)
    allowed = feas.mask.copy()
    # The table: the approach must start above it.
    c0 = transform_points(sc.T_world_base @ T_coarse,
                          cand.points + (p.ball_radius_m + p.approach_m) * cand.normals)
    low = allowed & (c0[:, 2] < p.ball_radius_m + p.body_radius_m)
    allowed &= ~low
    rejected = {k: int(v) for k, v in feas.counts.items() if k != "ok"}
    rejected["below_table"] = int(low.sum())
    rejected["unreachable"] = 0   # or the laser's housing beside the probe would come too near the part
    reach = ReachCheck(nominal, realized)
    chosen = np.zeros(0, dtype=np.int64)
    spins: dict[int, float | None] = {}
    for _ in range(MAX_PLANNING_ROUNDS):
        if allowed.sum() < m:
            break
        chosen = _choose(cand.points, cand.normals, m, allowed, planner, rng)
        for i in chosen:
            if i not in spins:
                spins[int(i)] = reach.spin(T_coarse, cand.points[i], cand.normals[i])
        bad = [i for i in chosen if spins[int(i)] is None]
        if not bad:
            break
        allowed[bad] = False
        rejected["unreachable"] += len(bad)
        chosen = np.zeros(0, dtype=np.int64)
    if len(chosen) < m:
        why = ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in rejected.items() if v)
        raise StageFailed("plan", f"only {int(allowed.sum())} of {len(cand.points)} candidate probe points are "
                                  f"plannable, {m} are needed (rejected: {why})")
    order = _tour(cand.points[chosen])
    chosen = chosen[order]
    T = T_coarse
    pts_b = transform_points(T, cand.points[chosen])
    nrm_b = cand.normals[chosen] @ T[:3, :3].T
    targets = tuple(ProbeTarget(pts_b[i], nrm_b[i], f"point {i + 1}", float(spins[int(j)] or 0.0))
                    for i, j in enumerate(chosen))
    sigma = probe_sigma_m(realized)
    return FinePlan(targets, cand.points[chosen], cand.normals[chosen], len(cand.points), int(feas.mask.sum()),
                    rejected, planner, predicted_pose_std(cand.points[chosen], cand.normals[chosen], sigma))


def _choose(points, normals, m, allowed, planner, rng) -> np.ndarray:
    if planner == "d_optimal":
        return np.asarray(d_optimal(points, normals, m, candidates_mask=allowed))
    if planner == "spread":
        return np.asarray(spread_points(points, m, candidates_mask=allowed))
    if planner == "random":
        return np.asarray(random_points(len(points), m, rng, candidates_mask=allowed))
    raise TwinError(f"locate.planner must be one of d_optimal, spread, random; got {planner!r}")


def _tour(points: np.ndarray) -> np.ndarray:
    """A short probing order: nearest neighbour from the point farthest along +x."""
    left = list(range(len(points)))
    order = [int(np.argmax(points[:, 0]))]
    left.remove(order[0])
    while left:
        d = np.linalg.norm(points[left] - points[order[-1]], axis=1)
        order.append(left.pop(int(np.argmin(d))))
    return np.asarray(order)


def fine_stage(hits: list[ProbeHit], qual: Qualification, realized: Realized, T_coarse: np.ndarray):
    """Document 001's fine stage (``fine_001``, from ``T_coarse``) on the compensated points,
    then the compensation re-done with the normals at the new estimate and the fit finished
    by ``hong_tan`` (the same minimum: a point-to-point method such as fine_001 slides
    slowly along the surface on a dozen points) until the estimate moves less than
    ``COMPENSATION_TOL_M``. Returns (fine_001's result, the final result, rounds, feet and
    normals at the final estimate (workpiece frame))."""
    index = realized.workpiece.index
    centres = np.array([h.centre + h.R_base_probe @ qual.offset_probe_m for h in hits])
    sigma = probe_sigma_m(realized)

    def points_at(T):
        c_wp = transform_points(inv_pose(T), centres)
        cp = index.query(c_wp)
        n_wp = index.smooth_normals(cp.face, cp.foot)
        return compensate(centres, n_wp @ T[:3, :3].T, qual.effective_radius_m), c_wp, n_wp

    doc = localize(points_at(T_coarse)[0], method="fine_001", init=T_coarse, sigma=sigma, outlier=None, index=index)
    final = doc
    T = doc.T_world_workpiece
    rounds, moved = 0, np.inf
    while rounds < COMPENSATION_ROUNDS and moved >= COMPENSATION_TOL_M:
        final = localize(points_at(T)[0], method="hong_tan", init=T, sigma=sigma, outlier=None, index=index)
        moved = np.abs(final.T_world_workpiece - T).max()
        T = final.T_world_workpiece
        rounds += 1
    _, c_wp, n_wp = points_at(T)
    return doc, final, rounds, c_wp - qual.effective_radius_m * n_wp, n_wp


def fine_covariance(hits, points_wp, normals_wp, qual: Qualification, realized: Realized) -> tuple[np.ndarray, float]:
    """(6, 6) covariance of the final pose twist [omega, v] (workpiece frame) and the random
    standard uncertainty of one point [m] (module docstring)."""
    sc = realized.scenario
    sigma = probe_sigma_m(realized)
    var = np.full(len(hits), sigma**2)
    if sc.noise.encoder_sigma_rad > 0:
        var += _encoder_variance(hits, normals_wp, realized)
    # Weighted least squares covariance of the random part.
    J = information_rows(points_wp, normals_wp)
    C = sym_inverse((J / var[:, None]).T @ J)
    # The qualification's errors are common to every point (systematic): the radius moves
    # each point along its normal, an offset component moves it by that component's share.
    basis = np.column_stack([np.ones(len(hits)), normals_wp])
    std = np.array([qual.radius_std_m] + [qual.offset_std_m] * 3)
    C = C + systematic_covariance(points_wp, normals_wp, np.eye(6), basis, std)
    return C, sigma


def _encoder_variance(hits, normals_wp, realized: Realized) -> np.ndarray:
    """Variance along each point's normal of the ball centre from the encoders' noise [m^2]
    (the arm's position Jacobian at the latched joints, by central differences)."""
    sc = realized.scenario
    p = probe_spec(sc)
    out = np.empty(len(hits))
    eps = 1e-6

    def centre(q):
        T = dh_forward(q, UR5E_DH) @ p.T_flange_probe
        return T[:3, 3] + p.tip_length_m * T[:3, 2]

    for i, h in enumerate(hits):
        Jp = np.column_stack([(centre(h.q + eps * e) - centre(h.q - eps * e)) / (2 * eps) for e in np.eye(6)])
        out[i] = sc.noise.encoder_sigma_rad**2 * float(np.sum((h.target.normal @ Jp) ** 2))
    return out
