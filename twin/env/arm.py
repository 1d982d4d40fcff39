"""The arm that carries the laser through an active-scan episode.

Each segment the agent asks for becomes one motion, simulated at 1 ms in the true cell from
where the last one left the arm:

1. retract: the sensor backs off along its beam by ``retract_m`` (joint move);
2. transit: a synchronised point-to-point joint move to ``retract_m`` before the new start
   (by way of the home configuration when the direct move would bring a link near the table
   or the part);
3. approach along the new beam to the start of the line (joint move);
4. the line itself: the sensor poses every 1 ms of a rest-to-rest straight move at the scan
   speed, joints by mink IK every ``LINE_KNOT_STEPS`` ms (a clamped cubic spline in between).

The joints come from the nominal cell (what the controller believes): mink, started for a
far pose from the nearest of the arm's closed-form solutions that keeps the links off the
table and the part. A motion whose transit, approach or line would bring a link (or the
sensor's housing) within ``TABLE_CLEARANCE_M`` of the table or ``PART_CLEARANCE_M`` of the
part's collision shape at its nominal pose (checked every ``TRANSIT_CHECK_S``) is refused, as a
cell's motion planner would refuse it. The motion comes from the true cell; the points are
those the sensor reports on the line, rebuilt from the encoder readings
(:func:`twin.scan.measure_samples`), less those on the table top. Contact sensors on the arm
and the sensor
(:func:`twin.replay.add_collision_checks`) report any collision with the part's collision
shape or the table along the whole motion.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import mujoco
import numpy as np
from scipy.interpolate import CubicSpline

from algorithms.geometry.kinematics import ur_inverse
from algorithms.geometry.se3 import inv_pose
from twin.cell import Cell, build_spec, compile_cell
from twin.ik import IKSolver, reachable
from twin.plan import straight_poses
from twin.realize import Realized
from twin.replay import HeightField, add_collision_checks, contact_columns, contact_records
from twin.robot import HOME_Q, UR5E_DH
from twin.scan import IK_ORIENTATION_TOL_RAD, IK_POSITION_TOL_M, SampleLog, measure_samples
from twin.sim import simulate
from twin.trajectory import TABLE_CLEARANCE_M, TableCheck, joint_move

#: Iterations allowed to solve a pose from a nearby configuration.
NEAR_POSE_ITERATIONS = 200
#: Points this close to the table top (world z = 0) are the table's, not the part's: dropped,
#: as a cell crops its known fixture before localizing [m].
TABLE_CROP_M = 0.0005
#: The planned joint path is checked against the table and the part every this many seconds.
TRANSIT_CHECK_S = 0.02
#: Links keep this far from the part's collision shape at its nominal pose in a planned motion:
#: the placement's spread (3 x 1 mm, 3 x 0.5 deg at the part's size) and the servo's tracking
#: error [m].
PART_CLEARANCE_M = 0.005
#: IK knots along a line every this many 1 ms steps. Sparser than the scan's (a straight line
#: at constant orientation has smooth joints); the points come from the encoders, so the
#: spline between knots moves the path by micrometres without biasing a point.
LINE_KNOT_STEPS = 50


def build_scan_cell(realized: Realized, hfield: HeightField | None = None, which: str = "true") -> Cell:
    """The true (or nominal) cell with the part's collision shape (``hfield``, made once per
    part) and contact sensors on the arm."""
    spec, poses = build_spec(realized, which)
    add_collision_checks(spec, realized.workpiece.mesh, hfield)
    return compile_cell(spec, realized, which, poses)


@dataclass(frozen=True)
class Motion:
    """Joint references of one segment's motion.

    Attributes:
        q_ref, qd_ref: (K, 6) references every 1 ms [rad, rad/s].
        line_start: index of the first sample of the line (the samples that measure).
        q_end: (6,) the joints the motion ends at (the controller's belief) [rad].
        beam_world: (3,) the line's planned beam direction, world frame.
    """

    q_ref: np.ndarray
    qd_ref: np.ndarray
    line_start: int
    q_end: np.ndarray
    beam_world: np.ndarray

    @property
    def steps(self) -> int:
        return len(self.q_ref)


@dataclass(frozen=True)
class SegmentResult:
    """What one motion measured: ``points_base`` (M, 3) valid points on the line [m] (robot
    base frame), the line's planned beam direction ``beam_base`` (3,) (robot base frame),
    ``readings_m`` (M,) the distances the sensor reported for them, ``duration_s`` of the
    motion, the ``contacts`` found (ContactRecord)."""

    points_base: np.ndarray
    beam_base: np.ndarray
    readings_m: np.ndarray
    duration_s: float
    contacts: list

    def decimated(self, at_most: int) -> SegmentResult:
        """The same with at most ``at_most`` points, evenly spaced along the line."""
        n = len(self.points_base)
        if n <= at_most:
            return self
        keep = np.unique(np.round(np.linspace(0, n - 1, at_most)).astype(np.int64))
        return replace(self, points_base=self.points_base[keep], readings_m=self.readings_m[keep])


class ScanArm:
    """IK on the nominal cell, 1 ms rollouts of the true cell, one episode long.

    Args:
        realized: the episode's realized scenario (truth and random streams).
        nominal: the nominal cell (IK); true_cell: :func:`build_scan_cell`;
        clearance_cell: the nominal cell with the part's collision shape (``build_scan_cell(...,
        which="nominal")``: the planning checks).
        speed_m_s: scan speed along a line; retract_m: back-off along the beam between lines.
    """

    def __init__(self, realized: Realized, nominal: Cell, true_cell: Cell, clearance_cell: Cell, speed_m_s: float,
                 retract_m: float):
        self.realized = realized
        self.nominal = nominal
        self.cell = true_cell
        self.speed_m_s = speed_m_s
        self.retract_m = retract_m
        self.dt = float(true_cell.model.opt.timestep)
        self.solver = IKSolver(nominal.model, nominal.sensor.site, IK_POSITION_TOL_M, IK_ORIENTATION_TOL_RAD)
        self.rng_sensor = realized.streams.generator("sensor")
        self.rng_encoder = realized.streams.generator("encoder")
        self.contact_names, self.contact_cols = contact_columns(true_cell.model)
        self.T_base_world = inv_pose(true_cell.T_world_base)
        self.clearance = TableCheck(clearance_cell, TABLE_CLEARANCE_M, PART_CLEARANCE_M)
        self.joint_range = nominal.model.jnt_range[:6].copy()
        # the sensor site in the flange's DH frame, as the nominal model has it (closed-form seeds)
        data = mujoco.MjData(nominal.model)
        mujoco.mj_kinematics(nominal.model, data)
        T_world = {}
        for name in ("flange", nominal.sensor.site):
            T_world[name] = np.eye(4)
            T_world[name][:3, :3] = data.site(name).xmat.reshape(3, 3)
            T_world[name][:3, 3] = data.site(name).xpos
        self.T_sensor_flange = inv_pose(T_world[nominal.sensor.site]) @ T_world["flange"]
        self.q = HOME_Q.copy()
        self.t_s = 0.0
        self.state = simulate(true_cell, np.stack([self.q, self.q]), np.zeros((2, 6)))

    def sensor_pose(self, q: np.ndarray) -> np.ndarray:
        """(4, 4) the believed world pose of the sensor at joints ``q``."""
        self.solver.set_q(q)
        return self.solver.site_pose()

    def _solve_near(self, T_world_target: np.ndarray, q_from: np.ndarray) -> np.ndarray | None:
        self.solver.set_q(q_from)
        pe, oe, _ = self.solver.solve(T_world_target, 0.05, NEAR_POSE_ITERATIONS, velocity_limited=False)
        return self.solver.q if reachable(pe, oe) else None

    def _solve_far(self, T_world_target: np.ndarray, q_near: np.ndarray) -> np.ndarray | None:
        """A pose anywhere in reach: mink from each closed-form solution within the joint
        ranges, nearest ``q_near`` first; the first that converges with the links off the table."""
        T_base_flange = self.T_base_world @ T_world_target @ self.T_sensor_flange
        sol = ur_inverse(T_base_flange, UR5E_DH)
        seeds = sol.q[0][sol.valid[0]]
        lo, hi = self.joint_range[:, 0], self.joint_range[:, 1]
        seeds = seeds[np.all((seeds >= lo) & (seeds <= hi), axis=1)]
        for q in seeds[np.argsort(np.linalg.norm(seeds - q_near, axis=1))]:
            q_sol = self._solve_near(T_world_target, q)
            if q_sol is not None and self.clearance.nearest(q_sol) is None:
                return q_sol
        return None

    def plan(self, T_line_start: np.ndarray, T_line_end: np.ndarray) -> Motion | str:
        """The motion to scan the line between two sensor poses, or why it cannot be done."""
        T_now = self.sensor_pose(self.q)
        T_out = T_now.copy()
        T_out[:3, 3] -= self.retract_m * T_now[:3, 2]
        q_out = self._solve_near(T_out, self.q)
        if q_out is None:
            return "the sensor cannot back off from where it is"
        T_in = T_line_start.copy()
        T_in[:3, 3] -= self.retract_m * T_line_start[:3, 2]
        q_in = self._solve_far(T_in, q_out)
        if q_in is None:
            return "the approach pose is out of reach"
        q_start = self._solve_near(T_line_start, q_in)
        if q_start is None:
            return "the start of the line is out of reach"
        poses = straight_poses(T_line_start, T_line_end, self.speed_m_s, self.dt)
        knots = np.arange(0, len(poses), LINE_KNOT_STEPS)
        if knots[-1] != len(poses) - 1:
            knots = np.append(knots, len(poses) - 1)
        track = self.solver.track(poses[knots], q_start, dt=LINE_KNOT_STEPS * self.dt)
        if not track.reachable.all():
            return "the line leaves the arm's reach"
        t = np.arange(len(poses)) * self.dt
        spline = CubicSpline(t[knots], track.q, axis=0, bc_type="clamped")
        transit = self._transit(q_out, q_in)
        if transit is None:
            return "every transit to the view would take a link near the table or the part"
        approach = joint_move(q_in, q_start, self.dt)
        near = self._first_near([approach[0], spline(t)])
        if near is not None:
            return (f"the approach or the line would take {near[0]} within {1e3 * near[1]:.1f} mm of the table "
                    "or the part")
        legs = [joint_move(self.q, q_out, self.dt), *transit, approach]
        q_ref = np.vstack([leg[0][:-1] for leg in legs] + [spline(t)])
        qd_ref = np.vstack([leg[1][:-1] for leg in legs] + [spline(t, 1)])
        line_start = sum(len(leg[0]) - 1 for leg in legs)
        return Motion(q_ref, qd_ref, line_start, track.q[-1].copy(), T_line_start[:3, 2].copy())

    def _transit(self, q_a: np.ndarray, q_b: np.ndarray) -> list | None:
        """The joint moves from ``q_a`` to ``q_b``: direct, or by way of the home configuration
        when the direct move would take a link within the clearance of the table or the part;
        None when both would."""
        for via in ([q_a, q_b], [q_a, HOME_Q, q_b]):
            legs = [joint_move(a, b, self.dt) for a, b in zip(via[:-1], via[1:], strict=True)]
            if self._first_near([leg[0] for leg in legs]) is None:
                return legs
        return None

    def _first_near(self, paths: list[np.ndarray]) -> tuple[str, float] | None:
        """(link, distance [m]) at the first configuration of the joint paths, sampled every
        ``TRANSIT_CHECK_S``, where a link comes within its clearance of the table or the part
        (the nominal model); None when none does."""
        step = max(1, int(round(TRANSIT_CHECK_S / self.dt)))
        for path in paths:
            for q in path[::step]:
                near = self.clearance.nearest(q)
                if near is not None:
                    return near
        return None

    def execute(self, motion: Motion) -> SegmentResult:
        """Simulate a motion from the current state and measure its line."""
        n = motion.steps
        log = SampleLog(self.cell, n)
        k = len(self.contact_names)
        cdata = np.zeros((n, k, 5))

        def on_chunk(i0, sens, q_before):
            log.on_chunk(i0, sens, q_before)
            if k:
                cdata[i0:i0 + len(sens)] = sens[:, self.contact_cols].reshape(len(sens), k, 5)

        self.state = simulate(self.cell, motion.q_ref, motion.qd_ref, on_chunk, state=self.state)
        t = self.t_s + np.arange(n) * self.dt
        rows = slice(motion.line_start, n)
        meas, _, points = measure_samples(self.realized.scenario, self.cell, t[rows], log.q_enc[rows],
                                          log.rays(rows), self.rng_sensor, self.rng_encoder)
        contacts = contact_records(self.contact_names, cdata, t, self.T_base_world) if k else []
        self.q = motion.q_end
        self.t_s += n * self.dt
        P, d = points[meas.valid], meas.d[meas.valid]
        z_world = P @ self.cell.T_world_base[2, :3] + self.cell.T_world_base[2, 3]
        keep = z_world > TABLE_CROP_M
        return SegmentResult(P[keep], self.T_base_world[:3, :3] @ motion.beam_world, d[keep], n * self.dt, contacts)

    def joints(self) -> np.ndarray:
        """(6,) the true joint positions now [rad]."""
        return self.state[1 + self.cell.qpos_adr].copy()
