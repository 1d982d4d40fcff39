"""CAD-model-based workpiece localization from a given start: Algorithm 1 of document 000 with
each pose update it names, and document 001's fine stage.

Frames and units: ``points`` (N, 3) [m] in the world (robot base / machine) frame, the model
``mesh`` in the workpiece (CAD) frame [m]; the result ``T_world_workpiece`` maps workpiece
coordinates to world ones (``points ~= transform_points(T_world_workpiece, model_points)``;
document 000's ``g = (p, R)``, ``y = R x + p``; document 001's ``T`` is its inverse).

Algorithm 1: closest points ("feet") on the model of the points mapped into the workpiece frame,
a pose update from the pairs, new feet, until a stopping rule. The updates (``METHODS``):

* ``"hong_tan"`` (default): point-to-plane least squares about the points' centroid, applied
  through the exponential map (Gauss-Newton on SE(3); reaches the Cramer-Rao bound).
* ``"tangent"``: point-to-plane least squares about the workpiece origin, first-order retraction.
* ``"menq"``: Levenberg-Marquardt on SE(3) of the true point-to-surface distances.
* ``"va"``: point-to-point Gauss-Newton step on SE(3) (Li's variational algorithm).
* ``"icp"``: closed-form point-to-point step (Besl-McKay).
* ``"fine_001"``: document 001's linearised point-to-point step about the points' centroid.

Stopping rules (all but the last: ``converged``):

* relative decrease ``1 - e_k / e_(k-1) < delta`` (``tolerance``), ``e`` the mean squared distance;
* fine_001: its step ``sum dtheta^2 + sum dDelta^2 < d`` (``tolerance``) instead;
* the RMS residual below ``FLOOR_REL`` times the model's size (an exact fit);
* hong_tan: the next update would move the pose by less than ``STOP_SIGMAS`` standard deviations;
* an overshooting update whose fallback moves it by less than ``FALLBACK_MIN_SIGMAS`` of them;
* no step lowers the residual (converged if it stays within 1e-6 of it);
* ``max_iterations`` pose updates (not converged).

An update that raises the residual is halved (up to 8 times), else replaced by one ICP step
(Hong-Tan first tries the rows of feet on edges along their offsets). A converged fit the given
noise cannot explain is restarted along its weakest directions (:mod:`.escape`) and judged by
:mod:`.fit_check`; an unknown pose goes through ``global_search.global_localize`` instead.
Input checks are those of :mod:`.inputs`, outlier rules those of :mod:`.robust`.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray, IntArray, Pose
from algorithms.errors import AlgorithmError
from algorithms.geometry.bvh_kernels import kernels_cached
from algorithms.geometry.mesh_index import ClosestPoints, MeshIndex, NearFaces
from algorithms.geometry.parametric import ParametricModel
from algorithms.geometry.query_pool import PARALLEL_MIN_POINTS
from algorithms.geometry.se3 import as_pose, exp_se3, inv_pose, log_se3
from algorithms.registration.escape import escape_wrong_minimum
from algorithms.registration.feet import Feet
from algorithms.registration.fit_check import poor_fit_reason, white_noise_sigma_m
from algorithms.registration.fit_uncertainty import fit_uncertainty
from algorithms.registration.inputs import (
    MIN_POINTS,
    UNITS_MAX_RATIO,
    UNITS_MIN_RATIO,
    check_sigma,
    check_units,
    finite_rows,
    mesh_index,
)
from algorithms.registration.iteration_state import (
    Candidate,
    IterationSetup,
    IterationState,
    LocalFit,
    Settled,
    Trial,
)
from algorithms.registration.kernels import plane_system as _nb_plane_system
from algorithms.registration.kernels import run as _nb_run
from algorithms.registration.kernels import solve as _nb_solve
from algorithms.registration.pose_updates import (
    centered,
    edge_feet,
    normal_equations,
    plane_rows,
    solve_sym6,
    update_fine_001,
    update_icp,
    update_tangent,
    update_va,
)
from algorithms.registration.printed import VARIANTS, iterate_printed
from algorithms.registration.result import RegistrationResult, fit_status
from algorithms.registration.robust import (
    ALL,
    OUTLIER_COARSE_FLOOR_REL,
    OUTLIER_FLOOR_REL,
    OUTLIER_K,
    Mask,
    OutlierConfig,
    OutlierStages,
    count,
    outlier_config,
)
from algorithms.registration.stopping import (
    FALLBACK_MIN_SIGMAS,
    RISE_REL,
    conclude,
    exact_feet,
    floor_message,
    go_on,
)
from algorithms.registration.uncertainty import OBSERVABILITY_TOL, Observability

if TYPE_CHECKING:
    import trimesh

__all__ = [
    "METHODS",
    "DEFAULT_METHOD",
    "localize",
    "localize_checked",
    "OUTLIER_K",
    "UNITS_MAX_RATIO",
    "UNITS_MIN_RATIO",
]

METHODS = ("hong_tan", "tangent", "menq", "va", "icp", "fine_001")
DEFAULT_METHOD = "hong_tan"
#: Iteration caps per method (point-to-point methods converge linearly).
MAX_ITERATIONS = {"hong_tan": 100, "tangent": 100, "menq": 100, "va": 3000, "icp": 3000, "fine_001": 3000}
#: delta of ``1 - e_k/e_(k-1) < delta``; for fine_001 the ``d`` [rad^2 + m^2] of its step criterion.
TOLERANCE = {"hong_tan": 1e-9, "tangent": 1e-9, "menq": 1e-9, "va": 1e-12, "icp": 1e-12, "fine_001": 1e-22}
#: RMS residual below ``FLOOR_REL * model size`` counts as an exact fit.
FLOOR_REL = 1e-12
#: Feet to within FAR_REL_ERROR of the distance while the RMS distance exceeds FAR_RMS_REL median
#: edge lengths: a far point needs no exact foot to point the way, and an exact search visits many leaves.
FAR_RMS_REL = 2.0
FAR_REL_ERROR = 0.3
#: Hong-Tan stops before an update that would move the pose by less than this many standard
#: deviations: the relative-decrease rule would spend more closest-point queries on nothing.
STOP_SIGMAS = 0.01
#: From this many points on, the early updates use a regular subset of SUBSET_POINTS points.
SUBSET_MIN_POINTS = 500
SUBSET_POINTS = 160
#: Initial (and smallest) Levenberg-Marquardt damping of "menq", relative to diag(J^T J); its
#: largest; and the damping from which an ICP step is tried as well (the steps are tiny then).
LM_LAMBDA0 = 1e-8
LM_LAMBDA_MAX = 1e8
LM_ICP_LAMBDA = 1e-3
#: An overshooting update is halved at most this many times.
HALVINGS = 8


def localize(
    points: ArrayLike,
    mesh: trimesh.Trimesh | None = None,
    method: str = DEFAULT_METHOD,
    init: ArrayLike | None = None,
    sigma: float | None = None,
    max_iterations: int | None = None,
    tolerance: float | None = None,
    outlier: OutlierConfig = "mad",
    index: MeshIndex | None = None,
    variant: str = "ours",
) -> RegistrationResult:
    """Find ``T_world_workpiece`` from measured points, the workpiece's CAD mesh and a start.

    Args:
        points: (N, 3) [m] measured points, world (robot base) frame; NaN/inf rows dropped.
        mesh: the model, a ``trimesh.Trimesh`` in the workpiece frame [m]. May be None when
            ``index`` is given.
        method: one of ``METHODS`` (see the module docstring); default ``"hong_tan"``.
        init: initial ``T_world_workpiece``: None (identity) or a rigid (4, 4) matrix. An
            unknown pose is found by
            :func:`algorithms.registration.global_search.global_localize`, not here.
        sigma: noise sigma along the normals [m] for the covariance and the poor-fit
            verdict; estimated from the residuals when None (then no poor-fit verdict).
        max_iterations: cap on pose updates (default per method, ``MAX_ITERATIONS``).
        tolerance: ``delta`` of the stopping rule (``d`` for fine_001), default ``TOLERANCE``
            (hong_tan also stops before an update of less than ``STOP_SIGMAS`` standard
            deviations, whatever ``delta``).
        outlier: ``"mad"`` (default), a maximum distance [m], or None (keep all); see
            :mod:`algorithms.registration.robust`.
        index: a prebuilt :class:`MeshIndex` of ``mesh`` to reuse across calls.
        variant: ``"ours"`` (the iteration above) or ``"printed"``: document 000's Algorithm 1
            as printed (:mod:`.printed`: every point, the update as it is, the relative-decrease
            test alone; ``outlier`` must then be left at its default or None).

    Returns:
        RegistrationResult (``method`` the update used; ``solutions`` the one pose). Its
        ``status``: NOT_CONVERGED if no stopping rule was met; else POOR_FIT if the fit check
        finds a reason; else UNOBSERVABLE if the points leave ``free_directions`` (the
        covariance then covers the determined directions only); else OK.

    Raises:
        AlgorithmError: bad points (shape, fewer than 6 finite), an empty mesh, units that
            look wrong, a non-rigid ``init`` or ``init="global"``, an unknown method or option.
    """
    t_start = time.perf_counter()
    if method not in METHODS:
        raise AlgorithmError(f"method must be one of {', '.join(METHODS)}; got {method!r}")
    P, rows = finite_rows(points)
    index = mesh_index(mesh, index)
    if max_iterations is None:
        max_iterations = MAX_ITERATIONS[method]
    if int(max_iterations) < 1:
        raise AlgorithmError(f"max_iterations must be >= 1, got {max_iterations}")
    if tolerance is None:
        tolerance = TOLERANCE[method]
    if not (np.isfinite(tolerance) and tolerance >= 0):
        raise AlgorithmError(f"tolerance must be a finite number >= 0, got {tolerance}")
    sigma = check_sigma(sigma)
    if variant not in VARIANTS:
        raise AlgorithmError(f"variant must be one of {', '.join(VARIANTS)}; got {variant!r}")
    if variant == "printed" and outlier not in ("mad", None):
        raise AlgorithmError(f"variant='printed' uses every point (document 000 has no outlier rule); got outlier="
                             f"{outlier!r}: leave it out or pass None")
    if isinstance(index, ParametricModel) and variant != "printed":
        raise AlgorithmError("Newton foot points on exact surfaces (a ParametricModel) run document 000's "
                             "Algorithm 1 as printed: pass variant='printed'")
    cfg = None if variant == "printed" else outlier_config(outlier)
    Y = P[rows]
    check_units(Y, index)
    if isinstance(init, str):
        if init == "global":
            raise AlgorithmError(
                "init='global' is not a pose: for an unknown pose call "
                "algorithms.registration.global_search.global_localize(points, mesh, noise_sigma_m=...) "
                "and pass its T_world_workpiece as init"
            )
        raise AlgorithmError(f"init must be None or a 4x4 rigid transform, got {init!r}")
    T0 = np.eye(4) if init is None else as_pose(init, name="init")
    return localize_checked(Y, index, method, T0, sigma=sigma, outlier_cfg=cfg,
                            max_iterations=int(max_iterations), tolerance=float(tolerance),
                            rows=rows, n_input=len(P), t_start=t_start, variant=variant)


def localize_checked(
    Y: FloatArray,
    index: MeshIndex,
    method: str,
    T0: Pose,
    *,
    sigma: float | None,
    outlier_cfg: OutlierConfig,
    max_iterations: int | None = None,
    tolerance: float | None = None,
    rows: IntArray | None = None,
    n_input: int | None = None,
    t_start: float | None = None,
    variant: str = "ours",
) -> RegistrationResult:
    """:func:`localize` on inputs already checked (for callers that checked them once).

    Args:
        Y: (M, 3) [m] finite points, world frame.
        index: the model's :class:`MeshIndex`.
        method: one of ``METHODS``.
        T0: (4, 4) rigid initial pose, T_world_workpiece.
        sigma: a positive noise sigma [m] or None.
        outlier_cfg: the checked outlier option (:func:`algorithms.registration.robust.outlier_config`).
        max_iterations, tolerance: as for :func:`localize` (None: the method's defaults).
        rows: (M,) the input rows ``Y`` came from (``inliers`` is over the input rows);
            default ``arange(M)``.
        n_input: the number of input rows (default M); ``n_dropped_nonfinite = n_input - M``.
        t_start: ``time.perf_counter()`` at the call, for ``time_s``.
        variant: ``"ours"`` or ``"printed"`` (:mod:`.printed`; ``outlier_cfg`` None).
    """
    if t_start is None:
        t_start = time.perf_counter()
    if rows is None:
        rows = np.arange(len(Y))
    if n_input is None:
        n_input = len(Y)
    max_it = MAX_ITERATIONS[method] if max_iterations is None else int(max_iterations)
    tol = TOLERANCE[method] if tolerance is None else float(tolerance)
    if len(Y) >= SUBSET_MIN_POINTS:
        # spatially coherent order: neighbouring points query neighbouring triangles (faster),
        # and every k-th point is a subset spread over the scan (see _iterate_staged)
        order = _morton_order(Y)
        Y = Y[order]
        rows = rows[order]

    def restart(T_start: Pose) -> LocalFit:
        return _iterate_staged(method, Y, index, T_start, max_it, tol, outlier_cfg)

    if variant == "printed":
        fit = iterate_printed(method, lambda T, Ym, cp: printed_update(method, T, Ym, cp), Y, index, T0, max_it, tol,
                              (FLOOR_REL * index.extent) ** 2)
    else:
        fit = restart(T0)
        if sigma is not None:
            fit = escape_wrong_minimum(fit, restart, float(sigma))
    n_used = count(fit.mask, len(Y))
    if n_used < MIN_POINTS:
        raise AlgorithmError(
            f"only {n_used} points lie within the outlier distance of the model; "
            f"at least {MIN_POINTS} are needed"
        )
    unc = fit_uncertainty(fit, Y, index, sigma)
    rmse = float(np.sqrt(np.mean(fit.cp.distance[fit.mask] ** 2)))
    # converged, but to residuals the noise cannot explain: a local minimum (global_localize
    # is the remedy) or a model that does not match the part
    poor = poor_fit_reason(rmse, n_used, len(Y), index.extent, sigma,
                           white_noise_sigma_m(unc.Ym_in, unc.s) if sigma is None else math.nan)
    inliers = np.zeros(n_input, dtype=bool)
    inliers[rows[fit.mask]] = True
    return RegistrationResult(
        T_world_workpiece=fit.T,
        method=method,
        converged=fit.converged,
        status=fit_status(fit.converged, len(unc.free), poor),
        message=_message(fit, unc.obs, len(unc.free), poor),
        rmse_m=rmse,
        iterations=fit.iterations,
        history=fit.history,
        pose_history=fit.poses,
        inliers=inliers,
        n_points_used=n_used,
        n_outliers=int(len(Y) - n_used),
        n_dropped_nonfinite=int(n_input - len(Y)),
        sigma_m=unc.sigma_m,
        determined_directions=unc.determined,
        covariance=unc.covariance,
        free_directions=unc.free,
        solutions=(fit.T,),
        relative_eigenvalues=unc.obs.relative_eigenvalues,
        time_s=time.perf_counter() - t_start,
        poor_fit_reason=poor,
    )


# ---------------------------------------------------------------- verdict
def _message(fit: LocalFit, obs: Observability, n_free: int, poor: str | None) -> str:
    """How the iteration ended, the poor-fit reason and the free directions, in words."""
    message = fit.status
    if poor is not None:
        message += f"; poor fit: {poor}"
    if not obs.observable:
        message = (
            f"unobservable: {n_free} weakly constrained direction(s) "
            f"(relative information < {OBSERVABILITY_TOL:g}; points on a plane, cylinder or "
            f"sphere?): the pose is not determined along free_directions; iteration {message}"
        )
    return message


def _morton_order(Y: FloatArray) -> IntArray:
    """Order of the points along a Z-order (Morton) curve, 10 bits per axis."""
    lo = Y.min(axis=0)
    span = np.ptp(Y, axis=0).max()
    if not span > 0:
        return np.arange(len(Y))
    q = np.clip(((Y - lo) * (1023.0 / span)).astype(np.int64), 0, 1023)
    code = _spread_bits(q[:, 0]) | (_spread_bits(q[:, 1]) << 1) | (_spread_bits(q[:, 2]) << 2)
    return np.argsort(code, kind="stable")


def _spread_bits(x: IntArray) -> IntArray:
    """Insert two zero bits between the 10 low bits of x (for Morton codes)."""
    x = (x | (x << 16)) & 0x030000FF
    x = (x | (x << 8)) & 0x0300F00F
    x = (x | (x << 4)) & 0x030C30C3
    x = (x | (x << 2)) & 0x09249249
    return x


# ------------------------------------------------------------------------ iteration
def _iterate_staged(method: str, Y: FloatArray, index: MeshIndex, T0: Pose, max_it: int, tol: float,
                    outlier_cfg: OutlierConfig) -> LocalFit:
    """:func:`_iterate`, with the early updates on a regular subset of the points when there
    are many.

    The updates far from the minimum only need enough points to point the way; a regular
    subset (every k-th point along the Morton curve, so spread over the whole scan) of
    ``SUBSET_POINTS`` converges first, and the iteration then goes on over all points from
    there. The last updates move the points by a fraction of the subset's own uncertainty,
    so their closest points come from each point's near-face list (a few point-triangle
    tests a point, see :class:`Feet`). Same fixed point, same stopping rule on all points.
    """
    n = len(Y)
    if n < SUBSET_MIN_POINTS:
        return _iterate(method, Y, index, T0, max_it, tol, outlier_cfg)
    stride = n // SUBSET_POINTS
    Ys = np.ascontiguousarray(Y[::stride])
    sub = _iterate(method, Ys, index, T0, max_it, tol, outlier_cfg, tighten=False)
    full = _iterate(method, Y, index, sub.T, max_it - sub.iterations, tol, outlier_cfg, near_from_start=True)
    return replace(
        full,
        iterations=full.iterations + sub.iterations,
        history=sub.history + full.history[1:],
        poses=sub.poses + full.poses[1:],
        status=full.status + (f"; the first {sub.iterations} update(s) on a regular subset of "
                              f"{len(Ys)} points (history: their RMS)"),
    )


_Outcome = Trial | Settled | None  # None: the compiled run used up the iterations


def _iterate(method: str, Y: FloatArray, index: MeshIndex, T0: Pose, max_it: int, tol: float,
             outlier_cfg: OutlierConfig, tighten: bool = True, near_from_start: bool = False) -> LocalFit:
    """Algorithm 1: alternate closest points and the method's pose update (:data:`_STEPS`).

    Outliers follow the staged rule of :mod:`algorithms.registration.robust`: the coarse cut
    until the iteration first converges, then the final one (unless ``tighten`` is False);
    if that changes the inlier set the iteration goes on. (A tight cut from a poor start
    throws away the far points that carry the correction.) ``near_from_start``: the start
    is already close (the closest points come from near-face lists from the first query).
    """
    size = index.extent
    setup = IterationSetup(
        method=method, Y=Y, index=index, feet=Feet(index, Y, FAR_RMS_REL, FAR_REL_ERROR, near_from_start),
        stages=OutlierStages(outlier_cfg, OUTLIER_COARSE_FLOOR_REL * size, OUTLIER_FLOOR_REL * size, MIN_POINTS),
        floor2=(FLOOR_REL * size) ** 2, tol=tol, max_it=max_it)
    cp, Ym = setup.feet(T0)
    mask = setup.stages.mask(cp.distance)
    it = IterationState(T=T0, cp=cp, Ym=Ym, mask=mask, e_prev=setup.mse(cp, mask), lm_lambda=LM_LAMBDA0,
                        not_converged=f"not converged: reached max_iterations = {max_it}")
    for _ in range(max_it + 1):
        if it.e_prev <= setup.floor2:
            done = it.stop(True, floor_message(it.e_prev))
        elif it.n_updates >= max_it:
            break
        else:
            outcome = _STEPS[method](setup, it)
            if outcome is None:  # out of iterations: the check above stops
                continue
            done = conclude(setup, it, outcome)
        if done and not go_on(setup, it, tighten):
            break
    if it.cp.rel_error > 0.0:  # out of iterations while far: report exact distances
        exact_feet(setup, it)
    return it.fit()


# ------------------------------------------------------------ the methods' steps
def _candidate(setup: IterationSetup, it: IterationState, T: Pose) -> Candidate:
    """The feet and mean squared distance of the current inliers at the trial pose T."""
    cp, Ym = setup.feet(T, it.cp.face)
    return Candidate(T, cp, Ym, setup.mse(cp, it.mask))


def _propose(setup: IterationSetup, it: IterationState) -> Trial:
    """The method's update (:data:`_UPDATES`) and where it lands."""
    T_new, step = _UPDATES[setup.method](it.T, it.Ym, it.cp, it.mask)
    at = _candidate(setup, it, T_new)
    return Trial(at, step, at.e > it.e_prev * (1.0 + RISE_REL))


