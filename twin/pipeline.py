"""The loop of the twin as one function: scan, localize, plan the process paths, solve the
joints, replay in the true cell. Returns a frozen :class:`RunResult`; writes no files.

1. scan the part (1 ms, true cell; one or several passes) and rebuild the points
   (document 004, eq. 2);
2. localize the part against its CAD mesh (documents 000/001) from the nominal pose, with the
   sensor's combined standard uncertainty as sigma, detecting the symmetry of what was
   scanned (document 000, Algorithm 2): the determined and free directions, the Cramer-Rao
   covariance and the fit check come with the estimate;
3. scan path (document 004): scan-line cloud, outlier filter, then each line is cut into
   pieces at sharp edges, steps, gaps and the border of the process region (judged on the
   CAD normals at the estimate), pieces on consecutive lines are chained into patches, and
   per patch: per-line B-spline fits resampled at ``path.point_spacing_m``, cross-line
   triangulation normals (never across a step), tool frames (eq. 11);
4. CAD path (document 003, step 5): a raster of contact points on the CAD mesh, cut the same
   way, moved by the localization estimate;
5. each path: five-axis mink IK on the nominal cell (the ball centre and the tool axis held,
   the spin about the axis free), the tool's shank and holder checked against the part at
   the estimate; a stretch that is unreachable, singular, discontinuous or colliding is
   dropped and listed (the line is split there, with a retract, a transit and a re-approach),
   or with ``strict`` the run fails there; then the time law at the feed and the replay in
   the true cell with the tool at 1 ms: deviation, contacts and joint limits.

A stage that fails (an unreachable scan, a path with nothing left, ``strict``) does not
raise: the result keeps what the finished stages made and says which stage failed and why
(``failure``), so the caller can write the evidence.

Cells: the nominal cell is compiled once (scan planning and path IK share it); the true cell
in two configurations, each compiled once from the same truth: with the sensor (the scan)
and with the process tool (the replays).
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import numpy as np

from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.paths.normals import smooth_line_normals, triangulation_normals
from algorithms.paths.pointcloud import CloudParams, LineCloud, organize_scan_lines, remove_outliers, simplify_lines
from algorithms.paths.regions import ProcessRegion, chain_pieces, split_runs
from algorithms.paths.spline import fit_lines
from algorithms.paths.timing import Trajectory
from algorithms.paths.toolpath import ProcessPath, ToolSettings, build_path, cad_raster, transform_path
from algorithms.registration.symmetric import localize_symmetric
from algorithms.registration.uncertainty import invariant_points, nearest_along_free, systematic_covariance
from twin.cell import Cell, build_cell
from twin.errors import TwinError
from twin.realize import Realized
from twin.replay import ReplayLog, build_replay_cell, replay
from twin.scan import Scan, run_scan
from twin.scenario import Scenario
from twin.trajectory import PathIK, PathProblem, solve_tool_path, time_law_for

RECORDING_GAP_S = 1.0      # sim_time between the scan and each replay in the recording
DROP_MARGIN_POINTS = 2     # contact points dropped on each side of a bad pose (first round)
MAX_DROP_ROUNDS = 8        # solve, drop, rebuild: at most this many times
# The shank and holder keep this far from the part: more than the replay's collision shape
# (a 1 mm height field, twin.replay.HFIELD_RES_M) stands out from the exact walls, up to
# a cell's diagonal.
CLEARANCE_M = 0.002
TABLE_CLEARANCE_M = 0.002  # the arm's links keep this far above the table
CLEARANCE_STEP_M = 0.002   # spacing of the clearance checks along the tool
BALL_TOLERANCE_M = 1e-4    # the ball may touch (approach, retract) but not enter the part in the air
MIN_PIECE_KNOT_SPANS = 2   # a scan-line piece shorter than this many B-spline knot spans is left out


@dataclass(frozen=True)
class Dropped:
    """A stretch of a process path left out: ``points`` contact points around ``position_m``."""

    line: int
    points: int
    position_m: tuple
    reason: str

    def to_dict(self) -> dict:
        return {"line": self.line, "points": self.points, "position_m": [round(float(v), 6) for v in self.position_m],
                "reason": self.reason}


@dataclass(frozen=True)
class PathRun:
    """One process path solved and replayed.

    Attributes:
        name: "scan_path" or "cad_path".
        path: the process path, robot base frame (after any drops).
        ik, trajectory, log: the joint solution, its timing and the replay.
        t_offset_s: where the replay starts on the recording's timeline [s].
        normals_points, normals: (M, 3) contact points and the normals the path used, base frame.
        dropped: the stretches left out (unreachable, singular, discontinuous, colliding).
    """

    name: str
    path: ProcessPath
    ik: PathIK
    trajectory: Trajectory
    log: ReplayLog
    t_offset_s: float
    normals_points: np.ndarray = field(repr=False)
    normals: np.ndarray = field(repr=False)
    dropped: tuple = ()


@dataclass(frozen=True)
class ScanPath:
    """Document 004's pipeline from the scan points to a path (robot base frame).

    Attributes:
        lines: fitted lines resampled at the point spacing, patch by patch.
        normals: cross-line triangulation normals of ``lines``; ``tool_normals`` smoothed.
        patches: number of patches (smooth pieces chained across lines).
        cloud_lines, cloud_points: scan lines and points after the outlier filter.
        removed: samples dropped by reason (invalid, between lines, outliers, merged, ...).
        fit_rms_error_m, fit_max_error_m: B-spline fit residuals of the pieces.
        left_out: pieces that could not form a patch (fewer than two lines), in words.
    """

    lines: tuple
    normals: tuple
    tool_normals: tuple
    patches: int
    cloud_lines: int
    cloud_points: int
    removed: dict
    fit_rms_error_m: float
    fit_max_error_m: float
    left_out: tuple
    time_s: float


@dataclass(frozen=True)
class RunResult:
    """Everything the loop produced (robot base frame, SI units).

    Attributes:
        realized: the realized scenario.
        scan: the simulated scan (None when the scan stage failed).
        localization: the registration result (None when it did not run).
        scan_path: document 004's path from the scan, or None (``scan_path_skipped`` says why).
        cad_path_workpiece: the CAD raster path in the workpiece frame (None if not made).
        runs: the replayed paths (scan path first when there is one, then the CAD path).
        replay_cell: the true cell with the tool (for recordings).
        timings_s: wall time per stage [s].
        failure: None for a complete run, else (stage, reason).
    """

    realized: Realized
    scan: Scan | None
    localization: object
    scan_path: ScanPath | None
    scan_path_skipped: str | None
    cad_path_workpiece: ProcessPath | None
    runs: tuple[PathRun, ...]
    replay_cell: Cell = field(repr=False)
    timings_s: dict = field(default_factory=dict)
    failure: tuple[str, str] | None = None
    pose_covariance: np.ndarray | None = field(default=None, repr=False)

    @property
    def complete(self) -> bool:
        return self.failure is None

    @property
    def T_base_workpiece_estimate(self) -> np.ndarray:
        return self.localization.T_world_workpiece

    def run(self, name: str) -> PathRun | None:
        return next((r for r in self.runs if r.name == name), None)


class StageFailed(TwinError):
    """A stage of the loop could not finish; the run keeps what the earlier stages made."""

    def __init__(self, stage: str, reason: str):
        super().__init__(f"{stage}: {reason}")
        self.stage = stage
        self.reason = reason


def cloud_params(scenario: Scenario) -> CloudParams:
    p = scenario.path
    return CloudParams(outlier_window_m=p.outlier_window_m, outlier_k=p.outlier_k, max_gap_m=p.max_gap_m,
                       simplify_spacing_m=p.simplify_spacing_m, empty=p.empty_lines)


def tool_settings(scenario: Scenario) -> ToolSettings:
    p = scenario.path
    return ToolSettings(p.heading, tuple(p.heading_direction), p.axis, tuple(p.axis_direction),
                        float(np.radians(p.lead_deg)), float(np.radians(p.tilt_deg)), p.tip_radius_m,
                        p.retract_m)


def process_region(scenario: Scenario) -> ProcessRegion:
    """The scenario's process region (workpiece frame)."""
    p = scenario.path
    lo, hi = (None, None) if p.region_box_m is None else (tuple(p.region_box_m[0]), tuple(p.region_box_m[1]))
    return ProcessRegion(tuple(p.region_axis), float(np.radians(p.region_cone_deg)), lo, hi)


