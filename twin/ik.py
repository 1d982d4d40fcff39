"""Differential inverse kinematics with mink: the sensor (or tool) frame follows a pose sequence.

The solver runs on the NOMINAL cell (what the robot controller believes). One pose is solved
by repeated QP steps (``mink.solve_ik`` with a FrameTask on the target site, a small posture
task and configuration and velocity limits); a sequence warm-starts each pose from the last,
which keeps the joint path continuous (no branch flips).
"""

from __future__ import annotations

from dataclasses import dataclass

import mink
import mujoco
import numpy as np

from twin.robot import JOINT_NAMES, VELOCITY_LIMIT_RAD_S

POSITION_TOL_M = 1e-7
ORIENTATION_TOL_RAD = 1e-6
# A pose still this far off after the iteration cap is unreachable (or singular).
UNREACHABLE_POSITION_M = 1e-4
UNREACHABLE_ORIENTATION_RAD = 1e-3
# PostureTask cost 1e-6 leaves a nanometre-level bias (1e-3 gave 6 um, measured with mink 1.3).
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


class IKSolver:
    """mink differential IK on one site of a (nominal) model."""

    def __init__(self, model: mujoco.MjModel, site: str = "laser", posture_cost: float = POSTURE_COST,
                 velocity_limit_rad_s: np.ndarray = VELOCITY_LIMIT_RAD_S):
        self.model = model
        self.site = site
        self.configuration = mink.Configuration(model)
        self.frame_task = mink.FrameTask(site, "site", position_cost=1.0, orientation_cost=1.0,
                                         lm_damping=1e-9)
        self.posture_task = mink.PostureTask(model, cost=posture_cost)
        self.config_limit = mink.ConfigurationLimit(model)
        self.velocity_limit = mink.VelocityLimit(
            model, {name: float(v) for name, v in zip(JOINT_NAMES, velocity_limit_rad_s)})
        self.tasks = [self.frame_task, self.posture_task]

    def _errors(self) -> tuple[float, float]:
        err = self.frame_task.compute_error(self.configuration)
        return float(np.linalg.norm(err[:3])), float(np.linalg.norm(err[3:]))

    def solve(self, T_world_target: np.ndarray, q0: np.ndarray, dt: float, max_iterations: int,
              velocity_limited: bool = True) -> tuple[np.ndarray, float, float]:
        """Iterate towards one target pose from ``q0``; returns (q, position_error, orientation_error).

        With ``velocity_limited``, each iteration moves at most ``v_max * dt`` per joint.
        """
        self.configuration.update(q0)
        self.frame_task.set_target(mink.SE3.from_matrix(T_world_target))
        self.posture_task.set_target(np.asarray(q0, dtype=np.float64))
        limits = [self.config_limit, self.velocity_limit] if velocity_limited else [self.config_limit]
        pos_err, rot_err = self._errors()
        for _ in range(max_iterations):
            if pos_err < POSITION_TOL_M and rot_err < ORIENTATION_TOL_RAD:
                break
            v = mink.solve_ik(self.configuration, self.tasks, dt, solver="daqp", damping=1e-12,
                              limits=limits)
            self.configuration.integrate_inplace(v, dt)
            pos_err, rot_err = self._errors()
        return self.configuration.q.copy(), pos_err, rot_err

    def track(self, T_world_targets: np.ndarray, q_start: np.ndarray, dt: float,
              iterations_per_pose: int = 4) -> IKTrack:
        """Follow a pose sequence spaced ``dt`` apart, warm-starting each pose from the last."""
        k = len(T_world_targets)
        q = np.empty((k, len(q_start)))
        pe = np.empty(k)
        oe = np.empty(k)
        qc = np.asarray(q_start, dtype=np.float64)
        for i in range(k):
            qc, pe[i], oe[i] = self.solve(T_world_targets[i], qc, dt, iterations_per_pose)
            q[i] = qc
        reachable = (pe < UNREACHABLE_POSITION_M) & (oe < UNREACHABLE_ORIENTATION_RAD)
        return IKTrack(q, pe, oe, reachable)
