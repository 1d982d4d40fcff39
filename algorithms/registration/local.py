"""CAD-model-based workpiece localization: Algorithm 1 of document 000 with each pose update
it names, and document 001's fine stage.

Frames and units. ``points`` are measured in the world (robot base / machine) frame, in
metres. The model ``mesh`` is in the workpiece (CAD) frame, in metres. The result
``T_world_workpiece`` maps workpiece coordinates to world coordinates, so that
``points ~= transform_points(T_world_workpiece, model_points)``. Document 000 writes this pose
``g = (p, R)``, ``y = R x + p``; document 001 writes its inverse ``T`` (``T P_i ~= Q_i``).

Algorithm 1 (document 000), for every method:

1. ``k = 0``, ``g^0`` = the initial pose; feet ``x_i^0`` = closest points on the model to the
   points mapped into the model frame, ``y_i^0 = (g^0)^-1 y_i``.
2. ``e_0`` = mean squared point-to-model distance.
3. ``k = k + 1``: update ``g^k`` from the pairs (the update names the method, below).
4. New feet for ``g^k`` (exact closest points, :class:`algorithms.geometry.mesh_index.MeshIndex`),
   ``e_k`` = their mean squared distance.
5. Stop when ``1 - e_k / e_(k-1) < delta`` (``tolerance``) or when ``e_k`` reaches the
   numerical floor (RMS below ``1e-12`` times the model's size, i.e. the data fit exactly),
   or after ``max_iterations`` (then ``converged`` is False).

The updates, all computed in the workpiece frame from the model-frame points ``y_i``, feet
``x_i``, face normals ``n_i`` and plane residuals ``s_i = <y_i - x_i, n_i>``:

* ``"icp"`` (Besl-McKay): closed-form point-to-point (Horn/Kabsch by SVD, det = +1): the rigid
  ``D`` minimising ``sum |D y_i - x_i|^2``; ``g^k = g^(k-1) D^-1``.
* ``"va"`` (variational algorithm of Li's group): point-to-point objective, one Gauss-Newton
  step on SE(3) through the exponential map: ``xi`` minimises
  ``sum |y_i - x_i - (omega x y_i + v)|^2``; ``g^k = g^(k-1) exp(xi)``.
* ``"tangent"``: linearised point-to-plane (tangent planes at the feet): ``xi`` minimises
  ``sum (s_i - (y_i x n_i).omega - n_i.v)^2``; the small-motion matrix
  ``[I - hat(omega), -v]`` is made a rotation (nearest rotation, SVD) and applied:
  first-order retraction, about the workpiece origin.
* ``"hong_tan"`` (default): the same point-to-plane least squares, solved about the centroid
  of the points and applied through the exact exponential map (a Gauss-Newton step on SE(3)
  for the point-to-surface distance; quadratic convergence on exact data). Document 000
  finds it the fastest and most accurate of the family; it is the efficient estimator whose
  covariance reaches the Cramer-Rao bound here (see :mod:`algorithms.registration.uncertainty`).
* ``"menq"``: nonlinear least squares (Levenberg-Marquardt) on SE(3) of the true
  point-to-surface distances: each trial step re-computes the closest points and is accepted
  only when the mean squared distance drops (the damping grows otherwise). More closest-point
  queries per iteration than ``hong_tan``, the same minimum.
* ``"fine_001"``: document 001's fine stage: the point-to-point objective
  ``J = sum |T P_i - Q'_i|^2`` linearised for a small motion (sin t = t, cos t = 1), solved
  as a 6x6 linear system for ``(theta_x, theta_y, theta_z, Delta_x, Delta_y, Delta_z)`` with
  the *variable iteration centre*: the origin is moved to the centroid ``S_k`` of the current
  points (``A_k``), ``T_d(k)`` is built exactly from the solved angles (``Rz Ry Rx``) and
  translation, mapped back ``T'_d = A_k T_d A_k^-1`` and accumulated ``T(k) = T'_d T(k-1)``.
  It stops, as in document 001, when ``sum dtheta^2 + sum dDelta^2 < d`` (``tolerance``,
  radians^2 + metres^2).

Document 000 only names VA, Tangent, Menq and Hong-Tan; the readings above follow what it
says of them (Tangent and Hong-Tan solve a linear system that turns singular on symmetric
features, Hong-Tan is the fastest and most accurate, Menq is nonlinear least squares) and
the cited papers' usual descriptions; the original Hong-Tan patent and Li's VA paper were not
at hand. All six share the same fixed point (the minimum of the sum of squared
point-to-surface distances): at a stationary point of ICP, ``sum d_i n_i = 0`` and
``sum d_i (y_i x n_i) = 0``, the normal equations of the point-to-plane methods.

The point-to-point methods (icp, va, fine_001) converge linearly (slowly when the points can
slide along the surface, e.g. 0.87 to 0.999 per iteration on the documents' parts); they
reach the same minimum, given enough iterations, and default to more iterations and a
smaller ``delta``. Safeguards shared by the linearised updates: a step that raises the
residual is halved (up to 8 times); if that fails, one closed-form point-to-point (ICP) step
is taken instead (it never raises the residual); menq takes the ICP step when its damping has
grown large. The number of such fallback steps is appended to ``status``.

Local minima: like every local method these converge to the nearest minimum. From random
starts of up to 45 degrees about the part and 20 % of its size, measured with 150 exact
points (benchmarks/bench_closest_point.py --section basin), every method recovered all 20
starts on the S-surface part and workpiece A, and 19 of 20 on workpiece B (one start, 19
degrees and 28 mm away, ends in a minimum 11.5 degrees off at 3.5 mm RMS for all six
methods). With ``sigma`` given, a converged fit whose RMS exceeds 3 sigma says "poor fit" in
``status``; ``init="global"`` (Algorithm 5's multistart) is the remedy.

Robustness: rows with NaN or infinite coordinates are dropped and counted; fewer than 6
finite points is an error. Outliers (spurious returns, fixture points) are rejected at every
iteration, by default (``outlier="mad"``) when their distance to the model exceeds
``max(5 * 1.4826 * median(distance), 1e-6 * model size)`` (a robust 5-sigma cut for Gaussian
noise along the normals, with a floor so exact data lose nothing). Until the iteration first
converges the cut is looser, ``max(8 * 1.4826 * median(distance), 0.01 * model size)``:
only gross outliers go. Far from the minimum the residuals are systematic misfit, not noise,
and the far points are the ones that carry the correction; cutting them early was seen to
trap the iteration in wrong minima and to slow the point-to-point methods a hundredfold. ``outlier=<float>`` is a
fixed maximum distance [m]; ``outlier=None`` keeps every point. Point sets spanning more
than 20 times the model's bounding-box diagonal, or less than 1/1000 of it, raise an error
that the units look wrong.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import as_pose, exp_se3, hat, inv_pose, log_se3, make_pose
from algorithms.registration.uncertainty import OBSERVABILITY_TOL, _sym_inverse, observability

__all__ = [
    "METHODS",
    "DEFAULT_METHOD",
    "LocalizationResult",
    "localize",
    "OUTLIER_K",
    "UNITS_MAX_RATIO",
    "UNITS_MIN_RATIO",
]

METHODS = ("hong_tan", "tangent", "menq", "va", "icp", "fine_001")
DEFAULT_METHOD = "hong_tan"
#: Iteration caps per method (point-to-point methods converge linearly).
MAX_ITERATIONS = {"hong_tan": 100, "tangent": 100, "menq": 100, "va": 3000, "icp": 3000, "fine_001": 3000}
#: delta of ``1 - e_k/e_(k-1) < delta``; for fine_001 the ``d`` of its step criterion.
TOLERANCE = {"hong_tan": 1e-9, "tangent": 1e-9, "menq": 1e-9, "va": 1e-12, "icp": 1e-12, "fine_001": 1e-22}
#: RMS residual below ``FLOOR_REL * model size`` counts as an exact fit.
FLOOR_REL = 1e-12
#: Outlier cut: ``OUTLIER_K`` robust sigmas (sigma = 1.4826 median distance), floored.
OUTLIER_K = 5.0
OUTLIER_K_COARSE = 8.0
#: Until the first convergence no point within this fraction of the model size is cut
#: (systematic misfit is not noise: cutting it slows or traps the iteration).
OUTLIER_COARSE_FLOOR_REL = 1e-2
OUTLIER_FLOOR_REL = 1e-6
#: Units check: point spread relative to the model's bounding-box diagonal.
UNITS_MAX_RATIO = 20.0
UNITS_MIN_RATIO = 1e-3
MIN_POINTS = 6
#: With a given sigma, an RMS residual above this many sigmas is reported as a poor fit.
POOR_FIT_SIGMAS = 3.0
OBSERVABILITY_MAX_POINTS = 4096
#: Initial (and smallest) Levenberg-Marquardt damping of "menq", relative to diag(J^T J).
LM_LAMBDA0 = 1e-8


@dataclass(frozen=True)
class LocalizationResult:
    """Result of :func:`localize`.

    Attributes:
        T_world_workpiece: (4, 4) pose of the workpiece (CAD) frame in the world frame.
        method: the pose update used.
        iterations: number of pose updates made.
        converged: whether the iteration met its stopping rule (not whether the pose is
            determined: see ``observable``).
        status: why it stopped, in words; starts with ``"unobservable"`` when the points do
            not fix all six DOF (then the pose must not be trusted along ``weak_directions``).
        rmse_m: RMS point-to-model distance of the inliers at the result [m].
        history: RMS distance [m] at the start and after every iteration.
        covariance: (6, 6) estimated covariance of the pose twist ``[omega, v]`` in the
            workpiece frame (the error twist of ``T_est = T_true exp(xi)``; rad^2, rad m,
            m^2), the Cramer-Rao
            expression at the estimate with ``sigma_m``; None when unobservable.
        weak_directions: (k, 6) weakly constrained twists ``[omega, v]`` (workpiece frame),
            empty (0, 6) when observable.
        observable: False when the points cannot fix all six DOF (plane, cylinder, sphere).
        relative_eigenvalues: (6,) scaled information eigenvalues / the largest, ascending.
        sigma_m: noise sigma used for the covariance [m] (given, or estimated from residuals).
        n_points_used: inliers at the result.
        n_dropped_nonfinite: rows dropped for NaN or infinite coordinates.
        n_outliers: finite points rejected as outliers at the result.
        inliers: (N,) bool over the input rows: finite and not an outlier.
        time_s: wall time of the call [s].
    """

    T_world_workpiece: np.ndarray
    method: str
    iterations: int
    converged: bool
    status: str
    rmse_m: float
    history: tuple
    covariance: np.ndarray | None
    weak_directions: np.ndarray
    observable: bool
    relative_eigenvalues: np.ndarray
    sigma_m: float
    n_points_used: int
    n_dropped_nonfinite: int
    n_outliers: int
    inliers: np.ndarray = field(repr=False)
    time_s: float = 0.0


def localize(
    points,
    mesh=None,
    method: str = DEFAULT_METHOD,
    init=None,
    rng: np.random.Generator | None = None,
    sigma: float | None = None,
    max_iterations: int | None = None,
    tolerance: float | None = None,
    outlier="mad",
    index: MeshIndex | None = None,
) -> LocalizationResult:
    """Find ``T_world_workpiece`` from measured points and the workpiece's CAD mesh.

    Args:
        points: (N, 3) [m] measured points, world (robot base) frame; NaN/inf rows dropped.
        mesh: the model, a ``trimesh.Trimesh`` in the workpiece frame [m]. May be None when
            ``index`` is given.
        method: one of ``METHODS`` (see the module docstring); default ``"hong_tan"``.
        init: initial ``T_world_workpiece``: None (identity), a rigid (4, 4) matrix, or
            ``"global"`` (the multistart global search of document 000, Algorithm 5).
        rng: random generator for the global search (ignored otherwise).
        sigma: noise sigma along the normals [m] for the covariance; estimated from the
            residuals when None.
        max_iterations: cap on pose updates (default per method, ``MAX_ITERATIONS``).
        tolerance: ``delta`` of the stopping rule (``d`` for fine_001), default ``TOLERANCE``.
        outlier: ``"mad"`` (default), a maximum distance [m], or None (keep all).
        index: a prebuilt :class:`MeshIndex` of ``mesh`` to reuse across calls.

    Returns:
        LocalizationResult.

    Raises:
        AlgorithmError: bad points (shape, fewer than 6 finite), an empty mesh, units that
            look wrong, a non-rigid ``init``, an unknown method or option.
    """
    t_start = time.perf_counter()
    if method not in METHODS:
        raise AlgorithmError(f"method must be one of {', '.join(METHODS)}; got {method!r}")
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise AlgorithmError(f"points must be (N, 3) with N >= {MIN_POINTS}, got {P.shape}")
    finite = np.all(np.isfinite(P), axis=1)
    n_drop = int(len(P) - finite.sum())
    if finite.sum() < MIN_POINTS:
        raise AlgorithmError(
            f"points must be (N, 3) with at least {MIN_POINTS} finite rows, got {int(finite.sum())} "
            f"finite of {len(P)}"
        )
    if index is None:
        if mesh is None:
            raise AlgorithmError("give a mesh (or a prebuilt index)")
        index = MeshIndex(mesh)
    elif not isinstance(index, MeshIndex):
        raise AlgorithmError(f"index must be a MeshIndex, got {type(index).__name__}")
    if max_iterations is None:
        max_iterations = MAX_ITERATIONS[method]
    if int(max_iterations) < 1:
        raise AlgorithmError(f"max_iterations must be >= 1, got {max_iterations}")
    if tolerance is None:
        tolerance = TOLERANCE[method]
    if not (np.isfinite(tolerance) and tolerance >= 0):
        raise AlgorithmError(f"tolerance must be a finite number >= 0, got {tolerance}")
    if sigma is not None and not (np.isfinite(sigma) and sigma > 0):
        raise AlgorithmError(f"sigma must be a positive length [m] or None, got {sigma}")
    outlier_cfg = _outlier_config(outlier)

    rows = np.nonzero(finite)[0]
    Y = P[rows]
    _check_units(Y, index)

    if init is None:
        T0 = np.eye(4)
    elif isinstance(init, str):
        if init != "global":
            raise AlgorithmError(f"init must be None, a 4x4 rigid transform or 'global', got {init!r}")
        from algorithms.registration.global_search import global_localize  # lazy: optional heavy module

        g = global_localize(Y, index.mesh, index=index, rng=rng)
        T0 = as_pose(getattr(g, "T_world_workpiece", g), name="global search result")
    else:
        T0 = as_pose(init, name="init")

    # Spatially coherent order: neighbouring points query neighbouring triangles (faster).
    order = _morton_order(Y)
    Y = Y[order]
    rows = rows[order]

    state = _iterate(method, Y, index, T0, int(max_iterations), float(tolerance), outlier_cfg)
    T, cp, mask = state["T"], state["cp"], state["mask"]
    n_used = _count(mask, len(Y))
    if n_used < MIN_POINTS:
        raise AlgorithmError(
            f"only {n_used} points lie within the outlier distance of the model; "
            f"at least {MIN_POINTS} are needed"
        )

    # Uncertainty at the result (workpiece frame).
    Ym = _apply(inv_pose(T), Y)
    feet = cp.foot[mask]
    normals = cp.normal[mask]
    s = np.einsum("ij,ij->i", Ym[mask] - feet, normals)
    # Observability is a property of where the points are; a regular subsample of at most
    # OBSERVABILITY_MAX_POINTS estimates the same normalised information (exactly so for
    # symmetric sets) at a fraction of the cost of the smooth normals.
    stride = max(1, -(-n_used // OBSERVABILITY_MAX_POINTS))
    sub_feet = feet[::stride]
    sub_faces = cp.face[mask][::stride]
    obs = observability(sub_feet, index.smooth_normals(sub_faces, sub_feet), OBSERVABILITY_TOL)
    if sigma is None:
        sigma_used = float(np.sqrt(np.sum(s * s) / max(n_used - 6, 1)))
    else:
        sigma_used = float(sigma)
    covariance = None
    if obs.observable:
        J = np.empty((n_used, 6))
        _cross_into(feet, normals, J)
        J[:, 3:] = normals
        covariance = _sym_inverse(_gram(J)) * sigma_used**2
    status = state["status"]
    rmse = float(np.sqrt(np.mean(cp.distance[mask] ** 2)))
    if sigma is not None and rmse > POOR_FIT_SIGMAS * sigma:
        # converged, but to residuals the stated noise cannot explain: a local minimum
        # (Algorithm 5's multistart is the remedy) or a model that does not match the part
        status += (
            f"; poor fit: RMS {rmse:.3g} m is {rmse / sigma:.0f} times the given sigma "
            "(local minimum or wrong model?)"
        )
    if not obs.observable:
        status = (
            f"unobservable: {len(obs.weak_directions)} weakly constrained direction(s) "
            f"(relative information < {OBSERVABILITY_TOL:g}; points on a plane, cylinder or "
            f"sphere?): the pose is not determined along weak_directions; iteration {status}"
        )
    inliers = np.zeros(len(P), dtype=bool)
    inliers[rows[mask]] = True
    return LocalizationResult(
        T_world_workpiece=T,
        method=method,
        iterations=state["iterations"],
        converged=state["converged"],
        status=status,
        rmse_m=rmse,
        history=tuple(state["history"]),
        covariance=covariance,
        weak_directions=obs.weak_directions,
        observable=obs.observable,
        relative_eigenvalues=obs.relative_eigenvalues,
        sigma_m=sigma_used,
        n_points_used=n_used,
        n_dropped_nonfinite=n_drop,
        n_outliers=int(len(Y) - n_used),
        inliers=inliers,
        time_s=time.perf_counter() - t_start,
    )


# ----------------------------------------------------------------------------- checks
def _outlier_config(outlier):
    if outlier is None or (isinstance(outlier, str) and outlier == "none"):
        return None
    if isinstance(outlier, str):
        if outlier != "mad":
            raise AlgorithmError(f"outlier must be 'mad', a distance [m] or None, got {outlier!r}")
        return "mad"
    try:
        value = float(outlier)
    except (TypeError, ValueError):
        raise AlgorithmError(f"outlier must be 'mad', a distance [m] or None, got {outlier!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise AlgorithmError(f"outlier distance must be a positive length [m], got {outlier!r}")
    return value


def _check_units(Y: np.ndarray, index: MeshIndex) -> None:
    """Refuse point sets whose size no rigid pose of the model can explain."""
    size = index.extent
    if not size > 0:
        raise AlgorithmError("the model has zero size (all vertices coincide)")
    center = np.median(Y, axis=0)
    r = np.linalg.norm(Y - center, axis=1)
    spread = 2.0 * float(np.percentile(r, 90))
    if spread > UNITS_MAX_RATIO * size:
        raise AlgorithmError(
            f"the points span {spread:.4g} but the model is only {size:.4g} across "
            f"({spread / size:.0f}x): units look wrong (points in mm and model in m?); "
            "mesh and points must be in the same units (metres)"
        )
    if spread < UNITS_MIN_RATIO * size:
        raise AlgorithmError(
            f"the points span {spread:.4g} but the model is {size:.4g} across "
            f"(1/{size / max(spread, 1e-300):.0f}): units look wrong (points in m and model in mm?) "
            "or the points cover too little of the part"
        )


def _morton_order(Y: np.ndarray) -> np.ndarray:
    """Order of the points along a Z-order (Morton) curve, 10 bits per axis."""
    lo = Y.min(axis=0)
    span = np.ptp(Y, axis=0).max()
    if not span > 0:
        return np.arange(len(Y))
    q = np.clip(((Y - lo) * (1023.0 / span)).astype(np.int64), 0, 1023)
    code = _spread_bits(q[:, 0]) | (_spread_bits(q[:, 1]) << 1) | (_spread_bits(q[:, 2]) << 2)
    return np.argsort(code, kind="stable")


def _spread_bits(x: np.ndarray) -> np.ndarray:
    """Insert two zero bits between the 10 low bits of x (for Morton codes)."""
    x = (x | (x << 16)) & 0x030000FF
    x = (x | (x << 8)) & 0x0300F00F
    x = (x | (x << 4)) & 0x030C30C3
    x = (x | (x << 2)) & 0x09249249
    return x


# ------------------------------------------------------------------------ iteration
def _inlier_mask(d: np.ndarray, cfg, floor: float, k: float = None) -> np.ndarray:
    if cfg is None:
        return _ALL
    if cfg == "mad":
        # distances are |noise| for Gaussian noise along the normals: sigma = 1.4826 median
        thr = max((OUTLIER_K if k is None else k) * 1.4826 * _median(d), floor)
    else:
        thr = cfg
    mask = d <= thr
    if mask.all():
        return _ALL  # a view, not a copy, of every array it indexes
    if mask.sum() < MIN_POINTS:
        # e.g. a fixed distance and a poor start: keep the closest half to get going
        mask = d <= _median(d)
    return mask


_ALL = slice(None)


def _same(a, b) -> bool:
    if isinstance(a, slice) or isinstance(b, slice):
        return isinstance(a, slice) and isinstance(b, slice)
    return np.array_equal(a, b)


def _count(mask, n: int) -> int:
    return n if isinstance(mask, slice) else int(mask.sum())


def _apply(T: np.ndarray, P: np.ndarray) -> np.ndarray:
    """T applied to (N, 3) points, without BLAS (see _gram): same as se3.transform_points."""
    R = T[:3, :3]
    if len(P) < 4096:  # small: BLAS stays on one thread and is fastest
        return P @ R.T + T[:3, 3]
    out = np.empty_like(P)
    x, y, z = P[:, 0], P[:, 1], P[:, 2]
    for k in range(3):
        out[:, k] = R[k, 0] * x + R[k, 1] * y + R[k, 2] * z + T[k, 3]
    return out


def _median(d: np.ndarray) -> float:
    k = len(d) // 2
    return float(np.partition(d, k)[k])


def _iterate(method, Y, index, T0, max_it, tol, outlier_cfg):
    """Algorithm 1: alternate exact closest points and the method's pose update.

    Outliers ("mad") are cut at OUTLIER_K_COARSE robust sigmas until the iteration first
    converges, then at OUTLIER_K; if that changes the inlier set the iteration goes on. (A
    tight cut from a poor start throws away the far points that carry the correction.)
    """
    size = index.extent
    floor2 = (FLOOR_REL * size) ** 2
    k_out = OUTLIER_K_COARSE
    out_floor = OUTLIER_COARSE_FLOOR_REL * size

    def mse(cp_, mask_):
        d = cp_.distance[mask_]
        return float((d * d).sum() / len(d))  # no BLAS: its threads contend with numba's

    T = T0
    cp = index.query(_apply(inv_pose(T), Y))
    mask = _inlier_mask(cp.distance, outlier_cfg, out_floor, k_out)
    e_prev = mse(cp, mask)
    history = [float(np.sqrt(e_prev))]
    lm_lambda = LM_LAMBDA0
    converged = False
    status = f"not converged: reached max_iterations = {max_it}"
    n_updates = 0
    n_fallback = 0
    for _ in range(max_it + 1):
        done = False
        if e_prev <= floor2:
            done, converged = True, True
            status = f"converged: residual at the numerical floor (RMS {np.sqrt(e_prev):.3g} m)"
        elif n_updates >= max_it:
            break
        else:
            Ym = _apply(inv_pose(T), Y)
            step = None
            if method == "menq":
                T_new, cp_new, e_new, lm_lambda, ok = _menq_step(T, Ym, Y, cp, mask, index, e_prev, lm_lambda)
                if not ok:
                    e_new = np.inf
                    cp_new = cp
                elif lm_lambda > 1e-3:
                    # heavily damped: the local model is poor and the steps are tiny; a
                    # point-to-point step may go further (it never raises the residual)
                    T_icp, _ = _update_icp(T, Ym, cp, mask)
                    cp_icp = index.query(_apply(inv_pose(T_icp), Y), hint=cp.face)
                    e_icp = mse(cp_icp, mask)
                    if e_icp < e_new:
                        T_new, cp_new, e_new = T_icp, cp_icp, e_icp
                        n_fallback += 1
            else:
                T_new, step = _UPDATES[method](T, Ym, cp, mask)
                cp_new = index.query(_apply(inv_pose(T_new), Y), hint=cp.face)
                e_new = mse(cp_new, mask)
                if e_new > e_prev * (1.0 + 1e-6) and method != "fine_001":
                    # overshoot far from the minimum: halve the motion (a safeguard the
                    # linearised updates need from large initial errors)
                    xi = log_se3(inv_pose(T) @ T_new)
                    for _ in range(8):
                        xi = 0.5 * xi
                        T_try = T @ exp_se3(xi)
                        cp_try = index.query(_apply(inv_pose(T_try), Y), hint=cp.face)
                        e_try = mse(cp_try, mask)
                        if e_try < e_prev:
                            T_new, cp_new, e_new = T_try, cp_try, e_try
                            break
            if not e_new <= e_prev * (1.0 + 1e-6) and method != "icp":
                # The linearised model is wrong here (far from the minimum, feet on edges):
                # take one closed-form point-to-point step, which never raises the residual.
                T_icp, _ = _update_icp(T, Ym, cp, mask)
                cp_icp = index.query(_apply(inv_pose(T_icp), Y), hint=cp.face)
                e_icp = mse(cp_icp, mask)
                if e_icp < e_prev:
                    T_new, cp_new, e_new, step = T_icp, cp_icp, e_icp, np.inf
                    n_fallback += 1
            if not e_new <= e_prev:
                # no decrease: keep the previous pose
                done = True
                if e_new <= e_prev * (1.0 + 1e-6):
                    converged = True
                    status = f"converged: no further decrease (1 - e_k/e_(k-1) = {1.0 - e_new / e_prev:.3g})"
                else:
                    converged = False
                    status = (
                        "not converged: stalled, no step along the update lowers the residual "
                        f"(1 - e_k/e_(k-1) = {1.0 - e_new / e_prev:.3g})"
                    )
            else:
                n_updates += 1
                T, cp = T_new, cp_new
                history.append(float(np.sqrt(e_new)))
                rel = 1.0 - e_new / e_prev if e_prev > 0 else 0.0
                new_mask = _inlier_mask(cp.distance, outlier_cfg, out_floor, k_out)
                mask_changed = not _same(new_mask, mask)
                mask = new_mask
                e_prev = mse(cp, mask)
                if e_prev <= floor2:
                    done, converged = True, True
                    status = f"converged: residual at the numerical floor (RMS {np.sqrt(e_prev):.3g} m)"
                elif mask_changed:
                    pass
                elif method == "fine_001":
                    if step < tol:
                        done, converged = True, True
                        status = f"converged: step sum dtheta^2 + sum dDelta^2 = {step:.3g} < d = {tol:g}"
                elif rel < tol:
                    done, converged = True, True
                    status = f"converged: relative decrease 1 - e_k/e_(k-1) = {rel:.3g} < delta = {tol:g}"
        if done:
            if converged and outlier_cfg == "mad" and k_out != OUTLIER_K:
                k_out = OUTLIER_K
                out_floor = OUTLIER_FLOOR_REL * size
                new_mask = _inlier_mask(cp.distance, outlier_cfg, out_floor, k_out)
                if not _same(new_mask, mask):
                    mask = new_mask
                    e_prev = mse(cp, mask)
                    converged = False
                    status = f"not converged: reached max_iterations = {max_it}"
                    continue
            break
    return {
        "T": T,
        "cp": cp,
        "mask": mask,
        "history": history,
        "iterations": n_updates,
        "converged": converged,
        "status": status + (f" ({n_fallback} point-to-point fallback step(s))" if n_fallback else ""),
    }


def _gram(J: np.ndarray) -> np.ndarray:
    """J^T J in row blocks small enough that BLAS stays on one thread: BLAS worker threads
    spin after a call and contend with the closest-point threads on small machines."""
    A = np.zeros((J.shape[1], J.shape[1]))
    for i in range(0, len(J), 2048):
        Jc = J[i : i + 2048]
        A += Jc.T @ Jc
    return A


def _normal_equations(J: np.ndarray, b: np.ndarray):
    """J^T J and J^T b (see _gram)."""
    return _gram(J), np.einsum("ij,i->j", J, b)


def _solve(A: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Solve the symmetric 6x6 system A x = g, minimum-norm where A is singular."""
    d = np.sqrt(np.diag(A))
    d[d == 0] = 1.0
    B = A / d[:, None] / d[None, :]
    w, V = np.linalg.eigh(B)
    keep = w > w[-1] * 1e-13
    x = V[:, keep] @ ((V[:, keep].T @ (g / d)) / w[keep])
    return x / d