def sensor_sigma_m(scenario: Scenario) -> float:
    """Combined standard uncertainty of one distance (GUM): repeatability, linearity band
    (uniform, amplitude / sqrt 3) and quantisation (step / sqrt 12), for the switched-on sources."""
    s, n = scenario.sensor, scenario.noise
    var = (s.sigma_m**2 if n.gaussian else 0.0) + ((s.linearity_m / np.sqrt(3)) ** 2 if n.linearity else 0.0) \
        + ((s.resolution_m / np.sqrt(12)) ** 2 if n.quantization else 0.0)
    return float(np.sqrt(var))


def pose_covariance(scan: Scan, localization, index: MeshIndex) -> np.ndarray:
    """The estimate's covariance along its determined directions: the Cramer-Rao term of the
    random errors (repeatability and quantisation) plus the sensor's linearity curve as a
    systematic error (Legendre polynomials of degree 0-3 in the measured distance across the
    window, each coefficient with the band's uniform standard deviation ``linearity / sqrt 3``;
    :func:`algorithms.registration.uncertainty.systematic_covariance`)."""
    sc = scan.scenario
    D = np.asarray(localization.determined_directions, dtype=np.float64).reshape(-1, 6)
    C = np.asarray(localization.covariance, dtype=np.float64)
    if len(D) == 0:
        return C
    s, n = sc.sensor, sc.noise
    sigma_all = sensor_sigma_m(sc)
    lin = s.linearity_m / np.sqrt(3) if n.linearity else 0.0
    C = C * max(sigma_all**2 - lin**2, 0.0) / sigma_all**2
    if lin == 0.0:
        return C
    mask = scan.valid & (scan.line >= 0)[:, None]
    d = scan.d[mask][localization.inliers]
    pts = scan.points_base[mask][localization.inliers]
    near, far = s.window_m
    u = np.clip(2.0 * (d - s.reference_m) / (far - near), -1.0, 1.0)
    basis = np.polynomial.legendre.legvander(u, 3)
    cp = index.query(transform_points(inv_pose(localization.T_world_workpiece), pts))
    normals = index.smooth_normals(cp.face, cp.foot)
    return C + systematic_covariance(cp.foot, normals, D, basis, np.full(4, lin))