def _shorten(setup: IterationSetup, it: IterationState, trial: Trial) -> Trial:
    """An update that raises the residual, halved (up to ``HALVINGS`` times) until it lowers it:
    the safeguard the linearised updates need from large initial errors."""
    if not trial.at.e > it.e_prev * (1.0 + RISE_REL):
        return trial
    xi = log_se3(inv_pose(it.T) @ trial.at.T)
    for _ in range(HALVINGS):
        xi = 0.5 * xi
        at = _candidate(setup, it, it.T @ exp_se3(xi))
        if at.e < it.e_prev:
            return replace(trial, at=at)
    return trial


def _point_to_point_fallback(setup: IterationSetup, it: IterationState, trial: Trial) -> Trial:
    """Where the linearised model is wrong (far from the minimum, feet on edges) and the trial
    raises the residual: one closed-form ICP step, which never raises it."""
    if trial.at.e <= it.e_prev * (1.0 + RISE_REL):
        return trial
    at = _candidate(setup, it, update_icp(it.T, it.Ym, it.cp, it.mask)[0])
    if at.e < it.e_prev:
        it.n_fallback += 1
        return replace(trial, at=at, step=np.inf)
    return trial


def _step_icp(setup: IterationSetup, it: IterationState) -> _Outcome:
    """ICP's closed-form step, shortened where it overshoots (it never raises the residual)."""
    return _shorten(setup, it, _propose(setup, it))


