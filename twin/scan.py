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
from dataclasses import dataclass, field

import mujoco
import mujoco.batch
import mujoco.rollout
import numpy as np
from scipy.interpolate import CubicSpline

from algorithms.geometry.kinematics import reconstruct_line_points, reconstruct_points
from algorithms.geometry.se3 import inv_pose
from twin.cell import STATIC_GROUPS, Cell, build_cell, load_workpiece_mesh
from twin.errors import TwinError
from twin.ik import IKSolver
from twin.plan import ScanPlan, plan_scan
from twin.robot import HOME_Q, JOINT_NAMES, UR5E_DH
from twin.scenario import Scenario
from twin.sensor import RAY_THREADS, Measurement, RawRays, measure

IK_KNOT_STEPS = 10   # IK every 10 ms; joint references in between by a cubic spline
ROLLOUT_CHUNK_STEPS = 2000


@dataclass(frozen=True)
class Scan:
    """A simulated scan.

    Attributes:
        t: (N,) sample times [s], 1 ms apart.
        q: (N, 6) joint encoder readings as logged [rad] (encoder noise and time skew applied).
        d: (N,) or (N, B) distances [m], NaN where invalid.
        valid: same shape as ``d``.
        status: same shape as ``d``, sensor status codes (see ``twin.sensor``).
        line: (N,) scan-line index, -1 between lines.
        points_base: (N, 3) or (N, B, 3) reconstructed points in the robot base frame [m], NaN where invalid.
        q_ref: (N, 6) joint references sent to the servos [rad].
        q_true: (N, 6) true joint positions [rad].
        plan: the planned sensor poses.
        T_base_workpiece_true: truth for evaluation only.
        T_base_workpiece_nominal: the planner's belief.
        T_flange_sensor_nominal: the believed hand-eye used for reconstruction.
        beam_dirs_sensor: (B, 3) beam directions in the sensor frame (line profiler), or (1, 3).
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
    timings_s: dict = field(default_factory=dict)

    @property
    def valid_points_base(self) -> np.ndarray:
        """(M, 3) the valid points only [m], robot base frame."""
        return self.points_base[self.valid]


def solve_joint_references(nominal: Cell, plan: ScanPlan) -> tuple[np.ndarray, np.ndarray]:
    """IK at knots every ``IK_KNOT_STEPS`` steps, cubic-spline references at every step.

    Returns (q_ref, qd_ref), each (K, 6). Raises TwinError naming the first unreachable scan line.
    """
    solver = IKSolver(nominal.model)
    q0, pe, oe = solver.solve(plan.T_world_sensor[0], HOME_Q, dt=0.05, max_iterations=1000,
                              velocity_limited=False)
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
    from twin.ik import UNREACHABLE_ORIENTATION_RAD, UNREACHABLE_POSITION_M

    if pos_err < UNREACHABLE_POSITION_M and rot_err < UNREACHABLE_ORIENTATION_RAD:
        return
    line = int(plan.line[i])
    if line >= 0:
        where = f"scan line {line}"
    else:
        later = plan.line[i:][plan.line[i:] >= 0]
        where = f"the move before scan line {int(later[0])}" if len(later) else "the final retract"
    p = plan.T_world_sensor[i, :3, 3]
    raise TwinError(
        f"{where} is unreachable: at t = {plan.t[i]:.3f} s the sensor pose at world "
        f"({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m stays {pos_err * 1e3:.2f} mm / "
        f"{np.degrees(rot_err):.2f} deg off (move the part or the base, or shrink scan.region_m)"
    )


def _sensor_slices(model: mujoco.MjModel) -> dict:
    out = {}
    for name in ("laser_ray", "laser_xaxis", "laser_yaxis", *[f"enc_{j}" for j in JOINT_NAMES]):
        s = model.sensor(name)
        out[name] = slice(int(s.adr[0]), int(s.adr[0] + s.dim[0]))
    return out


def simulate(true_cell: Cell, q_ref: np.ndarray, qd_ref: np.ndarray, on_chunk) -> None:
    """Roll the true cell out at 1 ms with the servo references; ``on_chunk(i0, sensordata, qpos)``."""
    model, data = true_cell.model, true_cell.data
    mujoco.mj_resetData(model, data)
    data.qpos[true_cell.qpos_adr] = q_ref[0]
    mujoco.mj_forward(model, data)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state, spec)
    ctrl = np.concatenate([q_ref, qd_ref], axis=1)
    n = len(q_ref)
    qadr = true_cell.qpos_adr + 1  # FULLPHYSICS state starts with time
    for i0 in range(0, n, ROLLOUT_CHUNK_STEPS):
        i1 = min(n, i0 + ROLLOUT_CHUNK_STEPS)
        states, sens = mujoco.rollout.rollout(model, data, state, ctrl[None, i0:i1])
        # sensordata of step i is computed before step i integrates: it pairs with the state
        # at the start of the step, which is the previous output state (or the initial one).
        q_before = np.vstack([state[None, qadr], states[0, :-1][:, qadr]])
        on_chunk(i0, sens[0], q_before)
        state = states[0, -1].copy()


def run_scan(scenario: Scenario, rng: np.random.Generator | None = None, mesh=None) -> Scan:
    """Simulate the scenario's scan and reconstruct its points (see the module docstring)."""
    timings = {}
    t0 = time.perf_counter()
    root = np.random.SeedSequence(scenario.seed)
    rng_kin, rng_sensor, rng_enc = (np.random.default_rng(s) for s in root.spawn(3))
    if rng is not None:
        rng_sensor = rng
    if mesh is None:
        mesh = load_workpiece_mesh(scenario)
    nominal = build_cell(scenario, "nominal", mesh)
    true_cell = build_cell(scenario, "true", mesh, rng=rng_kin)
    timings["build_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    plan = plan_scan(nominal)
    timings["plan_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    q_ref, qd_ref = solve_joint_references(nominal, plan)
    timings["ik_s"] = time.perf_counter() - t0

    sensor = scenario.sensor
    model = true_cell.model
    sl = _sensor_slices(model)
    n = len(q_ref)
    beams = sensor.beams
    shape = (n,) if sensor.kind == "point" else (n, beams)
    dist = np.empty(shape)
    origin = np.empty(shape + (3,))
    direction = np.empty(shape + (3,))
    normal = np.empty(shape + (3,))
    receiver = np.empty(shape + (3,))
    q_enc = np.empty((n, 6))
    q_true = np.empty((n, 6))
    enc_cols = [sl[f"enc_{j}"].start for j in JOINT_NAMES]

    def on_chunk(i0, sens, q_before):
        i1 = i0 + len(sens)
        q_enc[i0:i1] = sens[:, enc_cols]
        q_true[i0:i1] = q_before
        ray = sens[:, sl["laser_ray"]]
        xaxis = sens[:, sl["laser_xaxis"]]
        yaxis = sens[:, sl["laser_yaxis"]]
        if sensor.kind == "point":
            dist[i0:i1] = ray[:, 0]
            direction[i0:i1] = ray[:, 1:4]
            origin[i0:i1] = ray[:, 4:7]
            normal[i0:i1] = ray[:, 10:13]
            receiver[i0:i1] = ray[:, 4:7] + sensor.baseline_m * xaxis
        else:
            r = ray.reshape(len(sens), beams, 7)
            dist[i0:i1] = r[:, :, 0]
            direction[i0:i1] = r[:, :, 1:4]
            normal[i0:i1] = r[:, :, 4:7]
            # All beams of the fan leave the emitter (the site origin), which the dir data
            # does not carry: rebuild it from the encoder-consistent site pose below.
            origin[i0:i1] = np.nan
            receiver[i0:i1] = sensor.baseline_m * yaxis[:, None, :]

    t0 = time.perf_counter()
    simulate(true_cell, q_ref, qd_ref, on_chunk)
    timings["simulate_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    if sensor.kind == "line":
        # Site origin per step from the true kinematics (same step as the ray).
        site_pos = _site_positions(true_cell, q_true)
        origin[:] = site_pos[:, None, :]
        receiver += site_pos[:, None, :]
    rays = RawRays(dist, origin, direction, normal, receiver)
    batch = mujoco.batch.Batch(model, RAY_THREADS, nthread=RAY_THREADS)
    meas: Measurement = measure(rays, sensor, scenario.noise, rng_sensor, model, STATIC_GROUPS, batch)
    timings["sensor_model_s"] = time.perf_counter() - t0

    # Robot-side error sources on what the controller logs.
    t = plan.t.copy()
    q_log = q_enc.copy()
    if scenario.noise.time_skew_s != 0.0:
        # The distance at t pairs with the joints read at t - skew.
        ts = np.clip(t - scenario.noise.time_skew_s, t[0], t[-1])
        q_log = np.column_stack([np.interp(ts, t, q_log[:, j]) for j in range(6)])
    if scenario.noise.encoder_sigma_rad > 0:
        q_log = q_log + rng_enc.normal(0.0, scenario.noise.encoder_sigma_rad, q_log.shape)

    t0 = time.perf_counter()
    T_fs_nominal = scenario.sensor.T_flange_sensor
    beam_dirs = np.array([[0.0, 0.0, 1.0]])
    if sensor.kind == "point":
        points = reconstruct_points(q_log, meas.d, UR5E_DH, T_fs_nominal)
    else:
        beam_dirs = fan_directions_sensor(sensor)
        points = reconstruct_line_points(q_log, meas.d, beam_dirs, UR5E_DH, T_fs_nominal)
    timings["reconstruct_s"] = time.perf_counter() - t0

    T_base_world = inv_pose(scenario.T_world_base)
    return Scan(
        scenario=scenario, t=t, q=q_log, d=meas.d, valid=meas.valid, status=meas.status,
        line=plan.line.copy(), points_base=points, q_ref=q_ref, q_true=q_true, plan=plan,
        T_base_workpiece_true=T_base_world @ scenario.workpiece.T_world_workpiece_true,
        T_base_workpiece_nominal=T_base_world @ scenario.workpiece.T_world_workpiece_nominal,
        T_flange_sensor_nominal=T_fs_nominal, beam_dirs_sensor=beam_dirs, d_true=meas.d_true,
        timings_s=timings,
    )


def _site_positions(cell: Cell, q: np.ndarray) -> np.ndarray:
    model, data = cell.model, cell.data
    out = np.empty((len(q), 3))
    site = cell.sensor_site
    for i, qi in enumerate(q):
        data.qpos[cell.qpos_adr] = qi
        mujoco.mj_kinematics(model, data)
        out[i] = data.site_xpos[site]
    return out


def fan_directions_sensor(sensor) -> np.ndarray:
    """(B, 3) unit beam directions of the line profiler in the sensor frame.

    The fan is the 1-pixel-high perspective camera of ``twin.cell``: pixel centres spread
    evenly over ``fan_deg`` in the sensor's x-z plane.
    """
    half_width = np.tan(np.radians(sensor.fan_deg) / 2)
    b = sensor.beams
    x = ((np.arange(b) + 0.5) / b * 2.0 - 1.0) * half_width
    dirs = np.column_stack([x, np.zeros(b), np.ones(b)])
    return dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