def _beam_toward_sensor(scan: Scan, line_ids) -> np.ndarray:
    """Mean direction from the points of the given scan lines back to the sensor, base frame."""
    on = np.isin(scan.plan.line, np.asarray(line_ids))
    z = scan.plan.T_world_sensor[on, :3, 2].mean(axis=0)
    return -(inv_pose(scan.scenario.T_world_base)[:3, :3] @ z)


def _line_groups(scan: Scan) -> list[np.ndarray]:
    """Scan-line labels grouped by pass (lines of one pass run the same way)."""
    labels = np.unique(scan.line[scan.line >= 0])
    lp = np.asarray(scan.plan.line_pass)
    if len(labels) == 0 or len(lp) <= labels.max():
        return [labels]
    return [labels[lp[labels] == k] for k in np.unique(lp[labels])]


def _pieces(cloud: LineCloud, T_base_workpiece: np.ndarray, index: MeshIndex, region: ProcessRegion,
            max_gap_m: float, min_length_m: float) -> list[list[np.ndarray]]:
    """Each line of the cloud cut at edges, steps, gaps and the region's border; pieces
    shorter than ``min_length_m`` are left out."""
    T_wb = inv_pose(T_base_workpiece)
    out = []
    for line in cloud.lines:
        p_wp = transform_points(T_wb, line)
        cp = index.query(p_wp)
        n_wp = index.smooth_normals(cp.face, cp.foot)
        runs = split_runs(p_wp, n_wp, region.select(cp.foot, n_wp), max_gap_m=max_gap_m)
        out.append([line[r] for r in runs if np.linalg.norm(line[r[-1]] - line[r[0]]) >= min_length_m])
    return out