def _plane_rows(Ym, cp, mask, center):
    y = Ym[mask]
    n = cp.normal[mask]
    s = np.einsum("ij,ij->i", y - cp.foot[mask], n)
    J = np.empty((len(y), 6))
    _cross_into(y - center, n, J)
    J[:, 3:] = n
    return J, s


def _cross_into(a, b, out):
    """out[:, :3] = a x b (row-wise), cheaper than np.cross for (N, 3)."""
    ax, ay, az = a[:, 0], a[:, 1], a[:, 2]
    bx, by, bz = b[:, 0], b[:, 1], b[:, 2]
    out[:, 0] = ay * bz - az * by
    out[:, 1] = az * bx - ax * bz
    out[:, 2] = ax * by - ay * bx


def _update_icp(T, Ym, cp, mask):
    y = Ym[mask]
    x = cp.foot[mask]
    yc = y.mean(axis=0)
    xc = x.mean(axis=0)
    H = np.einsum("ij,ik->jk", y - yc, x - xc)
    U, _, Vt = np.linalg.svd(H)
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ S @ U.T
    D = make_pose(R, xc - R @ yc)
    return T @ inv_pose(D), None


def _small_motion_system(u, r):
    """Normal equations of ``omega x u_i + v = r_i`` (three rows per point, rows ``[u x e_k, e_k]``)."""
    A = np.zeros((6, 6))
    g = np.zeros(6)
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        Jk = np.hstack([np.cross(u, e), np.broadcast_to(e, u.shape)])
        Ak, gk = _normal_equations(Jk, r[:, k])
        A += Ak
        g += gk
    return A, g


