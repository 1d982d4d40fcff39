"""Touch probing in the true cell at 1 ms: the probing moves, the trigger, the hits.

A probing program is a list of targets (an expected contact point, its outward normal and
the probe's spin about the stylus, robot base frame). For each target the arm, holding the
stylus straight down (:class:`twin.ik.IKSolver` on the ball centre), makes the moves a CMM
makes:

1. transit: up to the safe height, across (turning to the target's spin), down to the
   approach point ``approach_m`` off the expected surface along its normal
   (``transit_speed_m_s``, each straight leg from rest to rest);
2. probing move: along the normal at ``probing_speed_m_s``, until the probe triggers or the
   ball centre is ``search_m`` past the expected surface: no trigger there is a reported
   miss, never a point;
3. on the trigger the controller brakes (``stop_deceleration_m_s2``) and retracts to the
   approach point.

Moves 2 and 3 are :func:`twin.touch_probing.probing_move`, the arm its machine
(:class:`_ArmProbingLine`).

The moves are Cartesian straight lines, solved on the NOMINAL cell every 10 ms and joined by
a clamped cubic spline, then simulated in the TRUE cell (servos, gravity) at 1 ms, one rollout
continuing the last (:func:`twin.sim.simulate` from its final state). The knots come from the
UR closed form on the arm's branch, which is what mink converges to wherever mink's table
avoidance does not act; a move the closed form cannot stand in for (a link near the table, a
wrist flip, a joint limit) is solved by mink knot by knot (:class:`twin.ik.IKSolver`). The
touch and the trigger come from the true ball-centre motion and the exact part
(:func:`twin.sensors.touch_probe.find_trigger`); the hit is the ball centre from the joint
encoders latched at the trigger (plus their noise) with the nominal kinematics.

Checked on every move: the ball, the stylus and the probe body against the exact part,
the reference sphere and the table (an unintended contact is a ball touch outside a probing
move, or any touch of the stylus or the body; the distances are exact wherever they decide
a contact or the smallest clearance, elsewhere bounded from the samples around them); the
arm and the laser housing against the part's height field and the table through MuJoCo's
contact sensors
(:func:`twin.replay.add_collision_checks`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import numpy as np
from scipy.interpolate import CubicSpline

from algorithms.arraytypes import FloatArray
from algorithms.geometry.kinematics import dh_forward, ur_branch, ur_inverse
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, make_pose, transform_points
from twin.cell import Cell, build_spec, compile_cell
from twin.errors import TwinError
from twin.ik import TABLE_DETECTION_DISTANCE_M, IKSolver, reachable
from twin.realize import Realized
from twin.replay import ContactRecord, add_collision_checks, contact_columns, contact_records
from twin.robot import HOME_Q, UR5E_DH, VELOCITY_LIMIT_RAD_S
from twin.sensors.base import sensor_slice
from twin.sensors.touch_probe import BALL_SITE, MODULE_SITE, Trigger, probe_spec
from twin.sim import simulate
from twin.touch_probing import probing_move
from twin.trajectory import TABLE_CLEARANCE_M, TableCheck, site_in_flange

IK_KNOT_STEPS = 10
IK_POSITION_TOL_M = 1e-7
IK_ORIENTATION_TOL_RAD = 1e-6
TRANSIT_ACCELERATION_M_S2 = 1.0
SPIN_RATE_RAD_S = 1.0
# Probing moves are simulated in chunks this long, so the rollout stops soon after a trigger.
PROBE_CHUNK_STEPS = 50
# Contact checks sample the stylus and the body this densely along their axis [m].
CONTACT_SAMPLE_M = 0.001
# ... and compute every this many 1 ms samples first, to bound the others (ProbingProgram._gaps).
CONTACT_STRIDE = 16
# The probe moves straight down (its stylus along -z of the world).
STYLUS_AXIS_WORLD = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class ProbeTarget:
    """A point to probe: the expected contact point and outward normal (robot base frame)."""

    point: np.ndarray
    normal: np.ndarray
    label: str = ""
    #: rotation of the probe about its stylus (world z) [rad]: chosen by the planner so the
    #: laser's housing beside the probe clears the part
    spin_rad: float = 0.0


@dataclass(frozen=True)
class ProbeHit:
    """The outcome of one probing move (robot base frame, SI units).

    Attributes:
        target: what was planned.
        hit: whether the probe triggered within the search distance.
        centre: (3,) the recorded ball centre (latched encoders, nominal kinematics); NaN on a miss.
        R_base_probe: (3, 3) the probe frame's rotation at the trigger (nominal kinematics).
        trigger_t_s: the trigger's time on the program's timeline [s] (NaN on a miss).
        miss: None, or why there is no point.
        overtravel_m: how far the ball went past the trigger before it stopped [m].
        q: (6,) the joint readings latched at the trigger [rad] (NaN on a miss).
        truth: the true touch and trigger (evaluation only), or None.
    """

    target: ProbeTarget
    hit: bool
    centre: np.ndarray
    R_base_probe: np.ndarray
    trigger_t_s: float
    miss: str | None
    overtravel_m: float
    q: np.ndarray = field(default_factory=lambda: np.full(6, np.nan))
    truth: Trigger | None = field(default=None, repr=False)


@dataclass(frozen=True)
class ProbingLog:
    """A probing program as it ran in the true cell.

    Attributes:
        t: (n,) times [s] on the program's timeline (starting at ``t_offset_s``).
        q: (n, 6) true joint positions [rad]; q_ref: (n, 6) the references.
        ball: (n, 3) true ball centre, robot base frame [m].
        phase: (n,) 0 transit, 1 probing move, 2 stop and retract.
        hits: one per target, in order.
        contacts: unintended contacts (exact probe checks and MuJoCo's arm checks).
        min_clearance_m: smallest distance of the stylus and body to the part, sphere or
            table over the program [m] (negative: a contact).
        wall_s: wall time [s].
    """

    t: np.ndarray
    q: np.ndarray
    q_ref: np.ndarray
    ball: np.ndarray
    phase: np.ndarray
    hits: tuple
    contacts: tuple
    min_clearance_m: float
    wall_s: float
    final_state: np.ndarray | None = field(repr=False)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0

    @property
    def misses(self) -> list[ProbeHit]:
        return [h for h in self.hits if not h.hit]


def build_probe_cell(realized: Realized) -> Cell:
    """The true cell with the probe, the part's height field and the arm's contact sensors."""
    if realized.scenario.probe is None:
        raise TwinError("the scenario has no [probe] table: nothing to probe with")
    spec, poses = build_spec(realized, "true")
    add_collision_checks(spec, realized.workpiece.mesh)
    return compile_cell(spec, realized, "true", poses)


class Obstacles:
    """Exact distances to what the probe may touch, world frame: the true part (its exact
    mesh), the reference sphere (analytic) and the table (z = 0)."""

    def __init__(self, cell: Cell, index: MeshIndex):
        self.index = index
        self.T_workpiece_world = inv_pose(cell.T_world_workpiece)
        lo, hi = index.mesh.bounds
        self.box_lo = lo
        self.box_hi = hi
        probe = probe_spec(cell.scenario)
        self.sphere_centre = np.asarray(probe.sphere_xyz_m, dtype=np.float64)
        self.sphere_radius = probe.sphere_radius_m

    def distance(self, points_world: np.ndarray, reach_m: float = np.inf) -> np.ndarray:
        """(n,) smallest signed distance [m] to the part, the sphere and the table; the part
        is queried only where it is within ``reach_m`` of its bounding box (else +inf)."""
        return self.distance_and_bound(points_world, reach_m)[0]

    def distance_and_bound(self, points_world: np.ndarray, reach_m: float) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`distance`, and a lower bound of the true distance: the same, with the
        distance to the part's bounding box where the part was not queried."""
        p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        d = np.minimum(p[:, 2], np.linalg.norm(p - self.sphere_centre, axis=1) - self.sphere_radius)
        pw = transform_points(self.T_workpiece_world, p)
        out = np.maximum(self.box_lo - pw, pw - self.box_hi).max(axis=1)
        near = out < reach_m
        if near.any():
            d[near] = np.minimum(d[near], self.index.signed_distance(pw[near]))
        bound = d.copy()
        far = ~near
        if far.any():
            to_box = np.linalg.norm(np.maximum(np.maximum(self.box_lo - pw[far], pw[far] - self.box_hi), 0.0), axis=1)
            bound[far] = np.minimum(d[far], to_box)
        return d, bound


def line_profile(p0: np.ndarray, p1: np.ndarray, speed: float, accel: float, dt: float) -> np.ndarray:
    """Positions (k, 3) every ``dt`` on the straight move p0 -> p1, from rest to rest
    (trapezoidal speed, or triangular when the move is short); the first row is p0."""
    L = float(np.linalg.norm(p1 - p0))
    if L < 1e-12:
        return p0[None].copy()
    v = min(speed, np.sqrt(accel * L))
    ta = v / accel
    T = L / v + ta
    t = np.arange(0.0, T + dt, dt)
    t[-1] = min(t[-1], T)
    s = np.where(t < ta, 0.5 * accel * t**2,
                 np.where(t < T - ta, v * (t - ta / 2), L - 0.5 * accel * np.clip(T - t, 0, None) ** 2))
    s = np.clip(s, 0.0, L)
    s[-1] = L
    return p0 + np.outer(s / L, p1 - p0)


def ball_pose(position_world: np.ndarray, spin_rad: float = 0.0) -> np.ndarray:
    """(4, 4) target of the ball site: at ``position_world``, stylus straight down, turned by
    ``spin_rad`` about it."""
    return ball_poses(np.asarray(position_world, dtype=np.float64)[None], np.array([spin_rad]))[0]


def ball_poses(positions_world: np.ndarray, spins_rad: np.ndarray) -> np.ndarray:
    """(m, 4, 4) :func:`ball_pose` of positions (m, 3) and spins (m,): ``Rz(spin) diag(1, -1, -1)``."""
    c, s = np.cos(spins_rad), np.sin(spins_rad)
    T = np.zeros((len(c), 4, 4))
    T[:, 0, 0], T[:, 0, 1] = c, s
    T[:, 1, 0], T[:, 1, 1] = s, -c
    T[:, 2, 2] = -1.0
    T[:, 3, 3] = 1.0
    T[:, :3, 3] = positions_world
    return T


class ProbingProgram:
    """Runs probing moves one after the other in the true cell (module docstring).

    Args:
        realized: the realized scenario (its ``encoder`` and ``probe`` random streams).
        nominal: the nominal cell (IK); cell: :func:`build_probe_cell` (simulation).
        rng: the probe's random stream (pre-travel repeatability).
        t_offset_s: where the program starts on the recording's timeline [s].

    Attributes:
        logs: the 1 ms samples simulated so far, per key (``t``, ``q``, ``q_ref``, ``ball``,
            ``module`` (world frame), ``phase``, ``cdata``) a list of chunks in time order, as
            :meth:`log` joins them.
    """

    def __init__(self, realized: Realized, nominal: Cell, cell: Cell, rng: np.random.Generator,
                 t_offset_s: float = 0.0, q_start: np.ndarray = HOME_Q):
        self.realized = realized
        self.scenario = realized.scenario
        self.spec = probe_spec(self.scenario)
        self.nominal = nominal
        self.cell = cell
        self.rng = rng
        self.rng_encoder = realized.streams.generator("probe_encoder")
        if cell.probe is None:
            raise TwinError("the probing cell has no touch probe: build it with build_probe_cell")
        self.touch_probe = cell.probe
        self.obstacles = Obstacles(cell, realized.workpiece.index)
        self.dt = float(cell.model.opt.timestep)
        self.solver = IKSolver(nominal.model, BALL_SITE, IK_POSITION_TOL_M, IK_ORIENTATION_TOL_RAD,
                               avoid_table=True)
        # the closed-form IK's data: the ball site in the flange frame, the joint ranges, and
        # where mink's table avoidance would act (_closed_form_knots)
        self.T_ball_flange = inv_pose(site_in_flange(nominal, BALL_SITE))
        self.joint_range = nominal.model.jnt_range[:6].copy()
        self.near_table = TableCheck(nominal, TABLE_DETECTION_DISTANCE_M)
        self.spin = 0.0
        self.T_world_base = cell.T_world_base
        self.T_base_world = inv_pose(cell.T_world_base)
        model = cell.model
        self.ball_cols = sensor_slice(model, f"{BALL_SITE}_pos")
        self.module_cols = sensor_slice(model, f"{MODULE_SITE}_pos")
        self.contact_names, self.contact_cols = contact_columns(model)
        self.t0 = t_offset_s
        self.state: np.ndarray | None = None
        self.q_start = np.asarray(q_start, dtype=np.float64)
        self.logs: dict[str, list] = {k: [] for k in ("t", "q", "q_ref", "ball", "module", "phase", "cdata")}
        self.wall_s = 0.0

    # ------------------------------------------------------------------ motion
    def _ik_references(self, P_world: np.ndarray, qd_start: np.ndarray | None = None,
                       spin_to: float | None = None) -> tuple:
        """Joint references (k, 6) and their rates along ball positions P (k, 3) every dt:
        IK every IK_KNOT_STEPS steps, a cubic spline in between (starting at ``qd_start``).
        With ``spin_to`` the probe turns about its stylus from the current spin to it along
        the move (in proportion to the distance travelled)."""
        k = len(P_world)
        knots = np.arange(0, k, IK_KNOT_STEPS)
        if knots[-1] != k - 1:
            knots = np.append(knots, k - 1)
        spin0 = self.spin
        spin1 = spin0 if spin_to is None else spin0 + np.angle(np.exp(1j * (spin_to - spin0)))
        travel = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P_world, axis=0), axis=1))])
        frac = travel / travel[-1] if travel[-1] > 0 else np.linspace(0.0, 1.0, k)
        T_world_ball = ball_poses(P_world[knots], spin0 + frac[knots] * (spin1 - spin0))
        q = self._closed_form_knots(T_world_ball)
        if q is None:
            q = self._mink_knots(T_world_ball)
        self.solver.set_q(q[-1])
        self.spin = spin1
        t = np.arange(k) * self.dt
        if len(knots) == 1:
            return np.repeat(q, k, axis=0), np.zeros((k, 6))
        start = (1, np.zeros(6)) if qd_start is None else (1, qd_start)
        spline = CubicSpline(t[knots], q, axis=0, bc_type=(start, (1, np.zeros(6))))
        return spline(t), spline(t, 1)

    def _closed_form_knots(self, T_world_ball: np.ndarray) -> np.ndarray | None:
        """Joint angles (m, 6) of ball poses (m, 4, 4) from the UR closed form, on the branch the
        arm is on, continuous from its configuration: what mink converges to (to its
        tolerances, ``IK_POSITION_TOL_M``) where no link is within the table-avoidance
        detection distance. None where the closed form cannot stand in for mink: a pose out of
        reach or beyond the joint ranges, a joint that would move faster than its velocity
        limit between knots (a wrist flip), a link near the table (mink's avoidance acts there)."""
        q_now = self.solver.q
        branch = ur_branch(q_now, UR5E_DH)
        sol = ur_inverse(self.T_base_world @ T_world_ball @ self.T_ball_flange, UR5E_DH, branches=(branch,))
        if not sol.valid[:, branch].all():
            return None
        q = np.unwrap(np.vstack([q_now, sol.q[:, branch]]), axis=0)
        if np.any(np.abs(np.diff(q, axis=0)) > VELOCITY_LIMIT_RAD_S * IK_KNOT_STEPS * self.dt):
            return None
        q = q[1:]
        if np.any((q < self.joint_range[:, 0]) | (q > self.joint_range[:, 1])):
            return None
        if any(self.near_table.nearest(qi) is not None for qi in q):
            return None
        return q

    def _mink_knots(self, T_world_ball: np.ndarray) -> np.ndarray:
        """Joint angles (m, 6) of ball poses (m, 4, 4) by mink, each from the last."""
        q = np.empty((len(T_world_ball), 6))
        for i, T in enumerate(T_world_ball):
            pe, oe, _ = self.solver.solve(T, dt=IK_KNOT_STEPS * self.dt, max_iterations=50)
            if not reachable(pe, oe):
                p = T[:3, 3]
                raise TwinError(f"probing move unreachable: the ball centre at world ({p[0]:.4f}, {p[1]:.4f}, "
                                f"{p[2]:.4f}) m stays {pe * 1e3:.2f} mm / {np.degrees(oe):.2f} deg off")
            q[i] = self.solver.q
        return q

    def _n_logged(self) -> int:
        """How many 1 ms samples the program has logged so far."""
        return sum(len(x) for x in self.logs["t"])

    def _run(self, q_ref: np.ndarray, qd_ref: np.ndarray, phase: int, chunk_steps: int = 2000,
             t_base_s: float | None = None, i_first: int = 0, states_out: list | None = None) -> None:
        """Simulate references (k, 6) from the current state and log every 1 ms sample.

        Reference i is stamped ``t_base_s + (i_first + i) * dt`` [s] (by default ``t_base_s``
        is the time right after the samples logged so far, ``i_first`` 0: a probing move rolled
        out chunk by chunk stamps every chunk from the move's start). With ``states_out`` the
        full state after every step is appended to it, chunk by chunk.
        """
        if t_base_s is None:
            t_base_s = self.t0 + self._n_logged() * self.dt

        def on_chunk(i0, sens, q_before):
            n = len(sens)
            t = t_base_s + (i_first + i0 + np.arange(n)) * self.dt
            self.logs["t"].append(t)
            self.logs["q"].append(q_before.copy())
            self.logs["q_ref"].append(q_ref[i0:i0 + n])
            self.logs["ball"].append(sens[:, self.ball_cols].copy())
            self.logs["module"].append(sens[:, self.module_cols].copy())
            self.logs["phase"].append(np.full(n, phase, dtype=np.int8))
            self.logs["cdata"].append(sens[:, self.contact_cols].reshape(n, len(self.contact_names), 5)
                                       if len(self.contact_names) else np.zeros((n, 0, 5)))

        t0 = time.perf_counter()
        self.state = simulate(self.cell, q_ref, qd_ref, on_chunk, state=self.state, chunk_steps=chunk_steps,
                              states_out=states_out)
        self.wall_s += time.perf_counter() - t0

    def _truncate(self, n_keep_total: int) -> None:
        """Keep only the first ``n_keep_total`` logged steps (the controller reacted there)."""
        total = 0
        for i, t in enumerate(self.logs["t"]):
            if total + len(t) >= n_keep_total:
                cut = n_keep_total - total
                for key in self.logs:
                    self.logs[key] = self.logs[key][:i] + [self.logs[key][i][:cut]]
                return
            total += len(t)

    def ball_world(self) -> np.ndarray:
        """The current reference ball position (world) from the solver's configuration."""
        return self.solver.site_pose()[:3, 3].copy()

    def start(self) -> None:
        """Put the arm at rest at its start configuration, stylus down."""
        self.solver.set_q(self.q_start)
        T = self.solver.site_pose()
        self.spin = float(np.arctan2(T[1, 0], T[0, 0]))
        pe, oe, _ = self.solver.solve(ball_pose(self.ball_world(), self.spin), dt=0.05, max_iterations=2000,
                                      velocity_limited=False)
        q0 = self.solver.q
        self.state = None
        q_ref = np.repeat(q0[None], 2, axis=0)
        self._run(q_ref, np.zeros_like(q_ref), 0)

    def transit(self, to_world: np.ndarray, safe_z_world: float, spin_rad: float | None = None) -> None:
        """Up to the safe height, across (turning to ``spin_rad``), down to ``to_world`` (ball
        centre), at transit speed."""
        here = self.ball_world()
        z = max(safe_z_world, here[2], to_world[2])
        legs = [(here, np.r_[here[:2], z]), (np.r_[here[:2], z], np.r_[to_world[:2], z]),
                (np.r_[to_world[:2], z], to_world)]
        for i, (a, b) in enumerate(legs):
            if np.linalg.norm(b - a) < 1e-9:
                continue
            P = line_profile(a, b, self.spec.transit_speed_m_s, TRANSIT_ACCELERATION_M_S2, self.dt)
            q_ref, qd_ref = self._ik_references(P, spin_to=spin_rad if i == 1 else None)
            self._run(q_ref, qd_ref, 0)
        turn = abs(float(np.angle(np.exp(1j * (spin_rad - self.spin))))) if spin_rad is not None else 0.0
        if turn > 1e-9:
            # the across leg was empty: turn on the spot (at most SPIN_RATE_RAD_S)
            k = max(int(np.ceil(turn / SPIN_RATE_RAD_S / self.dt)), 2 * IK_KNOT_STEPS)
            q_ref, qd_ref = self._ik_references(np.repeat(to_world[None], k, axis=0), spin_to=spin_rad)
            self._run(q_ref, qd_ref, 0)

    def probe(self, target: ProbeTarget, safe_z_world: float) -> ProbeHit:
        """Transit to the target's approach point, probe, brake and retract (module docstring)."""
        p = self.spec
        r = p.ball_radius_m
        point_w = transform_points(self.T_world_base, target.point[None])[0]
        n_w = self.T_world_base[:3, :3] @ target.normal
        c0 = point_w + (r + p.approach_m) * n_w
        c1 = point_w + (r - p.search_m) * n_w
        self.transit(c0, safe_z_world, target.spin_rad)
        out = probing_move(_ArmProbingLine(self, c0, c1), self._gap, self.touch_probe.pretravel, self.rng)
        trig = out.trigger
        if trig is None or out.reading is None or out.stop_centre is None:
            return ProbeHit(target, False, np.full(3, np.nan), np.eye(3), float("nan"),
                            f"no trigger within the search distance ({p.search_m * 1e3:g} mm past the expected "
                            "surface)", 0.0)
        q_latch = out.reading
        centre, R_bp = self._recorded_centre(q_latch)
        overtravel = float(np.linalg.norm(out.stop_centre - trig.centre_trigger))
        to_base = self.T_base_world
        truth = Trigger(trig.touch_t_s, trig.trigger_t_s, transform_points(to_base, trig.centre_touch[None])[0],
                        transform_points(to_base, trig.centre_trigger[None])[0], to_base[:3, :3] @ trig.direction,
                        trig.pretravel_m)
        return ProbeHit(target, True, centre, R_bp, trig.trigger_t_s, None, overtravel, q_latch, truth)

    def _gap(self, centres_world: np.ndarray) -> np.ndarray:
        """(k,) gap [m] of ball centres (k, 3), world frame, to the part, the sphere or the table."""
        r = self.spec.ball_radius_m
        return self.obstacles.distance(centres_world, reach_m=r + 1e-3) - r

    def transit_line(self, a: np.ndarray, b: np.ndarray, speed: float, phase: int) -> None:
        P = line_profile(a, b, speed, TRANSIT_ACCELERATION_M_S2, self.dt)
        q_ref, qd_ref = self._ik_references(P)
        self._run(q_ref, qd_ref, phase)

    # ------------------------------------------------------------------ readings
    def _R_world_probe_true(self) -> np.ndarray:
        """The probe frame's rotation in the world at the latest simulated step (true cell)."""
        q = self.logs["q"][-1][-1]
        T_bf = dh_forward(q, UR5E_DH)
        return self.T_world_base[:3, :3] @ T_bf[:3, :3] @ self.spec.T_flange_probe[:3, :3]

    def _latched_joints(self, t_s: float) -> np.ndarray:
        """Joint encoder readings latched at ``t_s`` (true positions interpolated between the
        1 ms samples, plus the encoders' noise)."""
        t = np.concatenate(self.logs["t"])
        q = np.vstack(self.logs["q"])
        q_t = np.array([np.interp(t_s, t, q[:, j]) for j in range(6)])
        sigma = self.scenario.noise.encoder_sigma_rad
        if sigma > 0:
            q_t = q_t + self.rng_encoder.normal(0.0, sigma, 6)
        return q_t

    def _recorded_centre(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ball centre and probe rotation, base frame, from joints with the nominal kinematics."""
        T_bp = dh_forward(q, UR5E_DH) @ self.spec.T_flange_probe
        return T_bp[:3, 3] + self.spec.tip_length_m * T_bp[:3, 2], T_bp[:3, :3]

    # ------------------------------------------------------------------ the whole program
    def run(self, targets: list[ProbeTarget], safe_z_world: float,
            say: Callable[[str], None] = lambda m: None) -> tuple[ProbeHit, ...]:
        """Probe every target in order (from rest at the start configuration the first time)."""
        if self.state is None and not self.logs["t"]:
            self.start()
        hits = []
        for i, tg in enumerate(targets):
            hits.append(self.probe(tg, safe_z_world))
            say(f"probe point {i + 1}/{len(targets)} ({tg.label}): {'hit' if hits[-1].hit else 'MISS'}")
        return tuple(hits)

    def lift(self, safe_z_world: float) -> None:
        """Straight up to the safe height (the end of a program)."""
        here = self.ball_world()
        self.transit(np.r_[here[:2], max(safe_z_world, here[2])], safe_z_world)

    def log(self, hits: tuple) -> ProbingLog:
        t = np.concatenate(self.logs["t"])
        ball_w = np.vstack(self.logs["ball"])
        module_w = np.vstack(self.logs["module"])
        phase = np.concatenate(self.logs["phase"])
        cdata = np.concatenate(self.logs["cdata"], axis=0)
        contacts = contact_records(self.contact_names, cdata, t, self.T_base_world)
        probe_contacts, clearance = self.probe_contacts(t, ball_w, module_w, phase)
        return ProbingLog(t, np.vstack(self.logs["q"]), np.vstack(self.logs["q_ref"]),
                          transform_points(self.T_base_world, ball_w), phase, hits,
                          tuple(contacts + probe_contacts), clearance, self.wall_s, self.state)

    def probe_contacts(self, t, ball_w, module_w, phase) -> tuple[list, float]:
        """Exact contacts of the ball (outside probing moves), the stylus and the body, over the
        samples ``t`` (n,) [s], ``ball_w`` and ``module_w`` (n, 3) (world frame) and ``phase``
        (n,) (any stretch of :attr:`logs`), and the smallest clearance of the stylus and body [m].

        The distances are exact where they decide anything (:meth:`_gaps`): at every sample
        that could touch, and at every sample that could hold the smallest clearance."""
        axis, parts = self.probe_samples(ball_w, module_w, phase)
        out: list[ContactRecord] = []
        clearance = np.inf
        for name, pts, radius, check, reach_along in parts:
            d = self._gaps(pts, radius, check, ball_w, module_w, axis, reach_along,
                           need_min=name != "probe_ball")
            if name != "probe_ball":
                clearance = min(clearance, float(d.min()))
            out += self.contact_of(name, t, d, check, ball_w)
        return out, clearance

    def contact_of(self, name: str, t, gap, check, ball_w) -> list[ContactRecord]:
        """The one contact record of a part over the samples whose ``gap`` (n,) [m] is negative
        where ``check`` (n,) holds (none: an empty list), at its deepest sample."""
        bad = check & (gap < 0)
        if not bad.any():
            return []
        idx = np.flatnonzero(bad)
        j = idx[np.argmin(gap[idx])]
        where = transform_points(self.T_base_world, ball_w[j][None])[0]
        return [ContactRecord(name, "part, sphere or table (exact)", False, float(t[idx[0]]), float(t[idx[-1]]),
                              int(len(idx)), float(-gap[j]), tuple(where))]

    def probe_samples(self, ball_w, module_w, phase) -> tuple[np.ndarray, tuple]:
        """The probe's stylus axis (n, 3) and its parts as :meth:`probe_contacts` checks them:
        (name, sample points (n, k, 3), radius, samples checked, farthest point from the module
        along the axis [m]: None for the ball, whose points are the centres themselves)."""
        p = self.spec
        axis = ball_w - module_w
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        stem = p.stylus_length_m - p.ball_radius_m
        n_stem = max(int(np.ceil(stem / CONTACT_SAMPLE_M)), 2)
        n_body = max(int(np.ceil(p.body_length_m / CONTACT_SAMPLE_M)), 2)
        every = np.ones(len(phase), bool)
        stylus = AxisPoints(module_w, axis, np.linspace(0, stem, n_stem))
        body = AxisPoints(module_w, -axis, np.linspace(0, p.body_length_m, n_body))
        return axis, (("probe_ball", ball_w[:, None, :], p.ball_radius_m, phase == 0, None),
                      ("probe_stylus", stylus, p.stylus_radius_m, every, stem),
                      ("probe_body", body, p.body_radius_m, every, p.body_length_m))

    def _gaps(self, pts, radius, check, ball_w, module_w, axis, reach_along, need_min: bool) -> np.ndarray:
        """(n,) the gap [m] of each sample's points (n, k, 3) to the obstacles, exact wherever
        it is negative on a checked sample or (``need_min``) could be the smallest; +inf at
        samples shown to be farther than that.

        The gap is 1-Lipschitz in each point, and a point of the probe at ``s`` from the module
        along the axis (at most ``reach_along``; None: the ball's centre) moves by at most
        ``|dm| + s |da|`` between two samples (dm the module's move, da the axis's change; the
        ball's centre moves by |db|). So lower bounds of the gaps every ``CONTACT_STRIDE``
        samples (exact near the part, the distance to its bounding box beyond) bound the
        others from below, and only the samples whose bound is under the threshold (0, or with
        ``need_min`` the smallest gap of the strided samples, if larger) are computed."""
        n, k = pts.shape[:2]
        if n == 0:
            return np.zeros(0)

        def gap(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            d, bound = self.obstacles.distance_and_bound(pts[rows].reshape(-1, 3), reach_m=radius + 0.01)
            return d.reshape(-1, k).min(axis=1) - radius, bound.reshape(-1, k).min(axis=1) - radius

        strided = np.unique(np.r_[np.arange(0, n, CONTACT_STRIDE), n - 1])
        at = np.clip(np.searchsorted(strided, np.arange(n) - CONTACT_STRIDE // 2), 0, len(strided) - 1)
        anchor = strided[at]
        if reach_along is None:
            moved = np.linalg.norm(ball_w - ball_w[anchor], axis=1)
        else:
            moved = (np.linalg.norm(module_w - module_w[anchor], axis=1)
                     + reach_along * np.linalg.norm(axis - axis[anchor], axis=1))
        d = np.full(n, np.inf)
        d[strided], bound = gap(strided)    # d as every sample is reported: the part near its box
        lower = bound[at] - moved - 1e-9
        threshold = max(0.0, float(d[strided].min())) if need_min else 0.0
        todo = np.flatnonzero((lower < threshold) & (check | need_min))
        todo = todo[~np.isin(todo, strided)]
        if len(todo):
            d[todo] = gap(todo)[0]
        return d


class AxisPoints:
    """Points along the probe's axis at every sample, made only for the samples asked for:
    ``origin`` (n, 3) plus ``direction`` (n, 3) times each of ``offsets`` (k,) [m]; indexing
    by rows gives (rows, k, 3), ``np.asarray`` all of them."""

    def __init__(self, origin: np.ndarray, direction: np.ndarray, offsets: np.ndarray):
        self.origin, self.direction, self.offsets = origin, direction, offsets

    @property
    def shape(self) -> tuple[int, int, int]:
        return len(self.origin), len(self.offsets), 3

    def __getitem__(self, rows) -> np.ndarray:
        return self.origin[rows][:, None, :] + self.direction[rows][:, None, :] * self.offsets[None, :, None]

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        return self[slice(None)] if dtype is None else self[slice(None)].astype(dtype)


class _ArmProbingLine:
    """The arm as the probing engine's machine (:class:`twin.touch_probing.ProbingMachine`).

    The ball-centre reference runs along the probing line ``c0_world -> c1_world`` (world
    frame, from rest at the probing speed, the stop deceleration as its acceleration); its
    joint references are solved for the whole line before the arm moves, and rolled out
    PROBE_CHUNK_STEPS at a time so the rollout stops soon after a trigger.
    """

    chunk_steps = PROBE_CHUNK_STEPS

    def __init__(self, program: ProbingProgram, c0_world: np.ndarray, c1_world: np.ndarray):
        p = program.spec
        self.program = program
        self.c0_world = c0_world
        self.c1_world = c1_world
        # where the reference ends (the line's end, or where the brake stops it): the retract starts there
        self.end_world = c1_world
        self.P_world = line_profile(c0_world, c1_world, p.probing_speed_m_s, p.stop_deceleration_m_s2, program.dt)
        self.q_ref, self.qd_ref = program._ik_references(self.P_world)
        self.n_before = program._n_logged()
        self.t_base_s = program.t0 + self.n_before * program.dt
        self.n_done = 0
        self.states: list[np.ndarray] = []

    def lead_in(self) -> tuple[FloatArray, FloatArray]:
        """None: the move's first sample is the arm at the line's start."""
        return np.zeros((0, 3)), np.zeros(0)

    def advance(self, n_steps: int) -> tuple[FloatArray, FloatArray]:
        """Roll out the next ``n_steps`` references (phase 1): true ball centres (world) and times."""
        i0 = self.n_done
        i1 = min(i0 + n_steps, len(self.q_ref))
        if i1 <= i0:
            return np.zeros((0, 3)), np.zeros(0)
        prog = self.program
        prog._run(self.q_ref[i0:i1], self.qd_ref[i0:i1], 1, chunk_steps=n_steps, t_base_s=self.t_base_s,
                  i_first=i0, states_out=self.states)
        self.n_done = i1
        return prog.logs["ball"][-1], prog.logs["t"][-1]

    def R_world_probe(self) -> FloatArray:
        return self.program._R_world_probe_true()

    def latch(self, t_s: float) -> FloatArray:
        """The joint encoders (6,) [rad] latched at ``t_s``."""
        return self.program._latched_joints(t_s)

    def brake(self, trigger_t_s: float) -> FloatArray:
        """The controller reacts at the first 1 ms cycle after the trigger: the rollout past it
        is dropped, and the reference brakes along the probing line from where it was then."""
        prog = self.program
        dt = prog.dt
        k_react = int(np.ceil((trigger_t_s - self.t_base_s) / dt - 1e-9))
        k_react = min(max(k_react, 1), self.n_done)
        prog._truncate(self.n_before + k_react)
        prog.state = np.vstack(self.states)[k_react - 1].copy()
        P = self.P_world
        v_ref = P[min(k_react, len(P) - 1)] - P[min(k_react - 1, len(P) - 2)]
        speed = float(np.linalg.norm(v_ref)) / dt
        u = (self.c1_world - self.c0_world) / np.linalg.norm(self.c1_world - self.c0_world)
        P_brake = brake_profile(P[min(k_react, len(P) - 1)], u, speed, prog.spec.stop_deceleration_m_s2, dt)
        prog.solver.set_q(self.q_ref[min(k_react, len(self.q_ref) - 1)])
        q_b, qd_b = prog._ik_references(P_brake, qd_start=self.qd_ref[min(k_react, len(self.qd_ref) - 1)])
        prog._run(q_b, qd_b, 2)
        self.end_world = P_brake[-1]
        return prog.logs["ball"][-1][-1]

    def retract(self) -> None:
        """Back to the approach point at transit speed (phase 2)."""
        prog = self.program
        prog.transit_line(self.end_world, self.c0_world, prog.spec.transit_speed_m_s, 2)


def brake_profile(p_start: np.ndarray, u: np.ndarray, speed: float, deceleration: float, dt: float) -> np.ndarray:
    """Positions (k, 3) every ``dt`` braking from ``speed`` [m/s] at ``deceleration`` [m/s^2]
    along the unit direction ``u`` from ``p_start`` to rest; the first row is ``p_start``."""
    s_stop = speed**2 / (2 * deceleration)
    tb = np.arange(0.0, speed / deceleration + dt, dt)
    tb[-1] = min(tb[-1], speed / deceleration)
    s = np.minimum(speed * tb - 0.5 * deceleration * tb**2, s_stop)
    return p_start + np.outer(s, u)


def safe_height_world(realized: Realized, T_world_workpiece: np.ndarray) -> float:
    """Transit height: the part's top (at the given pose) or the reference sphere's top, plus
    the probe's ``safe_height_m`` [m, world z of the ball centre]."""
    probe = probe_spec(realized.scenario)
    top = transform_points(T_world_workpiece, np.asarray(realized.workpiece.mesh.vertices))[:, 2].max()
    top = max(top, probe.sphere_xyz_m[2] + probe.sphere_radius_m)
    return float(top + probe.safe_height_m + probe.ball_radius_m)


def joint_state_of(state: np.ndarray, cell: Cell) -> np.ndarray:
    """The joint positions (6,) in a full physics state."""
    return np.asarray(state)[cell.qpos_adr + 1]


__all__ = ["ProbeHit", "ProbeTarget", "ProbingLog", "ProbingProgram", "brake_profile", "build_probe_cell",
           "line_profile", "safe_height_world"]


class ReachCheck:
    """Whether the arm reaches a probe point's approach and search-end positions with the
    stylus straight down, and at which spin about the stylus: a closed-form solution of the
    UR geometry (:func:`algorithms.geometry.kinematics.ur_inverse`) away from the wrist
    singularity, the links clear of the table, and the laser's housing beside the probe at
    least ``HEAD_CLEARANCE_M`` from the part at the coarse pose (its box sampled on a grid,
    exact distances). Spins are tried nearest the arm's start spin first."""

    SPINS_RAD = np.radians(np.arange(0.0, 360.0, 45.0))
    MIN_WRIST_SIN = 0.05
    HEAD_CLEARANCE_M = 0.010
    HOUSING_GRID = 5

    def __init__(self, nominal: Cell, realized: Realized):
        p = probe_spec(realized.scenario)
        self.realized = realized
        self.nominal = nominal
        self.T_base_world = inv_pose(realized.scenario.T_world_base)
        T_flange_ball = p.T_flange_probe @ make_pose(None, [0.0, 0.0, p.tip_length_m])
        self.T_ball_flange = inv_pose(T_flange_ball)
        self.table = TableCheck(nominal, TABLE_CLEARANCE_M)
        self.data = mujoco.MjData(nominal.model)
        self.housing = nominal.model.geom("laser_housing").id
        g = np.linspace(-1.0, 1.0, self.HOUSING_GRID)
        self.grid = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3) \
            * nominal.model.geom_size[self.housing]
        T_home = realized.scenario.T_world_base @ dh_forward(HOME_Q, UR5E_DH) @ T_flange_ball
        home = float(np.arctan2(T_home[1, 0], T_home[0, 0]))
        self.spins = self.SPINS_RAD[np.argsort(np.abs(np.angle(np.exp(1j * (self.SPINS_RAD - home)))))]

    def spin(self, T_coarse: np.ndarray, point_wp: np.ndarray, normal_wp: np.ndarray) -> float | None:
        """A spin [rad] at which the probe reaches the point and the housing clears, or None."""
        p = probe_spec(self.realized.scenario)
        T = self.realized.scenario.T_world_base @ T_coarse
        ends = [transform_points(T, (point_wp + off * normal_wp)[None])[0]
                for off in (p.ball_radius_m + p.approach_m, p.ball_radius_m - p.search_m)]
        for spin in self.spins:
            if all(self._clear(c, spin, T) for c in ends):
                return float(spin)
        return None

    def _clear(self, c_world: np.ndarray, spin: float, T_world_workpiece: np.ndarray) -> bool:
        sol = ur_inverse(self.T_base_world @ ball_pose(c_world, spin) @ self.T_ball_flange, UR5E_DH)
        good = sol.valid[0] & (sol.wrist_sin[0] > self.MIN_WRIST_SIN)
        for q in sol.q[0][good]:
            if self.table.nearest(q) is None and self._housing_clear(q, T_world_workpiece):
                return True
        return False

    def _housing_clear(self, q: np.ndarray, T_world_workpiece: np.ndarray) -> bool:
        self.data.qpos[self.nominal.qpos_adr] = q
        mujoco.mj_kinematics(self.nominal.model, self.data)
        R = self.data.geom_xmat[self.housing].reshape(3, 3)
        pts_w = self.grid @ R.T + self.data.geom_xpos[self.housing]
        pts_wp = transform_points(inv_pose(T_world_workpiece), pts_w)
        return bool(np.all(self.realized.workpiece.index.signed_distance(pts_wp) > self.HEAD_CLEARANCE_M))