def scan_path(scan: Scan, T_base_workpiece_estimate: np.ndarray, index: MeshIndex) -> ScanPath:
    """Document 004's pipeline from the scan points to process lines (robot base frame), per
    pass and per patch (module docstring, step 3)."""
    sc = scan.scenario
    if scan.beams != 1:
        raise TwinError("the scan-derived path needs one beam per sample (sensor.kind = 'point')")
    t0 = time.perf_counter()
    params = cloud_params(sc)
    region = process_region(sc)
    link_m = 3.0 * _max_line_spacing_m(sc)
    lines, normals, tool_normals, left_out = [], [], [], []
    removed: dict = {}
    n_lines = n_points = patches = 0
    sq = n_fit = 0.0
    max_fit = 0.0
    points = scan.points_base[:, 0]
    for group in _line_groups(scan):
        label = np.where(np.isin(scan.line, group), scan.line, -1)
        cloud = organize_scan_lines(points, label, empty=params.empty)
        cloud = remove_outliers(cloud, params.outlier_window_m, params.outlier_k, params.outlier_min_residual_m)
        n_lines += len(cloud.lines)
        n_points += cloud.n_points
        for k, v in cloud.removed.items():
            removed[k] = removed.get(k, 0) + int(v)
        pieces = _pieces(cloud, T_base_workpiece_estimate, index, region, params.max_gap_m,
                         MIN_PIECE_KNOT_SPANS * sc.path.knot_spacing_m)
        orient = _beam_toward_sensor(scan, group)
        for patch in chain_pieces(pieces, cloud.direction, link_m):
            if len(patch) < 2:
                (i, j), = patch
                left_out.append(f"a piece of {len(pieces[i][j])} points on scan line {int(cloud.line_ids[i])} "
                                "has no neighbour line in its patch")
                continue
            part = LineCloud(tuple(pieces[i][j] for i, j in patch), cloud.line_ids[[i for i, _ in patch]],
                             tuple(np.full(len(pieces[i][j]), -1) for i, j in patch), cloud.direction, cloud.across)
            part = simplify_lines(part, params.simplify_spacing_m)
            fits = fit_lines(part.lines, sc.path.point_spacing_m, sc.path.knot_spacing_m)
            n = triangulation_normals(fits.lines, orient=orient)
            lines.extend(fits.lines)
            normals.extend(n)
            tool_normals.extend(smooth_line_normals(fits.lines, n, 2 * sc.path.knot_spacing_m))
            patches += 1
            for f in fits.fits:
                sq += f.rms_error_m**2 * f.n_points
                n_fit += f.n_points
                max_fit = max(max_fit, f.max_error_m)
    if not lines:
        raise TwinError("no patch of the scan lies in the process region (path.region_*): nothing to process")
    return ScanPath(tuple(lines), tuple(normals), tuple(tool_normals), patches, n_lines, n_points, removed,
                    float(np.sqrt(sq / max(n_fit, 1))), float(max_fit), tuple(left_out), time.perf_counter() - t0)


def _max_line_spacing_m(scenario: Scenario) -> float:
    passes = getattr(scenario.scan, "passes", None)
    spacings = [scenario.scan.line_spacing_m]
    if isinstance(passes, tuple):
        spacings += [float(getattr(p, "line_spacing_m", 0.0)) for p in passes]
    return max(spacings)


def cad_path_lines(realized: Realized) -> tuple[list, list]:
    """The CAD raster's contact lines and normals in the WORKPIECE frame, cut at edges, steps
    and the border of the process region."""
    p = realized.scenario.path
    wp = realized.workpiece
    return cad_raster(wp.mesh, p.line_spacing_m, p.point_spacing_m, p.margin_m, p.line_axis,
                      normals=wp.index.smooth_normals, process_region=process_region(realized.scenario))


def cad_path(realized: Realized) -> ProcessPath:
    """A raster of contact points on the CAD model, as a process path in the WORKPIECE frame."""
    lines, normals = cad_path_lines(realized)
    return build_path(lines, normals, tool_settings(realized.scenario))


