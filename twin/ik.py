"""Differential inverse kinematics with mink: the one wrapper the scan and the process paths use.

The solver runs on the NOMINAL cell (what the robot controller believes). One pose is solved
by repeated QP steps (``mink.solve_ik`` with a FrameTask on the target site, a small posture
task and configuration and velocity limits) from the current configuration; a sequence
warm-starts each pose from the last, which keeps the joint path continuous (no branch flips:
with the velocity limit no step moves a joint more than ``v_max * dt``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import overload

import mink
import mujoco
import numpy as np

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray
from twin.robot import JOINT_NAMES, VELOCITY_LIMIT_RAD_S

# A pose still this far off after the iteration cap is unreachable (or singular).
UNREACHABLE_POSITION_M = 1e-4
UNREACHABLE_ORIENTATION_RAD = 1e-3
STALL_FRACTION = 0.02
# Table avoidance of the process-path IK (mink.CollisionAvoidanceLimit): the links keep this
# far from the table, the limit acting within the detection distance.
TABLE_MIN_DISTANCE_M = 0.005
TABLE_DETECTION_DISTANCE_M = 0.05
# Free spin: the weight of the spin about the tool axis against 1 for the tilt of the axis.
SPIN_COST = 1e-2
# PostureTask cost: small enough that its pull on the tracked pose stays at the nanometre level.
POSTURE_COST = 1e-6


@dataclass(frozen=True)
class IKTrack:
    """Joint solution of a pose sequence.

    Attributes:
        q: (K, 6) joint angles [rad].
        position_error_m: (K,) remaining position error of the frame at each pose [m].
        orientation_error_rad: (K,) remaining orientation error [rad].
        reachable: (K,) bool, errors within the unreachable thresholds.
    """

    q: np.ndarray
    position_error_m: np.ndarray
    orientation_error_rad: np.ndarray
    reachable: np.ndarray


@overload
def reachable(position_error_m: float, orientation_error_rad: float) -> np.bool_: ...


@overload
def reachable(position_error_m: FloatArray, orientation_error_rad: FloatArray) -> BoolArray: ...


def reachable(position_error_m: ArrayLike, orientation_error_rad: ArrayLike) -> BoolArray | np.bool_:
    """Whether the remaining errors [m], [rad] are within the unreachable thresholds (element-wise;
    a numpy bool for scalar errors)."""
    return (np.asarray(position_error_m) < UNREACHABLE_POSITION_M) & \
        (np.asarray(orientation_error_rad) < UNREACHABLE_ORIENTATION_RAD)


class IKSolver:
    """mink differential IK on one site of a (nominal) model, kept warm between poses.

    Args:
        model: the nominal cell's model.
        site: the frame that follows the targets ("laser" for scans, "flange" for tool paths).
        position_tol_m, orientation_tol_rad: a pose is solved once both errors are below these.
    """

    def __init__(self, model: mujoco.MjModel, site: str, position_tol_m: float, orientation_tol_rad: float,
                 posture_cost: float = POSTURE_COST, velocity_limit_rad_s: np.ndarray = VELOCITY_LIMIT_RAD_S,
                 free_spin: bool = False, avoid_table: bool = False) -> None:
        self.model = model
        self.free_spin = free_spin
        self.position_tol_m = position_tol_m
        self.orientation_tol_rad = orientation_tol_rad
        self.configuration = mink.Configuration(model)
        # A free spin: a small cost on the rotation about the site's own z (mink's error is in
        # the local frame): the spin follows the target's loosely (the arm keeps its posture
        # instead of drifting about the tool axis) and gives way where the other joints need it.
        orientation_cost = [1.0, 1.0, SPIN_COST] if free_spin else 1.0
        self.frame_task = mink.FrameTask(site, "site", position_cost=1.0, orientation_cost=orientation_cost,
                                         lm_damping=1e-9)
        self._target: np.ndarray | None = None
        self.site_name = site
        self.posture_task = mink.PostureTask(model, cost=posture_cost)
        self.config_limit = mink.ConfigurationLimit(model)
        self.velocity_limit = mink.VelocityLimit(
            model, {name: float(v) for name, v in zip(JOINT_NAMES, velocity_limit_rad_s, strict=True)})
        self.tasks = [self.frame_task, self.posture_task]
        self.extra_limits: list[mink.Limit] = []
        if avoid_table:
            # The links (not the base and shoulder turret, which stand on it) keep off the table.
            standing = ("base", "shoulder_pan_link")
            arm = [model.geom(g).name for g in range(model.ngeom)
                   if model.geom_contype[g] and model.body(model.geom_bodyid[g]).name not in standing]
            self.extra_limits.append(mink.CollisionAvoidanceLimit(
                model, [(arm, ["table"])], minimum_distance_from_collisions=TABLE_MIN_DISTANCE_M,
                collision_detection_distance=TABLE_DETECTION_DISTANCE_M))
        self.site_id = model.site(site).id
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))

    @property
    def q(self) -> np.ndarray:
        return self.configuration.q[:6].copy()

    def set_q(self, q: np.ndarray) -> None:
        self.configuration.update(np.asarray(q, dtype=np.float64))

    def predict(self, q: np.ndarray) -> None:
        """Warm start at ``q``, kept inside the joint ranges (the limits' QP needs a feasible start)."""
        lo = self.model.jnt_range[:6, 0] + 1e-6
        hi = self.model.jnt_range[:6, 1] - 1e-6
        self.configuration.update(np.clip(q, lo, hi))

    def set_spin_free(self, free: bool) -> None:
        """Free (a small cost) or hold the rotation about the site's z from the next solve on."""
        self.free_spin = free
        self.frame_task.set_orientation_cost([1.0, 1.0, SPIN_COST] if free else 1.0)

    def site_pose(self) -> np.ndarray:
        """(4, 4) world pose of the site at the current configuration."""
        return self.configuration.get_transform_frame_to_world(self.site_name, "site").as_matrix()

    def errors(self) -> tuple[float, float]:
        """(position [m], orientation [rad]) error of the site from its target (with a free
        spin: the angle between the site's z and the target's z)."""
        e = self.frame_task.compute_error(self.configuration)
        if self.free_spin:
            if self._target is None:
                raise RuntimeError("IKSolver.errors with a free spin needs a target: call solve first")
            z = self.site_pose()[:3, 2]
            tilt = float(np.arctan2(np.linalg.norm(np.cross(z, self._target[:3, 2])), z @ self._target[:3, 2]))
            return float(np.sqrt(e[0] ** 2 + e[1] ** 2 + e[2] ** 2)), tilt
        return float(np.sqrt(e[0] ** 2 + e[1] ** 2 + e[2] ** 2)), float(np.sqrt(e[3] ** 2 + e[4] ** 2 + e[5] ** 2))

    def solve(self, T_world_target: np.ndarray, dt: float, max_iterations: int,
              velocity_limited: bool = True, stop_when_stalled: bool = False) -> tuple[float, float, int]:
        """Iterate from the current configuration towards one target pose.

        With ``velocity_limited``, each iteration moves at most ``v_max * dt`` per joint.
        With ``stop_when_stalled``, a pose still farther than the unreachable threshold whose
        position error shrank by less than STALL_FRACTION in an iteration is given up early
        (it will be reported unreachable either way; a path with long unreachable stretches
        would otherwise spend the full iteration cap on every pose).
        Returns (position error [m], orientation error [rad], iterations).
        """
        self._target = np.asarray(T_world_target, dtype=np.float64)
        self.frame_task.set_target(mink.SE3.from_matrix(self._target))
        self.posture_task.set_target(self.configuration.q)
        limits: list[mink.Limit] = [self.config_limit, self.velocity_limit] if velocity_limited \
            else [self.config_limit]
        limits = limits + self.extra_limits
        pe, oe = self.errors()
        it = 0
        while it < max_iterations and (pe >= self.position_tol_m or oe >= self.orientation_tol_rad):
            try:
                v = mink.solve_ik(self.configuration, self.tasks, dt, solver="daqp", damping=1e-12, limits=limits)
            except mink.exceptions.NoSolutionFound:
                # No step satisfies the limits from here (a joint pressed against its range):
                # the pose stays where it is and is reported if it is off.
                break
            self.configuration.integrate_inplace(v, dt)
            pe_before = pe
            pe, oe = self.errors()
            it += 1
            if stop_when_stalled and it >= 3 and pe > UNREACHABLE_POSITION_M and pe > (1 - STALL_FRACTION) * pe_before:
                break
        return pe, oe, it

    def sigma_min(self, length_m: float) -> float:
        """Smallest singular value of the site Jacobian, rotation rows scaled by ``length_m`` [m/rad]
        (with a free spin: only the rotations that tilt the site's z count)."""
        mujoco.mj_jacSite(self.model, self.configuration.data, self._jacp, self._jacr, self.site_id)
        jacr = self._jacr
        if self.free_spin:
            R = self.configuration.data.site_xmat[self.site_id].reshape(3, 3)
            jacr = R[:, :2].T @ jacr
        J = np.vstack([self._jacp, length_m * jacr])
        return float(np.linalg.svd(J, compute_uv=False)[-1])

    def track(self, T_world_targets: np.ndarray, q_start: np.ndarray, dt: float,
              iterations_per_pose: int = 4) -> IKTrack:
        """Follow a pose sequence spaced ``dt`` apart, warm-starting each pose from the last."""
        k = len(T_world_targets)
        q = np.empty((k, 6))
        pe = np.empty(k)
        oe = np.empty(k)
        self.set_q(q_start)
        for i in range(k):
            pe[i], oe[i], _ = self.solve(T_world_targets[i], dt, iterations_per_pose)
            q[i] = self.q
        return IKTrack(q, pe, oe, reachable(pe, oe))