def _update_va(T, Ym, cp, mask):
    y = Ym[mask]
    r = y - cp.foot[mask]
    # omega x y + v = r  (3 rows per point)
    xi = _solve(*_small_motion_system(y, r))
    return T @ exp_se3(xi), None


def _update_tangent(T, Ym, cp, mask):
    J, s = _plane_rows(Ym, cp, mask, np.zeros(3))
    xi = _solve(*_normal_equations(J, s))
    M = np.eye(3) - hat(xi[:3])
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    D = make_pose(R, -xi[3:])
    return T @ inv_pose(D), None


def _centered(T, c, xi):
    """T A_c exp(xi) A_c^-1: the model-frame motion exp(-xi) about the point c."""
    A = make_pose(None, c)
    return T @ A @ exp_se3(xi) @ inv_pose(A)


def _update_hong_tan(T, Ym, cp, mask):
    c = Ym[mask].mean(axis=0)
    J, s = _plane_rows(Ym, cp, mask, c)
    xi = _solve(*_normal_equations(J, s))
    return _centered(T, c, xi), None


def _rot_xyz(t):
    cx, cy, cz = np.cos(t)
    sx, sy, sz = np.sin(t)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _update_fine_001(T, Ym, cp, mask):
    y = Ym[mask]
    x = cp.foot[mask]
    S = y.mean(axis=0)  # variable iteration centre S_k
    u = y - S
    b = x - y
    # theta x u + Delta = Q' - P  (linearised T_d), 3 rows per point
    p = _solve(*_small_motion_system(u, b))
    theta, delta = p[:3], p[3:]
    Td = make_pose(_rot_xyz(theta), delta)
    Ak = make_pose(None, S)
    Td_prime = Ak @ Td @ inv_pose(Ak)  # maps model-frame points: T(k) = T'_d T(k-1)
    step = float(theta @ theta + delta @ delta)
    return T @ inv_pose(Td_prime), step