# ------------------------------------------------------------------ solving with drops
def clearance_problems(path: ProcessPath, scenario: Scenario, T_base_workpiece: np.ndarray,
                       index: MeshIndex) -> list[PathProblem]:
    """Poses whose shank or holder comes within CLEARANCE_M of the part (at the estimate),
    or whose ball enters the part on a move in the air.

    The tool axis runs from the ball centre back to the flange; it is sampled every
    CLEARANCE_STEP_M beyond the ball, each sample with the radius of what is there.
    """
    p = scenario.path
    reach = float(np.linalg.norm(p.T_flange_tool[:3, 3])) - p.tip_radius_m
    s = np.arange(p.tip_radius_m + CLEARANCE_STEP_M, reach, CLEARANCE_STEP_M)
    if len(s) == 0:
        return []
    radius = np.where(s > reach - p.holder_length_m, max(p.holder_radius_m, p.shank_radius_m), p.shank_radius_m)
    T_wb = inv_pose(T_base_workpiece)
    T = T_wb @ path.T_tool
    centre = T[:, :3, 3] + p.tip_radius_m * T[:, :3, 2]
    samples = centre[:, None, :] + s[None, :, None] * T[:, None, :3, 2]
    d = index.signed_distance(samples.reshape(-1, 3)).reshape(len(T), len(s))
    short = d - radius[None, :]
    bad = np.flatnonzero(np.min(short, axis=1) < CLEARANCE_M)
    out = []
    # the ball itself on moves in the air (approach, retract, transit): never into the part
    ball = index.signed_distance(centre) - p.tip_radius_m
    for i in np.flatnonzero(~path.process_mask() & (ball < -BALL_TOLERANCE_M)):
        out.append(PathProblem(int(i), "collision", tuple(path.T_tool[i, :3, 3]),
                               f"the ball goes {-ball[i] * 1e3:.2f} mm into the part on a move in the air"))
    for i in bad:
        j = int(np.argmin(short[i]))
        out.append(PathProblem(int(i), "collision", tuple(path.T_tool[i, :3, 3]),
                               f"the tool {s[j] * 1e3:.0f} mm up its axis comes {short[i, j] * 1e3:.2f} mm "
                               "from the part"))
    return out


def table_problems(nominal: Cell, path: ProcessPath, q: np.ndarray) -> list[PathProblem]:
    """Poses at which a link of the arm comes within TABLE_CLEARANCE_M of the table (MuJoCo's
    collision detection on the nominal cell, with a margin on the table plane)."""
    model = copy.copy(nominal.model)
    table = model.geom("table").id
    model.geom_margin[table] = TABLE_CLEARANCE_M
    data = mujoco.MjData(model)
    adr = nominal.qpos_adr
    # the base and the shoulder's turret stand on the table whatever the joints
    standing = {model.geom(g).id for g in range(model.ngeom)
                if model.body(model.geom_bodyid[g]).name in ("base", "shoulder_pan_link")}
    out = []
    for i in range(len(q)):
        data.qpos[adr] = q[i]
        mujoco.mj_fwdPosition(model, data)
        c = data.contact[: data.ncon]
        other_geom = np.where(c.geom1 == table, c.geom2, c.geom1)
        hit = ((c.geom1 == table) | (c.geom2 == table)) & ~np.isin(other_geom, list(standing))
        if np.any(hit & (c.dist < TABLE_CLEARANCE_M)):
            k = int(np.flatnonzero(hit)[np.argmin(c.dist[hit])])
            other = int(other_geom[k])
            out.append(PathProblem(i, "collision", tuple(path.T_tool[i, :3, 3]),
                                   f"the arm's {model.geom(other).name} comes {c.dist[k] * 1e3:.1f} mm from the table"))
    return out