def _step_linearised(setup: IterationSetup, it: IterationState) -> _Outcome:
    """tangent and va: the update, shortened, else an ICP step."""
    return _point_to_point_fallback(setup, it, _shorten(setup, it, _propose(setup, it)))


def _step_fine_001(setup: IterationSetup, it: IterationState) -> _Outcome:
    """Document 001's step as it is (its own stopping rule), else an ICP step."""
    return _point_to_point_fallback(setup, it, _propose(setup, it))


def _step_menq(setup: IterationSetup, it: IterationState) -> _Outcome:
    """A Levenberg-Marquardt step; while heavily damped (the local model is poor and the steps
    tiny) the ICP step instead where it goes further; an ICP step where no damping descends."""
    at, it.lm_lambda = _menq_step(setup, it, it.lm_lambda)
    if at is None:
        at = Candidate(it.T, it.cp, it.Ym, np.inf)
    elif it.lm_lambda > LM_ICP_LAMBDA:
        icp = _candidate(setup, it, update_icp(it.T, it.Ym, it.cp, it.mask)[0])
        if icp.e < at.e:
            at = icp
            it.n_fallback += 1
    return _point_to_point_fallback(setup, it, Trial(at))


def _menq_step(setup: IterationSetup, it: IterationState, lam: float) -> tuple[Candidate | None, float]:
    """One accepted Levenberg-Marquardt step on SE(3) of the true point-to-surface distances:
    each trial re-computes the closest points and is accepted only when the mean squared
    distance does not rise. The damping ``lam`` (relative to the diagonal of J^T J) grows tenfold
    after each rejected trial, shrinks tenfold after an accepted one.

    Returns:
        The accepted step (None when no trial up to ``LM_LAMBDA_MAX`` lowers the residual) and
        the next damping.
    """
    A, g, c = _plane_system(it.Ym, it.cp, it.mask)
    diag = np.diag(np.diag(A))
    while lam <= LM_LAMBDA_MAX:
        xi = solve_sym6(A + lam * diag, g)
        at = _candidate(setup, it, centered(it.T, c, xi))
        if at.e <= it.e_prev:
            return at, max(lam * 0.1, LM_LAMBDA0)
        lam *= 10.0
    return None, LM_LAMBDA0


