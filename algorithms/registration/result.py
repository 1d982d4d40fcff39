"""One result family for every registration method, in the spirit of small_gicp's
``RegistrationResult``: the pose, how the iteration ended, a verdict to branch on, and what
the points determine of the pose.

Every method returns a :class:`RegistrationResult` or a subclass adding typed fields of its
own: :func:`algorithms.registration.local.localize` the base class itself,
:func:`algorithms.registration.global_search.global_localize` a ``GlobalLocalizationResult``
(candidates, diagnostics), :func:`algorithms.registration.symmetric.localize_symmetric` a
``SymmetricResult`` (feature, symmetry group, ...) and
:func:`algorithms.registration.hybrid.localize_hybrid` a ``HybridResult`` (feasibility,
allowances, ...).

Directions. The pose error is the twist ``xi = [omega, v]`` (angular part first; rad and m)
of ``T_est = T_true exp(xi)`` in the workpiece frame (see
:mod:`algorithms.registration.uncertainty`). The points split the six directions of ``xi``
into ``determined_directions`` (q rows), the ones they fix, and ``free_directions`` (k rows),
the ones they leave free or fix only weakly (a plane, a cylinder, a symmetric feature);
``q + k = 6`` (3 for Algorithm 2 on the planar 2D features, whose ambient group is SE(2)).
``covariance`` is the (q, q) covariance of the coordinates ``m`` of the error along the
determined directions, ``xi = B^T m`` with ``B = determined_directions``;
:attr:`RegistrationResult.covariance_twist` gives the same as a (6, 6) twist covariance
``B^T C B`` of rank q (the full twist covariance when observable).

Verdict. ``status`` is a :class:`Status`; ``message`` says the same in a sentence, with the
numbers. Only :attr:`Status.OK` (``trusted``) means one pose, determined in every direction,
whose residual the noise explains (as far as the method can tell).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from algorithms.arraytypes import BoolArray, FloatArray, Pose

__all__ = ["Status", "RegistrationResult", "fit_status"]


class Status(enum.Enum):
    """The verdict of a registration (its value is the string written to reports)."""

    #: one pose, determined in every direction, its residual consistent with the noise
    OK = "ok"
    #: the iteration did not meet its stopping rule (iteration cap, stalled)
    NOT_CONVERGED = "not_converged"
    #: converged, but the residual is far above the given noise (a local minimum or the
    #: wrong model)
    POOR_FIT = "poor_fit"
    #: the points leave some directions free (``free_directions``)
    UNOBSERVABLE = "unobservable"
    #: several distinct poses fit equally well (``solutions``)
    AMBIGUOUS = "ambiguous"
    #: the search found no pose that the noise explains, or one that is beaten by another
    FAILED = "failed"
    #: no pose meets the constraints (hybrid localization: the machining allowances)
    INFEASIBLE = "infeasible"


@dataclass(frozen=True, kw_only=True, eq=False)
class RegistrationResult:
    """The pose of the workpiece from measured points, and how far to trust it.

    Attributes:
        T_world_workpiece: (4, 4) maps workpiece (CAD) coordinates into the frame of the
            points ("world": the robot base in the twin's loop, the machine frame on a CMM).
        method: the method that produced it (``"hong_tan"``, ``"multistart"``, ...).
        converged: the iteration met its stopping rule (not whether the pose is determined:
            see ``status``).
        status: the verdict other code branches on (:class:`Status`).
        message: the verdict in words, with the numbers behind it.
        rmse_m: RMS point-to-model distance of the inliers at the result [m].
        iterations: pose updates made.
        history: RMS distance [m] at the start and after every iteration.
        pose_history: the (4, 4) pose at the start and after every iteration, one per entry
            of ``history`` (empty where a method does not record its iterations).
        inliers: (N,) bool over the input rows: finite and not an outlier.
        n_points_used: inliers at the result.
        n_outliers: finite points rejected as outliers at the result.
        n_dropped_nonfinite: input rows dropped for NaN or infinite coordinates.
        sigma_m: noise sigma along the normals [m] used for the covariance (given, or
            estimated from the residuals).
        determined_directions: (q, 6) unit twists ``[omega, v]`` (workpiece frame, about its
            origin) spanning the directions the points fix.
        covariance: (q, q) covariance of the pose error along ``determined_directions``
            (rad^2, rad m, m^2): the Cramer-Rao expression at the estimate with ``sigma_m``;
            None only when it cannot be computed.
        free_directions: (k, 6) unit twists ``[omega, v]`` (workpiece frame) spanning the
            directions the points leave free or fix only weakly; (0, 6) when observable.
        solutions: every equally good pose, (4, 4) each; ``solutions[0]`` is
            ``T_world_workpiece``.
        relative_eigenvalues: scaled information eigenvalues / the largest, ascending.
        time_s: wall time of the call [s].
        poor_fit_reason: why the noise cannot explain the fit
            (:func:`algorithms.registration.fit_check.poor_fit_reason`), or None.
        rejection_review: what the review of the points the outlier rule rejected found
            (:mod:`algorithms.registration.review`: ``confirmed``, ``wrong minimum``,
            ``ambiguous`` or ``unconfirmed``, with the numbers), or None when none was needed.
    """

    T_world_workpiece: Pose
    method: str
    converged: bool
    status: Status
    message: str
    rmse_m: float
    iterations: int
    history: tuple[float, ...]
    inliers: BoolArray = field(repr=False)
    n_points_used: int
    n_outliers: int
    n_dropped_nonfinite: int
    sigma_m: float
    determined_directions: FloatArray
    covariance: FloatArray | None
    free_directions: FloatArray
    solutions: tuple[Pose, ...] = field(repr=False)
    relative_eigenvalues: FloatArray
    time_s: float
    poor_fit_reason: str | None = None
    pose_history: tuple[Pose, ...] = field(default=(), repr=False)
    rejection_review: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.status, Status):
            raise TypeError(f"status must be a Status, got {self.status!r}")
        q = np.shape(self.determined_directions)
        k = np.shape(self.free_directions)
        if len(q) != 2 or len(k) != 2 or q[1] != 6 or k[1] != 6:
            raise ValueError(f"direction arrays must be (q, 6) and (k, 6), got {q} and {k}")
        if self.covariance is not None and np.shape(self.covariance) != (q[0], q[0]):
            raise ValueError(f"covariance must be ({q[0]}, {q[0]}), got {np.shape(self.covariance)}")
        if not self.solutions:
            raise ValueError("solutions must hold at least the result's pose")

    @property
    def observable(self) -> bool:
        """True when the points fix every direction (no free direction)."""
        return len(self.free_directions) == 0

    @property
    def free_dofs(self) -> int:
        """k: the number of free (or weakly fixed) directions."""
        return int(len(self.free_directions))

    @property
    def trusted(self) -> bool:
        """True only for :attr:`Status.OK`."""
        return self.status is Status.OK

    @property
    def covariance_twist(self) -> FloatArray | None:
        """(6, 6) covariance of the error twist ``[omega, v]``: ``B^T C B`` with ``B`` the
        determined directions (rank q; the full covariance when observable), or None."""
        if self.covariance is None:
            return None
        B = np.asarray(self.determined_directions, dtype=np.float64)
        if len(B) == 6 and np.array_equal(B, np.eye(6)):
            return np.array(self.covariance, dtype=np.float64)
        C = B.T @ self.covariance @ B
        return 0.5 * (C + C.T)


def fit_status(converged: bool, free_dofs: int, poor_fit_reason: str | None) -> Status:
    """The verdict of a fit from a given start: NOT_CONVERGED if not converged (its residual is
    no verdict on the model yet); else POOR_FIT if the fit check
    (:func:`algorithms.registration.fit_check.poor_fit_reason`) gave a reason (a model that
    does not explain the points makes its free directions moot); else UNOBSERVABLE if a
    direction is free; else OK."""
    if not converged:
        return Status.NOT_CONVERGED
    if poor_fit_reason is not None:
        return Status.POOR_FIT
    if free_dofs:
        return Status.UNOBSERVABLE
    return Status.OK