def _transit_check(scenario: Scenario, index: MeshIndex, T_base_workpiece: np.ndarray,
                   T_base_frame: np.ndarray | None):
    """The clearance test of transits and the safe plane above the part, in the frame the
    lines are given in (the workpiece frame when ``T_base_frame`` is the estimate, else the
    base frame): a transit is clear when the ball stays ``retract_m / 2`` above the part."""
    p = scenario.path
    T_frame_wp = inv_pose(T_base_frame) @ T_base_workpiece if T_base_frame is not None else T_base_workpiece
    T_wp_frame = inv_pose(T_frame_wp)
    top = float(index.vertices[:, 2].max())
    safe_point = transform_points(T_frame_wp, np.array([[0.0, 0.0, top + p.retract_m]]))[0]
    up = T_frame_wp[:3, :3] @ np.array([0.0, 0.0, 1.0])

    def clear(tcp: np.ndarray) -> np.ndarray:
        # TCP -> ball centre: the tool axis in the air is close to "up" on every transit
        centre = transform_points(T_wp_frame, tcp + p.tip_radius_m * up)
        return index.signed_distance(centre) >= p.tip_radius_m + 0.5 * p.retract_m

    return clear, (safe_point, up)


def _drop_masks(path: ProcessPath, problems, lines, margin: int) -> tuple[list[np.ndarray], list[Dropped]]:
    """Keep-masks over the lines' points after dropping ``margin`` points on each side of
    every pose in ``problems``."""
    keep = [np.ones(len(ln), dtype=bool) for ln in lines]
    seg_of_line = {seg[3]: seg for seg in path.segments if seg[2] == "process"}
    reasons: dict[tuple[int, int], str] = {}
    for prob in problems:
        a, b, kind, line = path.segments[path.segment[prob.index]]
        if kind == "process":
            j = prob.index - a
        else:
            # A move in the air: the end of the line it leaves, or the start of the one it reaches.
            nxt = [s for s in path.segments if s[2] == "process" and s[0] >= b]
            prv = [s for s in path.segments if s[2] == "process" and s[1] <= a]
            if kind == "retract" and prv:
                line, j = prv[-1][3], prv[-1][1] - prv[-1][0]
            elif nxt:
                line, j = nxt[0][3], 0
            else:
                continue
        a_line = seg_of_line[line]
        n = a_line[1] - a_line[0] + 1
        j_orig = (n - 1 - j) if line % 2 == 1 else j   # odd lines run reversed (zig-zag)
        lo, hi = max(0, j_orig - margin), min(n, j_orig + margin + 1)
        keep[line][lo:hi] = False
        reasons.setdefault((line, j_orig), f"{prob.kind}: {prob.detail}")
    dropped = [Dropped(line, margin * 2 + 1, tuple(lines[line][j]), why)
               for (line, j), why in sorted(reasons.items())]
    return keep, dropped


def _split_kept(lines, normals, keep) -> tuple[list, list]:
    out_l, out_n = [], []
    for ln, nm, k in zip(lines, normals, keep, strict=True):
        idx = np.flatnonzero(k)
        if len(idx) < 2:
            continue
        for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            if len(run) >= 2:
                out_l.append(ln[run])
                out_n.append(nm[run])
    return out_l, out_n


def solve_with_drops(name: str, lines, normals, settings: ToolSettings, T_frame_ref, nominal: Cell,
                     T_base_workpiece: np.ndarray, index: MeshIndex, strict: bool,
                     T_base_frame: np.ndarray | None = None) -> tuple[ProcessPath, PathIK, list[Dropped]]:
    """Build the path, check the tool's clearance, solve the five-axis IK; drop every bad
    stretch and rebuild, until nothing is bad (module docstring, step 5).

    ``lines``/``normals`` are in the frame ``T_base_frame`` maps to the base (None: the base).

    Raises:
        StageFailed: ``strict`` and a stretch is bad, or nothing is left.
    """
    sc = nominal.scenario
    p = sc.path
    dropped: list[Dropped] = []
    lines, normals = list(lines), list(normals)
    clear, safe_plane = _transit_check(sc, index, T_base_workpiece, T_base_frame)
    for round_ in range(MAX_DROP_ROUNDS):
        path = build_path(lines, normals, settings, T_frame_ref=T_frame_ref, clear=clear, safe_plane=safe_plane)
        if T_base_frame is not None:
            path = transform_path(T_base_frame, path)
        problems = clearance_problems(path, sc, T_base_workpiece, index)
        ik = solve_tool_path(nominal, path, p.T_flange_tool, p.feed_m_s, p.transit_speed_m_s, free_spin=True)
        problems += table_problems(nominal, path, ik.q)
        problems = sorted(list(problems) + list(ik.problems), key=lambda q: q.index)
        if not problems:
            return path, ik, dropped
        if strict:
            raise StageFailed(name, f"{len(problems)} bad pose(s) (--strict); first: {problems[0].describe()}")
        # the margin doubles each round: a stretch still bad after a drop is wider than thought
        keep, more = _drop_masks(path, problems, lines, DROP_MARGIN_POINTS * 2**round_)
        dropped += more
        lines, normals = _split_kept(lines, normals, keep)
        if not lines:
            raise StageFailed(name, f"no stretch of the path can be processed; first problem: {problems[0].describe()}")
    raise StageFailed(name, f"bad poses remain after {MAX_DROP_ROUNDS} rounds of dropping; "
                            f"first: {problems[0].describe()}")