def _step_hong_tan(setup: IterationSetup, it: IterationState) -> _Outcome:
    """Hong-Tan's update (its plain iterations compiled below ``PARALLEL_MIN_POINTS`` points);
    when it overshoots, the step with the rows of feet on edges along their offsets, halved,
    else an ICP step."""
    if _nb_run is not None and setup.index.backend == "numba" and len(setup.Y) < PARALLEL_MIN_POINTS:
        # the plain iterations in one compiled call (more points: the loop's queries use every core)
        outcome = _compiled_hong_tan(setup, it)
    else:
        outcome = _loop_hong_tan(setup, it)
    if isinstance(outcome, Trial) and outcome.overshoot:
        outcome = _along_edge_offsets(setup, it, outcome)
    if not isinstance(outcome, Trial):
        return outcome
    return _point_to_point_fallback(setup, it, _shorten(setup, it, outcome))


def _stop_before_message() -> str:
    """The status of Hong-Tan's stop before a tiny update."""
    return f"converged: the next update would move the pose by less than {STOP_SIGMAS:g} of its standard deviation"


def _loop_hong_tan(setup: IterationSetup, it: IterationState) -> Trial | Settled:
    """Hong-Tan's update in numpy, or a stop before it (see :func:`_update_settles`)."""
    T_new, decrease = _update_hong_tan(it.T, it.Ym, it.cp, it.mask)
    if _update_settles(it.T, it.Ym, it.cp, it.mask, decrease, it.e_prev):
        return Settled(_stop_before_message())
    at = _candidate(setup, it, T_new)
    return Trial(at, decrease, at.e > it.e_prev * (1.0 + RISE_REL))


