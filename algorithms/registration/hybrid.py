"""Hybrid (envelopment) localization: document 000's Algorithm 3.

The problem (document 000, section 5.1). Some surfaces of the part are finished ("standard")
and symmetric; the rest are rough (cast, forged) and carry stock. Find the pose of the
finished part (the CAD model) so that its finished features match the measured finished
points, and every measured rough point ``z_i`` lies at least the machining allowance
``delta_i`` outside the model: ``<g^-1 z_i - t_i, n_i> >= delta_i`` (``t_i`` the closest
model point, ``n_i`` the outward normal there).

The solution (document 000, section 5.2):

1. The finished points fix the pose on ``SE(3)/G_0`` (Algorithm 2, :mod:`algorithms.registration.symmetric`,
   with ``G_0`` found from the data or given); the pose ``g_0`` is left free along ``G_0``.
2. Over ``g(lambda) = g_0 exp(sum lambda_j eta_j)`` (``eta_j`` a basis of ``g_0``) the rough
   points are kept outside by their allowances while the envelope objective
   ``e_e = sum_i ||g^-1 z_i - t_i||^2`` is minimised. Each step is the linear programme of
   Algorithm 3, ``min <de_e, lambda>  s.t.  f + Df lambda <= 0`` with
   ``f_i = delta_i - d_i`` (``d_i`` the signed distance of ``z_i`` from the model), solved by
   scipy's HiGHS; then ``g_k = g_(k-1) exp(sum lambda_j eta_j)``. Stop when
   ``1 - e_k / e_(k-1) < delta``.

What the document leaves open, and the choices made here:

* A linear programme with a linear objective runs to a vertex or is unbounded; the step is
  therefore bounded by a trust region (a box on ``lambda``, in metres of point motion), and
  the LP's direction is followed as far as the quadratic ``e_e`` keeps falling (exact line
  search on its linearisation). Steps that would break an allowance on the true (nonlinear)
  distances or not lower ``e_e`` are shrunk.
* Before that, and always, the **best achievable minimum margin** ``max_lambda min_i (d_i -
  delta_i)`` is found by the same kind of LP steps (maximise ``t`` subject to
  ``d_i - A_i lambda - delta_i >= t``); where the LP sees no gain (the smallest margins flat
  to first order: rough points over finished faces parallel to ``G_0``'s motions) compass
  steps along each direction, from the trust region's size down to ``COMPASS_MIN_REL`` of the
  rough points' size, are tried before a maximum is declared. When it is negative no pose
  along ``G_0`` gives every rough point its allowance: the result says so
  (``feasible = False``), its pose is the max-min placement (the best achievable), and
  ``limiting_points`` names the points that hold the margin down (within ``LIMIT_TOL_REL``
  of the size of the rough-point set of the minimum). When it is not negative, Algorithm 3
  starts from there.
* A rough point that even at the max-min placement lies inside the finished model by more
  than the stock (``stock_m``, default the 10th percentile of the rough points' signed
  distances there: the thin end of the stock) is not on a rough surface (a finished-surface
  or fixture point, or the wrong model): that is an input error naming the points. A point
  inside by less is a casting with too little stock there: the infeasibility report.
* Directions of ``G_0`` that neither the objective nor any allowance depends on (the rough
  points' information along them is below ``DETECTION_TOL`` of the strongest, e.g. rotation
  about the axis of a round boss) stay free and are reported as such.

Frames and units: points in the world frame, the model in the workpiece frame, metres;
twists ``[omega, v]`` in the workpiece frame about its origin, as everywhere in this package.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray, IntArray, Pose
from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import as_pose, exp_se3, inv_pose, transform_points
from algorithms.registration.result import RegistrationResult, Status
from algorithms.registration.robust import OutlierConfig
from algorithms.registration.symmetric import DETECTION_TOL, SymmetricResult, localize_symmetric, pseudo_normals
from algorithms.registration.uncertainty import unit_twists

__all__ = ["HybridResult", "localize_hybrid", "envelope_distances", "LIMIT_TOL_REL", "TOLERANCE"]

#: Stopping rule ``1 - e_k / e_(k-1) < TOLERANCE`` of Algorithm 3.
TOLERANCE = 1e-10
MAX_ITERATIONS = 200
#: Points whose margin is within this fraction of the rough points' size of the minimum
#: margin at the max-min placement are reported as limiting it.
LIMIT_TOL_REL = 1e-6
#: Default stock for the inside-the-model check: this percentile of the rough points' signed
#: distances at the max-min placement (the thin end of the stock; robust to the few bad
#: points it is looking for).
STOCK_PERCENTILE = 10.0
#: Trust region: initial and smallest half-width, relative to the rough points' size.
TRUST0_REL = 0.05
TRUST_MIN_REL = 1e-12
#: Where the linearised max-min gains nothing, compass steps are tried from the trust region's
#: size down to this fraction of the rough points' size before a maximum is declared.
COMPASS_MIN_REL = 1e-4


@dataclass(frozen=True, kw_only=True, eq=False)
class HybridResult(RegistrationResult):
    """Result of :func:`localize_hybrid`: a
    :class:`algorithms.registration.result.RegistrationResult` plus

    Attributes:
        feasible: whether every rough point keeps at least its allowance at the result.
        symmetric: the Algorithm 2 result on the finished points (``g_0``, ``G_0``).
        T_max_min: (4, 4) the placement that maximises the smallest margin.
        best_min_margin_m: ``max over G_0 of min_i (d_i - delta_i)`` [m] (negative:
            infeasible by that much).
        limiting_points: indices (into the rough points) that hold the margin down at the
            max-min placement, smallest margin first.
        stock_m: (M,) signed distance of each rough point from the finished model at the
            result [m] (its stock; negative inside).
        allowance_m: (M,) the required allowances delta_i [m].
        margin_m: (M,) ``stock_m - allowance_m`` [m].
        min_allowance_m: {group: smallest stock in the group at the result} [m].
        groups: (M,) group label of each rough point.
        envelope_rmse_m: ``sqrt(e_e / M)`` at the result [m].
        group_dofs: dim G_0: the directions Algorithm 3 worked on.
        lp_solves: linear programmes solved.

    The base fields: ``T_world_workpiece`` is Algorithm 3's optimum when feasible, else the
    max-min placement (the best achievable); ``method`` is ``"algorithm3"``; ``status`` is
    INFEASIBLE when no pose gives every rough point its allowance (``message`` names the
    limiting points), else NOT_CONVERGED, POOR_FIT (the finished points' fit), UNOBSERVABLE
    (directions of ``G_0`` the rough points do not constrain either: ``free_directions``) or OK;
    ``rmse_m``, the inliers and ``sigma_m`` are those of the finished points at the result;
    ``iterations`` counts the accepted LP steps (max-min stage + Algorithm 3) and ``history``
    the envelope objective's RMS [m] at the start of Algorithm 3 and after each of its steps.
    ``determined_directions`` spans ``m_0`` (fixed by the finished points) and the directions
    of ``G_0`` the rough points fix; the rough points fix theirs through inequalities and an
    envelope objective, not a least-squares fit, so ``covariance`` is None (the finished
    points' covariance along ``m_0`` is ``symmetric.covariance``).
    """

    feasible: bool
    symmetric: SymmetricResult = field(repr=False)
    T_max_min: Pose
    best_min_margin_m: float
    limiting_points: IntArray
    stock_m: FloatArray
    allowance_m: FloatArray
    margin_m: FloatArray
    min_allowance_m: dict[str, float]
    groups: np.ndarray
    envelope_rmse_m: float
    group_dofs: int
    lp_solves: int


def envelope_distances(points_world: ArrayLike, T_world_workpiece: Pose,
                       index: MeshIndex) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Signed distances of points from a closed model and their outward gradients.

    The sign is decided with the angle-weighted pseudo-normal of the face, edge or vertex the
    closest point lies on (Baerentzen and Aanaes, 2005), which is exact for a closed,
    consistently wound mesh; the face normal alone misjudges points beside a convex edge
    (the rim of a boss, say).

    Args:
        points_world: (M, 3) [m] points, world frame.
        T_world_workpiece: (4, 4) pose of the model.
        index: MeshIndex of the closed, outward-wound model (workpiece frame).

    Returns:
        (d (M,) [m], positive outside; u (M, 3) unit outward directions (the gradient of d
        with respect to the model-frame point); model-frame points (M, 3)).
    """
    Z = transform_points(inv_pose(T_world_workpiece), np.asarray(points_world, dtype=np.float64))
    cp = index.query(Z)
    diff = Z - cp.foot
    pn = pseudo_normals(index).at(cp.face, cp.foot)
    sign = np.where(np.einsum("ij,ij->i", diff, pn) < 0.0, -1.0, 1.0)
    dist = cp.distance
    tiny = 1e-12 * index.extent
    u = np.where((dist > tiny)[:, None], sign[:, None] * diff / np.maximum(dist, tiny)[:, None], cp.normal)
    return sign * dist, u, Z


def _check_allowance(allowance: ArrayLike, m: int) -> FloatArray:
    a = np.asarray(allowance, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(m, float(a))
    if a.shape != (m,):
        raise AlgorithmError(f"allowance must be a number or ({m},) per rough point [m], got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise AlgorithmError("allowance must be finite [m]")
    bad = np.nonzero(a < 0)[0]
    if len(bad):
        rows = ", ".join(str(i) for i in bad[:10]) + (f" and {len(bad) - 10} more" if len(bad) > 10 else "")
        raise AlgorithmError(
            f"allowance must be >= 0 [m] (material left for machining); rough point(s) {rows} "
            f"have {a[bad[0]]:g}"
        )
    return a


def _check_rough_points(rough_points: ArrayLike) -> FloatArray:
    Z = np.asarray(rough_points, dtype=np.float64)
    if Z.ndim != 2 or Z.shape[1] != 3 or len(Z) < 1:
        raise AlgorithmError(f"rough points must be (M, 3) with M >= 1, got {Z.shape}")
    if not np.all(np.isfinite(Z)):
        bad = np.nonzero(~np.all(np.isfinite(Z), axis=1))[0]
        raise AlgorithmError(f"rough points must be finite; row(s) {', '.join(map(str, bad[:10]))} are not")
    return Z


def _check_groups(groups: ArrayLike | None, m: int) -> np.ndarray:
    if groups is None:
        return np.full(m, "rough")
    labels = np.asarray(groups).astype(str)
    if labels.shape != (m,):
        raise AlgorithmError(f"groups must be ({m},) labels, got shape {labels.shape}")
    return labels


def _check_options(symmetric: Any, stock_m: float | None, max_iterations: int) -> None:
    if isinstance(symmetric, str) and symmetric == "none":
        raise AlgorithmError("the hybrid problem needs the finished features' G_0: symmetric must not be 'none'")
    if stock_m is not None and not (np.isfinite(stock_m) and stock_m > 0):
        raise AlgorithmError(f"stock_m must be a positive length [m] or None, got {stock_m}")
    if int(max_iterations) < 1:
        raise AlgorithmError(f"max_iterations must be >= 1, got {max_iterations}")


@dataclass(frozen=True)
class _Placement:
    """A pose of the model and the rough points' linearisation there."""

    T: Pose  # (4, 4) T_world_workpiece
    d: FloatArray  # (M,) [m] signed distances of the rough points (positive outside)
    A: FloatArray  # (M, r) [m] derivatives of d along lambda (the basis H of g_0)


@dataclass
class _RoughProblem:
    """The rough points, their allowances and the directions of ``G_0`` Algorithm 3 moves along."""

    Z: FloatArray  # (M, 3) [m] rough points, world frame
    delta: FloatArray  # (M,) [m] allowances
    H: FloatArray  # (r, 6) basis of g_0 (unit twists, workpiece frame)
    scale: FloatArray  # (r,) [m] RMS motion of the rough points per unit lambda_j
    size: float  # [m] the rough points' size (RMS distance from their centroid)
    index: MeshIndex
    lp_solves: int = 0

    @classmethod
    def build(cls, Z: FloatArray, delta: FloatArray, H: FloatArray, T: Pose, index: MeshIndex) -> _RoughProblem:
        c = Z.mean(axis=0)
        size = float(np.sqrt(np.mean(np.sum((Z - c) ** 2, axis=1)))) or float(index.extent)
        size = max(size, 1e-3 * index.extent)
        return cls(Z, delta, H, _lambda_scale(Z, H, T), size, index)

    @property
    def r(self) -> int:
        return len(self.H)

    def at(self, T: Pose) -> _Placement:
        """The signed distances at T and their derivatives along lambda."""
        d, u, Zm = envelope_distances(self.Z, T, self.index)
        A = np.zeros((len(self.Z), self.r))
        if self.r:
            J = np.hstack([np.cross(Zm, u), u])
            A = J @ self.H.T
        return _Placement(T, d, A)

    def move(self, T: Pose, lam: FloatArray) -> _Placement:
        """The placement at ``T exp(sum lambda_j eta_j)``."""
        return self.at(T @ exp_se3(self.H.T @ lam))

    def lp(self, c: FloatArray, A_ub: FloatArray | None, b_ub: FloatArray | None,
           bounds: list[tuple[float | None, float | None]]) -> FloatArray | None:
        """scipy's HiGHS on ``min c x  s.t.  A_ub x <= b_ub``, x in bounds; None when it fails."""
        # imported here: importing the package need not load scipy.optimize
        from scipy.optimize import linprog

        self.lp_solves += 1
        res = linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
        if res.status != 0:
            return None
        return res.x


def _lambda_scale(Z: FloatArray, H: FloatArray, T: Pose) -> FloatArray:
    """(r,) [m] the RMS motion of the rough points per unit lambda_j (1 where they do not move)."""
    r = len(H)
    if not r:
        return np.zeros(0)
    motion = np.zeros(r)
    Zm = transform_points(inv_pose(T), Z)
    for j in range(r):
        mv = np.cross(H[j, :3], Zm) + H[j, 3:]
        motion[j] = np.sqrt(np.mean(np.sum(mv * mv, axis=1)))
    return np.where(motion > 0, motion, 1.0)


@dataclass(frozen=True)
class _Stage:
    """What an LP stage reached: its placement, accepted steps, whether it met its stopping
    rule, and (Algorithm 3) the envelope objective's RMS [m] at its start and after each step."""

    placement: _Placement
    iterations: int
    converged: bool
    history: tuple[float, ...] = ()


def localize_hybrid(
    finished_points: ArrayLike,
    rough_points: ArrayLike,
    mesh: Any,
    allowance: ArrayLike,
    groups: ArrayLike | None = None,
    symmetric: Any = "auto",
    init: ArrayLike | None = None,
    stock_m: float | None = None,
    sigma: float | None = None,
    outlier: OutlierConfig = "mad",
    max_iterations: int = MAX_ITERATIONS,
    tolerance: float = TOLERANCE,
    index: MeshIndex | None = None,
) -> HybridResult:
    """Hybrid localization: Algorithm 2 on the finished points, Algorithm 3 on the rough ones.

    Args:
        finished_points: (N, 3) [m] points on the finished (standard) surfaces, world frame.
        rough_points: (M, 3) [m] points on the rough (envelope) surfaces, world frame.
        mesh: the finished part's closed, outward-wound model (workpiece frame, metres).
        allowance: machining allowance delta_i >= 0 [m]: one number or (M,).
        groups: (M,) labels of the rough points (e.g. one per cast surface) for the
            per-group minimum stock; default all "rough".
        symmetric: ``G_0`` of the finished points: "auto" (detected), a feature type, a
            :class:`~algorithms.registration.symmetric.features.Feature` or a
            :class:`~algorithms.registration.symmetric.features.SymmetryGroup`.
        init: initial pose (4x4) or None (identity); also fixes the ``G_0`` start. An
            unknown pose is found first by
            :func:`algorithms.registration.global_search.global_localize`.
        stock_m: nominal stock [m] for the inside-the-model check (default: the 10th
            percentile of the rough points' stock at the max-min placement).
        sigma: noise sigma of the finished points (see :func:`localize_symmetric`).
        outlier: outlier rule of the finished points (see :func:`localize_symmetric`).
        max_iterations: cap on LP steps per stage.
        tolerance: ``delta`` of ``1 - e_k/e_(k-1) < delta``.
        index: prebuilt MeshIndex of ``mesh``.

    Returns:
        HybridResult.

    Raises:
        AlgorithmError: bad points, a negative or non-finite allowance, ``symmetric="none"``,
            rough points inside the model by more than the stock (named), bad options.
    """
    t0 = time.perf_counter()
    Z = _check_rough_points(rough_points)
    delta = _check_allowance(allowance, len(Z))
    labels = _check_groups(groups, len(Z))
    _check_options(symmetric, stock_m, max_iterations)
    T_init = as_pose(init, name="init") if init is not None else None
    index = index if index is not None else MeshIndex(mesh)
    # 1. the finished points fix the pose on SE(3)/G_0 (Algorithm 2)
    sym = localize_symmetric(finished_points, mesh, symmetric=symmetric, init=T_init, sigma=sigma,
                             outlier=outlier, index=index, discrete=False)
    # 2. the rough points place it along G_0 (the max-min, then Algorithm 3)
    problem = _RoughProblem.build(Z, delta, sym.free_directions, sym.T_world_workpiece, index)
    return _algorithm3(problem, sym, finished_points, labels, stock_m, max_iterations, tolerance, t0)


def _algorithm3(problem: _RoughProblem, sym: SymmetricResult, finished_points: ArrayLike, labels: np.ndarray,
                stock_m: float | None, max_iterations: int, tolerance: float, t0: float) -> HybridResult:
    """The best achievable minimum margin over G_0, then Algorithm 3 from there when it is
    not negative; ``t0``: the call's start (perf_counter) [s]."""
    delta = problem.delta
    max_min = _max_min(problem, problem.at(sym.T_world_workpiece), max_iterations)
    best, limiting = _limiting_points(max_min.placement, delta, problem.size)
    _refuse_points_inside(max_min.placement.d, stock_m, len(delta))
    feasible = best >= 0.0
    if feasible:
        final = _envelope(problem, max_min.placement, max_iterations, tolerance)
        summary = _feasible_summary(final, delta, best)
    else:
        final = _Stage(max_min.placement, 0, True)
        summary = _infeasible_summary(final.placement.d, delta, labels, limiting, best, sym.group.name)
    free_dirs, rough_fixed = _rough_directions(problem, final.placement.A)
    converged = bool(max_min.converged and final.converged and sym.converged)
    T_out, stock = final.placement.T, final.placement.d
    return HybridResult(
        T_world_workpiece=T_out,
        method="algorithm3",
        converged=converged,
        status=_status(feasible, converged, sym, free_dirs),
        message=summary + f"; finished features: {sym.group.describe()}",
        rmse_m=_finished_rmse(finished_points, sym, T_out, problem.index),
        iterations=max_min.iterations + final.iterations,
        history=final.history,
        inliers=sym.inliers,
        n_points_used=sym.n_points_used,
        n_outliers=sym.n_outliers,
        n_dropped_nonfinite=sym.n_dropped_nonfinite,
        sigma_m=sym.sigma_m,
        determined_directions=np.vstack([sym.determined_directions, rough_fixed]),
        covariance=None,
        free_directions=free_dirs,
        solutions=(T_out,),
        relative_eigenvalues=sym.relative_eigenvalues,
        time_s=time.perf_counter() - t0,
        poor_fit_reason=sym.poor_fit_reason,
        feasible=feasible,
        symmetric=sym,
        T_max_min=max_min.placement.T,
        best_min_margin_m=best,
        limiting_points=limiting,
        stock_m=stock,
        allowance_m=delta,
        margin_m=stock - delta,
        min_allowance_m={g: float(stock[labels == g].min()) for g in dict.fromkeys(labels.tolist())},
        groups=labels,
        envelope_rmse_m=float(np.sqrt(np.mean(stock**2))),
        group_dofs=problem.r,
        lp_solves=problem.lp_solves,
    )


def _limiting_points(placement: _Placement, delta: FloatArray, size: float) -> tuple[float, IntArray]:
    """The smallest margin [m] at the max-min placement and the points within
    LIMIT_TOL_REL x size of it, smallest margin first."""
    margin = placement.d - delta
    best = float(margin.min())
    order = np.argsort(margin, kind="stable")
    return best, order[margin[order] <= best + LIMIT_TOL_REL * size]


def _refuse_points_inside(d: FloatArray, stock_m: float | None, m: int) -> None:
    """Raise when rough points lie inside the model by more than the stock (given, or the
    STOCK_PERCENTILE of d): they are not on a rough surface."""
    s_ref = float(stock_m) if stock_m is not None else float(np.percentile(d, STOCK_PERCENTILE))
    if not s_ref > 0:
        return
    deep = np.nonzero(d < -s_ref)[0]
    if not len(deep):
        return
    deep = deep[np.argsort(d[deep])]
    names = ", ".join(f"{i} ({-d[i] * 1e3:.3g} mm inside)" for i in deep[:10])
    more = f" and {len(deep) - 10} more" if len(deep) > 10 else ""
    what = "the given stock" if stock_m is not None else f"the stock's {STOCK_PERCENTILE:g}th percentile"
    raise AlgorithmError(
        f"rough point(s) {names}{more} of {m} lie inside the finished model by more than "
        f"{what} ({s_ref * 1e3:.3g} mm) even at the best placement: they are not on a rough "
        "surface (finished-surface or fixture points?) or the model is wrong; remove them"
    )


def _infeasible_summary(d: FloatArray, delta: FloatArray, labels: np.ndarray, limiting: IntArray, best: float,
                        group_name: str) -> str:
    lim_txt = ", ".join(f"{i} ({labels[i]}: stock {d[i] * 1e3:.4g} mm, allowance {delta[i] * 1e3:.4g} mm)"
                        for i in limiting[:10])
    more = f" and {len(limiting) - 10} more" if len(limiting) > 10 else ""
    return (
        f"infeasible: no pose along G_0 ({group_name}) gives every rough point its allowance; "
        f"the best achievable minimum margin is {best * 1e3:.4g} mm (smallest stock "
        f"{d.min() * 1e3:.4g} mm), limited by point(s) {lim_txt}{more}; the pose returned is "
        "that max-min placement"
    )


def _feasible_summary(final: _Stage, delta: FloatArray, best: float) -> str:
    return (f"feasible: every rough point keeps its allowance (smallest margin "
            f"{(final.placement.d - delta).min() * 1e3:.4g} mm; best achievable {best * 1e3:.4g} mm); "
            + ("converged" if final.converged else "not converged: reached max_iterations"))


def _rough_directions(problem: _RoughProblem, A: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The directions of G_0 the rough points do not constrain (information below
    DETECTION_TOL of the strongest) and those they fix: ((k, 6), (r - k, 6)) unit twists."""
    free_dirs = np.zeros((0, 6))
    rough_fixed = np.zeros((0, 6))
    r, scale, H = problem.r, problem.scale, problem.H
    if not r:
        return free_dirs, rough_fixed
    As = A * (1.0 / scale)[None, :]
    w, V = np.linalg.eigh(As.T @ As / len(A))
    wmax = w[-1] if w[-1] > 0 else 1.0
    weak = w / wmax < DETECTION_TOL if w[-1] > 0 else np.ones(r, dtype=bool)
    if weak.any():
        coef = V[:, weak] / scale[:, None]
        free_dirs = unit_twists(coef.T @ H)
    if not weak.all():
        rough_fixed = unit_twists((V[:, ~weak] / scale[:, None]).T @ H)
    return free_dirs, rough_fixed


def _status(feasible: bool, converged: bool, sym: SymmetricResult, free_dirs: FloatArray) -> Status:
    if not feasible:
        return Status.INFEASIBLE
    if not converged:
        return Status.NOT_CONVERGED
    if sym.status is Status.POOR_FIT:
        return Status.POOR_FIT
    if len(free_dirs):
        return Status.UNOBSERVABLE
    return Status.OK


def _finished_rmse(finished_points: ArrayLike, sym: SymmetricResult, T: Pose, index: MeshIndex) -> float:
    """[m] RMS distance of the finished inliers at T (Algorithm 3 moves the pose along G_0 only)."""
    Yf = np.asarray(finished_points, dtype=np.float64)[sym.inliers]
    return float(np.sqrt(np.mean(index.query(transform_points(inv_pose(T), Yf)).distance ** 2)))


def _max_min(problem: _RoughProblem, start: _Placement, max_it: int) -> _Stage:
    """Trust-region LP steps maximising min_i (d_i - delta_i) over lambda in R^r."""
    if problem.r == 0:
        return _Stage(start, 0, True)
    size, scale, delta = problem.size, problem.scale, problem.delta
    trust = TRUST0_REL * size
    trust_min = TRUST_MIN_REL * size
    here, cur = start, float((start.d - delta).min())
    it, converged = 0, False
    for _ in range(20 * max_it):
        if it >= max_it or trust < trust_min:
            converged = trust < trust_min
            break
        step = _max_min_lp(problem, here, trust)
        if step is None:
            trust *= 0.5
            continue
        lam, pred = step
        if pred - cur <= 1e-12 * size:
            # No first-order gain: the smallest margins are flat along G_0 here (rough points
            # over finished faces parallel to its motions). They change only where a point's
            # nearest finished face does, which the linearisation cannot see, so a maximum is
            # only declared once no compass step (+-trust along each direction) gains either.
            better = _compass_step(problem, here.T, cur, trust)
            if better is not None:
                here, cur = better, float((better.d - delta).min())
                it += 1
            elif trust <= COMPASS_MIN_REL * size:
                converged = True
                break
            else:
                trust *= 0.5
            continue
        new = problem.move(here.T, lam)
        new_min = float((new.d - delta).min())
        ratio = (new_min - cur) / (pred - cur)
        if ratio >= 0.1:
            here, cur = new, new_min
            it += 1
            if ratio > 0.75 and np.max(np.abs(lam) * scale) > 0.99 * trust:
                trust *= 2.0
        else:
            trust = 0.5 * max(trust if ratio < 0 else np.max(np.abs(lam) * scale), trust_min)
    return _Stage(here, it, converged)


def _max_min_lp(problem: _RoughProblem, here: _Placement, trust: float) -> tuple[FloatArray, float] | None:
    """``max t  s.t.  A lambda + t <= d - delta,  |lambda_j| scale_j <= trust``: (lambda, the
    predicted min margin t), or None when the LP fails. Rows that cannot be the smallest
    anywhere in the box are left out (exactly)."""
    r, scale = problem.r, problem.scale
    cost = np.zeros(r + 1)
    cost[-1] = -1.0
    bounds: list[tuple[float | None, float | None]] = [(-trust / s, trust / s) for s in scale]
    bounds.append((None, None))
    margin = here.d - problem.delta
    reach = np.abs(here.A) @ (trust / scale)
    rows = margin - reach <= np.min(margin + reach)
    x = problem.lp(cost, np.hstack([here.A[rows], np.ones((int(rows.sum()), 1))]), margin[rows], bounds)
    if x is None:
        return None
    return x[:r], x[-1]


def _compass_step(problem: _RoughProblem, T: Pose, cur: float, trust: float) -> _Placement | None:
    """The best of the 2r moves of +-trust [m of point motion] along each direction of G_0, if
    it raises the smallest margin above ``cur``, else None."""
    best: _Placement | None = None
    best_min = -np.inf
    for j in range(problem.r):
        for sign in (1.0, -1.0):
            new = problem.at(T @ exp_se3(problem.H[j] * (sign * trust / problem.scale[j])))
            new_min = float((new.d - problem.delta).min())
            if new_min > cur + 1e-12 * problem.size and (best is None or new_min > best_min):
                best, best_min = new, new_min
    return best


def _envelope(problem: _RoughProblem, start: _Placement, max_it: int, tol: float) -> _Stage:
    """Algorithm 3: LP steps on <de_e, lambda> under the linearised allowances."""
    here = start
    e = float(np.sum(here.d * here.d))
    history = [float(np.sqrt(e / len(here.d)))]
    if problem.r == 0:
        return _Stage(here, 0, True, tuple(history))
    size, scale, delta = problem.size, problem.scale, problem.delta
    trust = TRUST0_REL * size
    trust_min = TRUST_MIN_REL * size
    it, converged = 0, False
    for _ in range(20 * max_it):
        if it >= max_it:
            break
        if trust < trust_min:
            converged = True
            break
        grad = -2.0 * here.A.T @ here.d  # d e_e / d lambda
        lam = _envelope_lp(problem, here, grad, trust)
        if lam is None:
            trust *= 0.5
            continue
        Ap = here.A @ lam
        denom = float(Ap @ Ap)
        if denom <= 0 or float(grad @ lam) >= 0:
            converged = True
            break
        alpha = min(1.0, float(here.d @ Ap) / denom)  # exact line search on the linearised e_e
        step = alpha * lam
        new = problem.move(here.T, step)
        e_new = float(np.sum(new.d * new.d))
        if not (e_new < e and float((new.d - delta).min()) >= 0.0):
            trust *= 0.5
            continue
        rel = 1.0 - e_new / e
        here, e = new, e_new
        it += 1
        history.append(float(np.sqrt(e / len(here.d))))
        # the box follows the step length (a vertex step in a large box zig-zags)
        trust = max(2.0 * float(np.max(np.abs(step) * scale)), trust_min)
        if rel < tol:
            converged = True
            break
    return _Stage(here, it, converged, tuple(history))


def _envelope_lp(problem: _RoughProblem, here: _Placement, grad: FloatArray, trust: float) -> FloatArray | None:
    """``min <grad, lambda>  s.t.  d - A lambda >= delta`` in the box ``|lambda_j| scale_j <=
    trust``; rows that no step in the box can violate are left out (exactly)."""
    bounds: list[tuple[float | None, float | None]] = [(-trust / s, trust / s) for s in problem.scale]
    margin = here.d - problem.delta
    rows = np.abs(here.A) @ (trust / problem.scale) >= margin
    if rows.any():
        return problem.lp(grad, here.A[rows], margin[rows], bounds)
    return problem.lp(grad, None, None, bounds)