def determined_part(lines_wp, normals_wp, localization, index: MeshIndex) -> tuple[list, list]:
    """The CAD path's points whose position the estimate fixes: with free directions (a bore
    whose rotation about its axis the scan leaves free), only the points that stay on the
    part when moved along them (:func:`algorithms.registration.uncertainty.invariant_points`)."""
    F = np.asarray(localization.free_directions, dtype=np.float64).reshape(-1, 6)
    if len(F) == 0:
        return list(lines_wp), list(normals_wp)
    keep = [invariant_points(index, ln, F) for ln in lines_wp]
    return _split_kept(lines_wp, normals_wp, keep)


def _replay(name: str, path: ProcessPath, ik: PathIK, dropped, replay_cell: Cell, realized: Realized,
            t_offset_s: float, normals_points: np.ndarray, normals: np.ndarray,
            say: Callable[[str], None]) -> PathRun:
    p = realized.scenario.path
    traj = time_law_for(path, ik, p.feed_m_s, p.transit_speed_m_s, p.acceleration_m_s2,
                        p.touchdown_acceleration_m_s2)
    note = f", {len(dropped)} stretch(es) dropped" if dropped else ""
    say(f"{name}: {len(path.T_tool)} poses, IK {ik.time_per_pose_ms:.3f} ms/pose, "
        f"{traj.duration_s:.1f} s of motion{note}")
    log = replay(replay_cell, traj, path, realized.workpiece.index)
    say(f"{name}: replayed, {len(log.unintended_contacts)} unintended contact(s)")
    return PathRun(name, path, ik, traj, log, t_offset_s, normals_points, normals, tuple(dropped))


# ------------------------------------------------------------------ the loop
def run(realized: Realized, say: Callable[[str], None] = lambda msg: None, strict: bool = False) -> RunResult:
    """The whole loop (module docstring). ``say`` receives one progress line per stage.

    A failing stage ends the run with ``failure`` set; bad input found before the loop
    starts (cells that do not compile) raises :class:`TwinError`.
    """
    check_process_region(realized)
    timings: dict = {}
    t0 = time.perf_counter()
    nominal = build_cell(realized, "nominal")
    true_cell = build_cell(realized, "true")
    replay_cell = build_replay_cell(realized)
    timings["build_cells_s"] = time.perf_counter() - t0
    state = {"scan": None, "localization": None, "covariance": None, "scan_path": None, "skipped": None,
             "cad": None, "runs": []}
    stage = "scan"
    try:
        _run(realized, nominal, true_cell, replay_cell, say, strict, timings, state)
        failure = None
    except StageFailed as exc:
        failure = (exc.stage, exc.reason)
    except (TwinError, AlgorithmError) as exc:
        stage = _current_stage(state)
        failure = (stage, str(exc))
    return RunResult(realized, state["scan"], state["localization"], state["scan_path"], state["skipped"],
                     state["cad"], tuple(state["runs"]), replay_cell, timings, failure, state["covariance"])


def check_process_region(realized: Realized) -> None:
    """Bad input, before anything runs: a process region that selects no face of the part."""
    mesh = realized.workpiece.mesh
    centres = np.asarray(mesh.triangles_center)
    if not process_region(realized.scenario).select(centres, np.asarray(mesh.face_normals)).any():
        p = realized.scenario.path
        raise TwinError(f"the process region (path.region_axis {np.round(p.region_axis, 3).tolist()}, "
                        f"region_cone_deg {p.region_cone_deg:g}, region_box_m {p.region_box_m}) selects no face "
                        "of the part")