def _compiled_hong_tan(setup: IterationSetup, it: IterationState) -> _Outcome:
    """The plain iterations compiled (:func:`_plain_steps`), taken; then the first trial that
    needs the loop's rules, a stop before an update, or None (out of iterations)."""
    plain = _plain_steps(setup, it)
    if plain.steps:
        it.n_updates += plain.steps
        it.T, it.cp, it.Ym, it.mask, it.e_prev = plain.T, plain.cp, plain.Ym, plain.mask, plain.e_prev
        it.history.extend(plain.history)
        it.poses.extend(plain.poses)
    if plain.settled:
        return Settled(_stop_before_message())
    if plain.trial is None:
        return None
    return Trial(plain.trial, None, plain.trial.e > it.e_prev * (1.0 + RISE_REL))


def _along_edge_offsets(setup: IterationSetup, it: IterationState, trial: Trial) -> Trial | Settled:
    """An overshooting Hong-Tan update, and the step with the rows of feet on edges along their
    offsets (the gradient of their distances: with the face's plane such a point pulls sideways
    and the step need not descend), whichever lands lower; a stop when even that step would move
    the pose by less than ``FALLBACK_MIN_SIGMAS`` of its standard deviation."""
    T_edge, decrease = _update_hong_tan(it.T, it.Ym, it.cp, it.mask, edges=True)
    n_used = count(it.mask, len(setup.Y))
    if decrease < FALLBACK_MIN_SIGMAS**2 * it.e_prev * n_used / max(n_used - 6, 1):
        return Settled("converged: the update overshoots where it would move the pose by less than "
                        f"{FALLBACK_MIN_SIGMAS:g} of its standard deviation")
    if edge_feet(it.Ym, it.cp, it.mask)[2].any():
        at = _candidate(setup, it, T_edge)
        if at.e < trial.at.e:
            it.n_edge += 1
            return replace(trial, at=at)
    return trial


