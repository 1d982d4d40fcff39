"""Scan execution: plan on the nominal cell, joints by mink IK, 1 ms simulation of the true cell,
the sensor model, and document 004's point reconstruction.

Every 1 ms step records ``t``, the six joint encoder readings ``q`` and the distance ``d`` with
its ``valid`` flag, all evaluated in the same MuJoCo step (EtherCAT-style pairing). The arm is
simulated with its dynamics: position/velocity servos track the IK joint references, so the
real path differs from the planned one by the servo tracking error; the points do not suffer
from it because they are rebuilt from the encoder readings.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

from twin.cell import Cell
from twin.errors import TwinError
from twin.ik import IKSolver
from twin.plan import ScanPlan, plan_scan
from twin.realize import Realized
from twin.robot import HOME_Q, JOINT_NAMES, UR5E_DH
from twin.scenario import Scenario
from twin.sensors import RaySensor
from twin.sensors.base import Measurement, RawRays, sensor_slice
from twin.sim import simulate

IK_KNOT_STEPS = 10   # IK every 10 ms; joint references in between by a cubic spline
# The scan's IK solves each knot pose to these (nanometre-level sensor poses).
IK_POSITION_TOL_M = 1e-7
IK_ORIENTATION_TOL_RAD = 1e-6


@dataclass(frozen=True)
class Scan:
    """A simulated scan.

    Attributes:
        t: (N,) sample times [s], 1 ms apart.
        q: (N, 6) joint encoder readings as logged [rad] (encoder noise and time skew applied).
        d: (N, B) distances [m] of the B beams (B = 1: point sensor), NaN where invalid.
        valid: (N, B) bool.
        status: (N, B) sensor status codes (see ``twin.sensors.base``).
        line: (N,) scan-line index, -1 between lines.
        points_base: (N, B, 3) reconstructed points in the robot base frame [m], NaN where invalid.
        q_ref: (N, 6) joint references sent to the servos [rad].
        q_true: (N, 6) true joint positions [rad].
        plan: the planned sensor poses.
        T_base_workpiece_true: truth for evaluation only.
        T_base_workpiece_nominal: the planner's belief.
        T_flange_sensor_nominal: the believed hand-eye used for reconstruction.
        beam_dirs_sensor: (B, 3) beam directions in the sensor frame.
        d_true: (N, B) ideal distances [m] (-1 on a miss).
        sensor: the sensor that measured.
        timings_s: wall-clock seconds per stage.
    """

    scenario: Scenario
    t: np.ndarray
    q: np.ndarray
    d: np.ndarray
    valid: np.ndarray
    status: np.ndarray
    line: np.ndarray
    points_base: np.ndarray
    q_ref: np.ndarray
    q_true: np.ndarray
    plan: ScanPlan
    T_base_workpiece_true: np.ndarray
    T_base_workpiece_nominal: np.ndarray
    T_flange_sensor_nominal: np.ndarray
    beam_dirs_sensor: np.ndarray
    d_true: np.ndarray = field(repr=False)
    sensor: RaySensor = field(repr=False)
    timings_s: dict = field(default_factory=dict)

    @property
    def beams(self) -> int:
        return int(self.d.shape[1])

    @property
    def valid_points_base(self) -> np.ndarray:
        """(M, 3) the valid points only [m], robot base frame (sample-major order)."""
        return self.points_base[self.valid]

    @property
    def line_points_base(self) -> np.ndarray:
        """(M, 3) the valid points measured on scan lines [m] (approach, retract and line
        changes left out), robot base frame: the points localization uses."""
        return self.points_base[self.valid & (self.line >= 0)[:, None]]


def solve_joint_references(nominal: Cell, plan: ScanPlan) -> tuple[np.ndarray, np.ndarray]:
    """IK at knots every ``IK_KNOT_STEPS`` steps, cubic-spline references at every step.

    Returns (q_ref, qd_ref), each (K, 6). Raises TwinError naming the first unreachable scan line.
    """
    solver = IKSolver(nominal.model, nominal.sensor.site, IK_POSITION_TOL_M, IK_ORIENTATION_TOL_RAD)
    solver.set_q(HOME_Q)
    pe, oe, _ = solver.solve(plan.T_world_sensor[0], dt=0.05, max_iterations=1000, velocity_limited=False)
    q0 = solver.q
    _check_reachable(plan, 0, pe, oe)
    knots = np.arange(0, len(plan.t), IK_KNOT_STEPS)
    if knots[-1] != len(plan.t) - 1:
        knots = np.append(knots, len(plan.t) - 1)
    dt_knot = IK_KNOT_STEPS * plan.dt
    track = solver.track(plan.T_world_sensor[knots], q0, dt=dt_knot)
    bad = np.flatnonzero(~track.reachable)
    if len(bad):
        k = bad[0]
        _check_reachable(plan, knots[k], track.position_error_m[k], track.orientation_error_rad[k])
    spline = CubicSpline(plan.t[knots], track.q, axis=0, bc_type="clamped")
    return spline(plan.t), spline(plan.t, 1)


def _check_reachable(plan: ScanPlan, i: int, pos_err: float, rot_err: float) -> None:
    from twin.ik import reachable

    if reachable(pos_err, rot_err):
        return
    line = int(plan.line[i])
    if line >= 0:
        where = f"scan line {line}{_pass_label(plan, line)}"
    else:
        later = plan.line[i:][plan.line[i:] >= 0]
        where = (f"the move before scan line {int(later[0])}{_pass_label(plan, int(later[0]))}" if len(later)
                 else "the final retract")
    p = plan.T_world_sensor[i, :3, 3]
    raise TwinError(
        f"{where} is unreachable: at t = {plan.t[i]:.3f} s the sensor pose at world "
        f"({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m stays {pos_err * 1e3:.2f} mm / "
        f"{np.degrees(rot_err):.2f} deg off (move the part or the base, or shrink scan.region_m, or the "
        f"pass's region_m)"
    )


def _pass_label(plan: ScanPlan, line: int) -> str:
    """`` (pass 'NAME')`` for a line of a scan of several passes, else nothing."""
    if len(plan.passes) < 2 or line >= len(plan.line_pass):
        return ""
    return f" (pass {plan.passes[int(plan.line_pass[line])].name!r})"


def run_scan(realized: Realized, nominal: Cell, true_cell: Cell, plan: ScanPlan | None = None,
             reachable: Callable[[ScanPlan], None] | None = None) -> Scan:
    """Simulate the scenario's scan and reconstruct its points (see the module docstring).

    Args:
        realized: the realized scenario (its ``sensor`` and ``encoder`` streams are used).
        nominal: the nominal cell (plan and IK); true_cell: the true cell (simulation).
        plan: a plan made elsewhere (e.g. :func:`twin.plan.plan_level_raster`); default: the
            scenario's ``[scan]`` planned by :func:`twin.plan.plan_scan`.
        reachable: called with the plan once every sample's joints are solved (from then on
            nothing refuses the scenario: the simulation and the sensor model follow).
    """
    timings = {}
    t0 = time.perf_counter()
    plan = plan_scan(nominal) if plan is None else plan
    timings["plan_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    q_ref, qd_ref = solve_joint_references(nominal, plan)
    timings["ik_s"] = time.perf_counter() - t0
    if reachable is not None:
        reachable(plan)

    log = SampleLog(true_cell, len(q_ref))
    t0 = time.perf_counter()
    simulate(true_cell, q_ref, qd_ref, log.on_chunk)
    timings["simulate_s"] = time.perf_counter() - t0
    return scan_from_log(realized, true_cell, plan, q_ref, log, timings)


def scan_from_log(realized: Realized, true_cell: Cell, plan: ScanPlan, q_ref: np.ndarray, log: SampleLog,
                  timings: dict | None = None) -> Scan:
    """The scan from its rollout's log (``log``, the true cell's ideal rays and encoder readings
    of the references ``q_ref``): the sensor model with the realization's ``sensor`` and
    ``encoder`` streams and ``true_cell``'s sensor, then the points rebuilt (eq. 2). A rollout
    depends on the true cell and the references only, so one log serves every realization that
    shares them."""
    scenario = realized.scenario
    timings = {} if timings is None else timings
    sensor = true_cell.sensor
    t0 = time.perf_counter()
    meas, q_log, points = measure_samples(scenario, true_cell, plan.t, log.q_enc, log.rays(),
                                          realized.streams.generator("sensor"),
                                          realized.streams.generator("encoder"))
    timings["sensor_model_s"] = time.perf_counter() - t0
    return Scan(
        scenario=scenario, t=plan.t.copy(), q=q_log, d=meas.d, valid=meas.valid, status=meas.status,
        line=plan.line.copy(), points_base=points, q_ref=q_ref, q_true=log.q_true, plan=plan,
        T_base_workpiece_true=realized.T_base_workpiece_true,
        T_base_workpiece_nominal=realized.T_base_workpiece_nominal,
        T_flange_sensor_nominal=scenario.sensor.T_flange_sensor, beam_dirs_sensor=sensor.beam_dirs_sensor(),
        d_true=meas.d_true, sensor=sensor, timings_s=timings,
    )


class SampleLog:
    """Collects what a rollout's chunks carry for a ray sensor: encoder readings, true joints
    and the ideal rays of ``n`` steps (``on_chunk`` is :func:`twin.sim.simulate`'s callback)."""

    def __init__(self, true_cell: Cell, n: int):
        self.cell = true_cell
        b = true_cell.sensor.beams
        self.dist = np.empty((n, b))
        self.direction, self.normal = np.empty((n, b, 3)), np.empty((n, b, 3))
        # the beams of a sample share the emitter and the receiver
        self.origin, self.receiver = np.empty((n, 3)), np.empty((n, 3))
        self.q_enc = np.empty((n, 6))
        self.q_true = np.empty((n, 6))
        self.enc_cols = [sensor_slice(true_cell.model, f"enc_{j}").start for j in JOINT_NAMES]

    def on_chunk(self, i0: int, sens: np.ndarray, q_before: np.ndarray) -> None:
        i1 = i0 + len(sens)
        self.q_enc[i0:i1] = sens[:, self.enc_cols]
        self.q_true[i0:i1] = q_before
        r = self.cell.sensor.decode(self.cell.model, sens, q_before)
        self.dist[i0:i1], self.origin[i0:i1], self.direction[i0:i1] = r.dist, r.origin[:, 0], r.direction
        self.normal[i0:i1], self.receiver[i0:i1] = r.normal, r.receiver[:, 0]

    def rays(self, rows: slice | np.ndarray = slice(None)) -> RawRays:
        """The ideal rays of the logged steps (``rows`` of them)."""
        dist = self.dist[rows]
        return RawRays(dist, np.broadcast_to(self.origin[rows][:, None], dist.shape + (3,)), self.direction[rows],
                       self.normal[rows], np.broadcast_to(self.receiver[rows][:, None], dist.shape + (3,)))


def measure_samples(scenario: Scenario, true_cell: Cell, t: np.ndarray, q_enc: np.ndarray, rays: RawRays,
                    rng_sensor: np.random.Generator,
                    rng_encoder: np.random.Generator) -> tuple[Measurement, np.ndarray, np.ndarray]:
    """What the cell reports for simulated samples, and the points rebuilt from it.

    The sensor's error model on the ideal rays, then the robot-side error sources on the
    encoder readings the controller logs (time skew, encoder noise), then document 004's
    reconstruction with the believed hand-eye transform.

    Args:
        t: (N,) sample times [s]; q_enc: (N, 6) ideal encoder readings [rad]; rays: (N, B).
        rng_sensor, rng_encoder: the sensor's and the encoders' random streams.

    Returns:
        (measurement, q_log (N, 6) [rad] as logged, points (N, B, 3) [m] robot base frame).
    """
    meas = true_cell.sensor.measure(rays, rng_sensor, true_cell.model)
    q_log = q_enc.copy()
    if scenario.noise.time_skew_s != 0.0:
        # The distance at t pairs with the joints read at t - skew.
        ts = np.clip(t - scenario.noise.time_skew_s, t[0], t[-1])
        q_log = np.column_stack([np.interp(ts, t, q_log[:, j]) for j in range(6)])
    if scenario.noise.encoder_sigma_rad > 0:
        q_log = q_log + rng_encoder.normal(0.0, scenario.noise.encoder_sigma_rad, q_log.shape)
    points = true_cell.sensor.reconstruct(q_log, meas.d, UR5E_DH, scenario.sensor.T_flange_sensor)
    return meas, q_log, points


def scan_scenario(scenario: Scenario, mesh=None) -> Scan:
    """Realize a scenario and simulate its scan in one call (tests, notebooks, quick studies)."""
    from twin.cell import build_cell
    from twin.realize import realize

    realized = realize(scenario, mesh)
    return run_scan(realized, build_cell(realized, "nominal"), build_cell(realized, "true"))