def _current_stage(state: dict) -> str:
    if state["scan"] is None:
        return "scan"
    if state["localization"] is None:
        return "localize"
    if state["cad"] is None and not state["runs"]:
        return "scan_path" if state["scan"].beams == 1 and state["skipped"] is None else "cad_path"
    return "cad_path"


def _run(realized: Realized, nominal: Cell, true_cell: Cell, replay_cell: Cell, say, strict: bool,
         timings: dict, state: dict) -> None:
    scenario = realized.scenario
    index = realized.workpiece.index
    t0 = time.perf_counter()
    scan = run_scan(realized, nominal, true_cell)
    timings["scan_s"] = time.perf_counter() - t0
    state["scan"] = scan
    say(f"scanned {len(scan.t)} samples ({scan.t[-1]:.1f} s simulated)")

    t0 = time.perf_counter()
    loc = localize_symmetric(scan.line_points_base, realized.workpiece.mesh, symmetric="auto",
                             init=realized.T_base_workpiece_nominal, sigma=sensor_sigma_m(scenario), index=index)
    timings["localize_s"] = time.perf_counter() - t0
    if len(loc.free_directions):
        # along its free directions the estimate keeps the nominal pose (the points cannot move it)
        loc = dataclasses.replace(loc, T_world_workpiece=nearest_along_free(
            loc.T_world_workpiece, loc.free_directions, realized.T_base_workpiece_nominal))
    state["localization"] = loc
    state["covariance"] = pose_covariance(scan, loc, index)
    T_est = loc.T_world_workpiece
    free = len(loc.free_directions)
    say(f"localized: {loc.status.value}, rms {loc.rmse_m * 1e6:.2f} um, {6 - free} determined, "
        f"{free} free direction(s)")

    t_offset = float(scan.t[-1]) + RECORDING_GAP_S
    settings = tool_settings(scenario)
    if scan.beams == 1:
        t0 = time.perf_counter()
        try:
            sp = scan_path(scan, T_est, index)
        except (TwinError, AlgorithmError) as exc:
            raise StageFailed("scan_path", str(exc)) from None
        state["scan_path"] = sp
        timings["scan_path_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        path, ik, dropped = solve_with_drops("scan_path", sp.lines, sp.tool_normals, settings, T_est, nominal,
                                             T_est, index, strict)
        timings["scan_path_ik_s"] = time.perf_counter() - t0
        mask = path.process_mask()
        t0 = time.perf_counter()
        r = _replay("scan_path", path, ik, dropped, replay_cell, realized, t_offset, path.contact[mask],
                    path.normal[mask], say)
        timings["scan_path_replay_s"] = time.perf_counter() - t0
        state["runs"].append(r)
        t_offset += r.trajectory.duration_s + RECORDING_GAP_S
    else:
        state["skipped"] = "the scan-derived path needs one beam per sample (sensor.kind = 'point')"

    t0 = time.perf_counter()
    try:
        lines_wp, normals_wp = determined_part(*cad_path_lines(realized), loc, index)
        if not lines_wp:
            raise StageFailed("cad_path", "no CAD path point is determined by the scan: the free directions "
                                          "move every point of the process region off the part")
        state["cad"] = build_path(lines_wp, normals_wp, settings)
    except AlgorithmError as exc:
        raise StageFailed("cad_path", str(exc)) from None
    timings["cad_path_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    path, ik, dropped = solve_with_drops("cad_path", lines_wp, normals_wp, settings, None, nominal, T_est, index,
                                         strict, T_base_frame=T_est)
    state["cad"] = transform_path(inv_pose(T_est), path)   # after any drops, workpiece frame
    timings["cad_path_ik_s"] = time.perf_counter() - t0
    mask = path.process_mask()
    t0 = time.perf_counter()
    r = _replay("cad_path", path, ik, dropped, replay_cell, realized, t_offset, path.contact[mask],
                path.normal[mask], say)
    timings["cad_path_replay_s"] = time.perf_counter() - t0
    state["runs"].append(r)