# -------------------------------------------------- Hong-Tan's update, compiled where possible
@dataclass
class _PlainRun:
    """What :func:`_plain_steps` did: ``steps`` accepted updates ending at ``T`` (with its
    closest points, model-frame points, inlier mask and mean squared distance), their RMS
    ``history`` and ``poses``, and the next ``trial`` (None when out of iterations or
    ``settled``: stopped before an update that would move the pose by less than
    ``STOP_SIGMAS`` of its standard deviation)."""

    steps: int
    T: Pose
    cp: ClosestPoints
    Ym: FloatArray
    mask: Mask
    e_prev: float
    history: list[float]
    poses: list[Pose]
    trial: Candidate | None
    settled: bool = False


#: The compiled inlier rule of each outlier option (2: a fixed distance).
_OUTLIER_MODE: dict[OutlierConfig, int] = {None: 0, "mad": 1}


def _plain_steps(setup: IterationSetup, it: IterationState) -> _PlainRun:
    """Hong-Tan updates of :func:`_iterate` from ``it`` in one compiled call, as long as each is plain:
    it lowers the residual, leaves it above the floor, and the relative decrease stays at
    least ``tol`` (or the inlier set changes, by the current stage's rule). The same update,
    closest points (approximate while far, as :class:`Feet` does), acceptance and inlier
    rule as the loop's; the first trial that is not plain goes back to the loop's rules
    (shortened and point-to-point steps, the stopping rules), un-accepted. Stops without a
    trial where the loop's ``STOP_SIGMAS`` rule would (``settled``)."""
    _announce()
    Y, T, Ym, cp, mask, feet, stages = setup.Y, it.T, it.Ym, it.cp, it.mask, setup.feet, setup.stages
    sel = np.ones(len(Y), dtype=np.bool_) if isinstance(mask, slice) else mask.copy()
    near = feet.near
    use_near = near is not None
    if near is None:
        near = NearFaces(anchor=np.zeros((0, 3)), faces=np.zeros((0, 1), np.int64), reach=np.zeros((0, 1)))
    cfg = stages.cfg
    mode = _OUTLIER_MODE.get(cfg, 2)
    fixed = float(cfg) if mode == 2 else 0.0  # type: ignore[arg-type]
    rel_error = feet.far_rel_error
    out = _nb_run(Y, np.ascontiguousarray(T), Ym, cp.foot, cp.distance, cp.face, cp.normal, cp.rel_error > 0.0,
                  sel, isinstance(mask, slice), it.e_prev, setup.max_it - it.n_updates, setup.floor2, setup.tol,
                  STOP_SIGMAS**2, mode, stages.k, stages.floor, fixed, stages.min_points, feet.far, feet.far_m2,
                  1.0 / (1.0 + rel_error) ** 2, use_near, near.anchor, near.faces, near.reach,
                  *feet.index.kernel_arrays())
    (steps, T_acc, Ym_acc, foot, dist, face, normal, approx, all_sel, e_acc, hist, pose_arr, far,
     more, T_t, Ym_t, foot_t, dist_t, face_t, normal_t, approx_t, e_t, settled) = out
    feet.far = bool(far)
    plain = _PlainRun(
        steps=int(steps), T=T_acc, Ym=Ym_acc,
        cp=ClosestPoints(foot=foot, distance=dist, face=face, normal=normal,
                         rel_error=rel_error if approx else 0.0) if steps else cp,
        mask=(ALL if all_sel else sel) if steps else mask,
        e_prev=float(e_acc), history=[float(h) for h in hist[:steps]], poses=list(pose_arr[:steps]), trial=None,
        settled=bool(settled),
    )
    if more:
        cp_t = ClosestPoints(foot=foot_t, distance=dist_t, face=face_t, normal=normal_t,
                             rel_error=rel_error if approx_t else 0.0)
        plain.trial = Candidate(T_t, cp_t, Ym_t, float(e_t))
    return plain