def _menq_step(T, Ym, Y, cp, mask, index, e_prev, lam):
    """One accepted Levenberg-Marquardt step on the true point-to-surface distances.

    Returns (T, closest points, e, next lambda, ok). The damping ``lam`` (relative to the
    diagonal of J^T J) grows tenfold after each rejected trial, shrinks tenfold after an
    accepted one; ok is False when no trial up to lam = 1e8 lowers the residual.
    """
    c = Ym[mask].mean(axis=0)
    J, s = _plane_rows(Ym, cp, mask, c)
    A, g = _normal_equations(J, s)
    diag = np.diag(np.diag(A))
    while lam <= 1e8:
        xi = _solve(A + lam * diag, g)
        T_try = _centered(T, c, xi)
        cp_try = index.query(_apply(inv_pose(T_try), Y), hint=cp.face)
        d = cp_try.distance[mask]
        e_try = float((d * d).sum() / len(d))
        if e_try <= e_prev:
            return T_try, cp_try, e_try, max(lam * 0.1, LM_LAMBDA0), True
        lam *= 10.0
    return T, cp, e_prev, LM_LAMBDA0, False


_UPDATES = {
    "icp": _update_icp,
    "va": _update_va,
    "tangent": _update_tangent,
    "hong_tan": _update_hong_tan,
    "fine_001": _update_fine_001,
}
