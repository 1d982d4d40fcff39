"""The typed state of the local iteration (:mod:`algorithms.registration.local`): what is fixed
in one run (:class:`IterationSetup`), where it stands (:class:`IterationState`), the trial a
method proposes (:class:`Candidate`, :class:`Trial`, :class:`Settled`) and what the run ends
with (:class:`LocalFit`). Poses are T_world_workpiece; points, feet and distances are in the
workpiece frame [m] unless said otherwise."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from algorithms.arraytypes import FloatArray, Pose
from algorithms.geometry.mesh_index import ClosestPoints, MeshIndex
from algorithms.registration.feet import Feet
from algorithms.registration.robust import Mask, OutlierStages

__all__ = ["Candidate", "IterationSetup", "IterationState", "LocalFit", "Settled", "Trial"]


@dataclass(frozen=True)
class LocalFit:
    """The end of an iteration of Algorithm 1 (before its uncertainty and verdict).

    Attributes:
        T: (4, 4) the pose reached, T_world_workpiece.
        cp: the closest points (exact) of the points at ``T``.
        mask: the inliers (:mod:`algorithms.registration.robust`) at ``T``.
        history: RMS distance [m] of the inliers at the start and after each update.
        poses: the pose at the start and after each update.
        iterations: the number of pose updates.
        converged: whether a stopping rule was met.
        status: how the iteration ended, in words.
    """

    T: Pose
    cp: ClosestPoints
    mask: Mask
    history: tuple[float, ...]
    poses: tuple[Pose, ...]
    iterations: int
    converged: bool
    status: str

    def sum_sq(self) -> tuple[float, int]:
        """(sum of squared distances [m^2], points used) of the inliers."""
        d = self.cp.distance[self.mask]
        return float(d @ d), len(d)


@dataclass(frozen=True)
class IterationSetup:
    """The fixed parts of one iteration: the method, the points ``Y`` (N, 3) [m] (world frame),
    the model, the points' feet, the outlier stages, the floor of the mean squared distance
    [m^2], the tolerance of the stopping rule and the iteration cap."""

    method: str
    Y: FloatArray
    index: MeshIndex
    feet: Feet
    stages: OutlierStages
    floor2: float
    tol: float
    max_it: int

    def mse(self, cp: ClosestPoints, mask: Mask) -> float:
        """Mean squared distance [m^2] of the inliers ``mask``."""
        d = cp.distance[mask]
        return float((d * d).sum() / len(d))  # no BLAS: its threads contend with numba's


@dataclass
class IterationState:
    """Where the iteration stands: the pose ``T``, the feet ``cp`` of the workpiece-frame points
    ``Ym`` [m], the inliers and their mean squared distance ``e_prev`` [m^2]; the RMS history
    and poses so far; the counts of updates and of fallback and edge steps; menq's damping
    ``lm_lambda``; and the verdict so far (``not_converged`` the status while none is met)."""

    T: Pose
    cp: ClosestPoints
    Ym: FloatArray
    mask: Mask
    e_prev: float
    lm_lambda: float
    not_converged: str
    history: list[float] = field(default_factory=list)
    poses: list[Pose] = field(default_factory=list)
    n_updates: int = 0
    n_fallback: int = 0
    n_edge: int = 0
    converged: bool = False
    status: str = ""

    def __post_init__(self) -> None:
        self.history.append(float(np.sqrt(self.e_prev)))
        self.poses.append(self.T)
        self.status = self.not_converged

    def stop(self, converged: bool, status: str) -> bool:
        """End the iteration here (returns True: done)."""
        self.converged, self.status = converged, status
        return True

    def reopen(self, e_prev: float) -> None:
        """Go on from the current pose with a new mean squared distance (new feet or inliers)."""
        self.e_prev = e_prev
        self.converged, self.status = False, self.not_converged

    def fit(self) -> LocalFit:
        """The typed result, the counts of edge and fallback steps appended to the status."""
        status = self.status
        if self.n_edge:
            status += f" ({self.n_edge} step(s) along the offsets of feet on edges)"
        if self.n_fallback:
            status += f" ({self.n_fallback} point-to-point fallback step(s))"
        return LocalFit(T=self.T, cp=self.cp, mask=self.mask, history=tuple(self.history), poses=tuple(self.poses),
                        iterations=self.n_updates, converged=self.converged, status=status)


@dataclass(frozen=True)
class Candidate:
    """A trial pose ``T`` with the feet ``cp`` of the workpiece-frame points ``Ym`` [m] and the
    mean squared distance ``e`` [m^2] of the current inliers."""

    T: Pose
    cp: ClosestPoints
    Ym: FloatArray
    e: float


@dataclass(frozen=True)
class Trial:
    """The next pose a method proposes (``at``, after its safeguards), its step measure (the
    decrease hong_tan predicts [m^2], fine_001's ``sum dtheta^2 + sum dDelta^2``; inf after an
    ICP fallback; None for the others) and whether the method's own update raised the residual
    (``overshoot``)."""

    at: Candidate
    step: float | None = None
    overshoot: bool = False


@dataclass(frozen=True)
class Settled:
    """Stop here, converged, keeping the current pose (``message`` says why)."""

    message: str