def _plane_system(Ym: FloatArray, cp: ClosestPoints, mask: Mask,
                  edges: bool = False) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Normal equations ``(J^T J, J^T s)`` of the point-to-plane step about the centroid ``c``
    [m] of the points (rows ``[(y_i - c) x n_i, n_i]``, residuals ``s_i = <y_i - x_i, n_i>``;
    with ``edges`` the rows of feet on edges as :func:`plane_rows` makes them), and ``c``; one
    compiled pass over the points when numba is installed (numpy takes some forty small calls)."""
    if _nb_plane_system is not None:
        _announce()
        sel = np.ones(len(Ym), dtype=np.bool_) if isinstance(mask, slice) else mask
        return _nb_plane_system(Ym, cp.foot, cp.normal, sel, edges)
    c = Ym[mask].mean(axis=0)
    J, s = plane_rows(Ym, cp, mask, c, edges)
    A, g = normal_equations(J, s)
    return A, g, c


_announced = False


def _announce() -> None:
    """Say on stderr, once, when the localization kernels are about to be compiled."""
    global _announced
    if not _announced:
        _announced = True
        if kernels_cached([k for k in (_nb_plane_system, _nb_solve, _nb_run) if k is not None]) is False:
            print("compiling localization kernels, first run only ...", file=sys.stderr, flush=True)


def _update_settles(T: Pose, Ym: FloatArray, cp: ClosestPoints, mask: Mask, decrease: float, e_prev: float) -> bool:
    """Whether Hong-Tan's update from exact feet (predicting ``decrease`` of the sum of
    squares), and the one with the rows of feet on edges along their offsets, would both move
    the pose by less than ``STOP_SIGMAS`` of its standard deviation: a decrease of less than
    ``STOP_SIGMAS^2 sigma^2``, sigma^2 estimated from the mean square ``e_prev``. (As
    ``kernels.settled`` does in the compiled iterations.)"""
    if cp.rel_error > 0.0:
        return False
    n_used = count(mask, len(Ym))
    bound = STOP_SIGMAS**2 * e_prev * n_used / max(n_used - 6, 1)
    return decrease < bound and _update_hong_tan(T, Ym, cp, mask, edges=True)[1] < bound


def _update_hong_tan(T: Pose, Ym: FloatArray, cp: ClosestPoints, mask: Mask, edges: bool = False) -> tuple[Pose, float]:
    """Hong-Tan: the point-to-plane least squares ``xi`` minimising
    ``sum (s_i - ((y_i - c) x n_i).omega - n_i.v)^2`` about the centroid ``c`` of the points,
    applied through the exact exponential map (a Gauss-Newton step on SE(3) of the
    point-to-surface distance; quadratic convergence on exact data).

    Returns:
        The new pose, and the decrease of the sum of squared distances it predicts, ``g^T xi`` [m^2].
    """
    A, g, c = _plane_system(Ym, cp, mask, edges)
    xi = solve_sym6(A, g) if _nb_solve is None else _nb_solve(A, g)
    return centered(T, c, xi), float(g @ xi)


def printed_update(method: str, T: Pose, Ym: FloatArray, cp: ClosestPoints) -> tuple[Pose, float | None]:
    """The method's pose update from every pair, taken as it is (:mod:`.printed`): Hong-Tan's
    least squares, menq's Levenberg-Marquardt step at ``LM_LAMBDA0``, the others' own."""
    if method == "hong_tan":
        return _update_hong_tan(T, Ym, cp, ALL)[0], None
    if method == "menq":
        A, g, c = _plane_system(Ym, cp, ALL)
        return centered(T, c, solve_sym6(A + LM_LAMBDA0 * np.diag(np.diag(A)), g)), None
    return _UPDATES[method](T, Ym, cp, ALL)


#: The pose update of the methods that take it as it is (:func:`_propose`): (T, Ym, cp, mask) to
#: (the next pose, the method's step measure or None). Hong-Tan's is :func:`_update_hong_tan`,
#: menq's :func:`_menq_step`.
_UPDATES: dict[str, Callable[[Pose, FloatArray, ClosestPoints, Mask], tuple[Pose, float | None]]] = {
    "icp": update_icp,
    "va": update_va,
    "tangent": update_tangent,
    "fine_001": update_fine_001,
}

#: One iteration's trial of each method: its update with the safeguards it takes.
_STEPS: dict[str, Callable[[IterationSetup, IterationState], _Outcome]] = {
    "hong_tan": _step_hong_tan,
    "tangent": _step_linearised,
    "menq": _step_menq,
    "va": _step_linearised,
    "icp": _step_icp,
    "fine_001": _step_fine_001,
}
