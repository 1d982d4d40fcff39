"""Uncertainty of a workpiece localization: Fisher information, Cramer-Rao bound,
observability, and document 000's accuracy metrics.

Conventions (shared with :mod:`algorithms.registration.local`):

* The pose is ``T_world_workpiece`` (maps workpiece/model coordinates to world coordinates).
* A pose error is the twist ``xi = [omega, v]`` (angular part first, radians and metres) of
  the *right* perturbation in the **workpiece frame**: ``T_est = T_true @ exp_se3(xi)``, i.e.
  ``xi = log_se3(inv(T_true) @ T_est)`` (:func:`pose_error_twist`). Covariances are of this
  twist, 6x6, order ``[omega_x, omega_y, omega_z, v_x, v_y, v_z]``.
* Measurement model: a measured point is the model point ``p_i`` (workpiece frame) moved
  along its unit surface normal ``n_i`` by Gaussian noise ``N(0, sigma^2)``, then mapped to
  the world by the true pose. The point-to-surface residual then changes by
  ``-(p_i x n_i) . omega - n_i . v`` under a perturbation ``xi``, so each point contributes
  the row ``g_i = [p_i x n_i, n_i]`` and the Fisher information is
  ``F = (1 / sigma^2) sum g_i g_i^T``. The Cramer-Rao lower bound on the covariance of any
  unbiased estimate is ``F^-1 = sigma^2 (sum g_i g_i^T)^-1``; least squares on the
  point-to-surface distance attains it asymptotically, so the same expression, evaluated at
  the estimate with the given or estimated sigma, is the covariance reported with a result.

Observability: the information is analysed in consistent units. Twists are taken about the
centroid ``c`` of the points and the angular part is multiplied by the characteristic length
``L = sqrt(mean |p_i - c|^2)`` (a rotation ``omega`` moves a typical point by about
``L |omega|``), so every coordinate is a displacement in metres. The eigenvalues of
``H = (1/N) sum h_i h_i^T`` with ``h_i = [(p_i - c) x n_i / L, n_i]`` are then dimensionless
(between 0 and about 1: the mean squared normal displacement per unit motion). A direction
is *weakly constrained* when its eigenvalue is below ``OBSERVABILITY_TOL`` times the largest;
the pose is *observable* when no direction is weak. Points on one plane give three zero
eigenvalues, on a cylinder two, on a sphere three (exactly zero when the normals are those of
the ideal surface; use smooth normals, :meth:`MeshIndex.smooth_normals`, on tessellated
models so facets do not fake information).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray, Pose
from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import exp_se3, inv_pose, log_se3, rotation_error_rad, translation_error_m

if TYPE_CHECKING:  # for the annotations only: this module needs no mesh index at run time
    from algorithms.geometry.mesh_index import MeshIndex

__all__ = [
    "OBSERVABILITY_TOL",
    "Observability",
    "information_rows",
    "fisher_information",
    "crlb",
    "cross_into",
    "observability",
    "estimate_sigma",
    "pose_error_twist",
    "sym_inverse",
    "unit_twists",
    "whitened_error",
    "rotation_error_rad",
    "translation_error_m",
]

#: A direction whose scaled information eigenvalue is below this fraction of the strongest
#: is weakly constrained (its standard deviation is more than 1/sqrt(tol) = 100 times that
#: of the best-constrained direction, in the scaled units above).
OBSERVABILITY_TOL = 1e-4


@dataclass(frozen=True)
class Observability:
    """Which rigid motions a point set constrains.

    Attributes:
        observable: True when all six directions are constrained (no weak direction).
        relative_eigenvalues: (6,) eigenvalues of the scaled information, ascending, divided
            by the largest (1.0 for the strongest direction).
        eigenvalues: (6,) the scaled information eigenvalues themselves, ascending.
        weak_directions: (k, 6) twists ``[omega, v]`` about the workpiece origin (workpiece
            frame) spanning the weakly constrained motions; each has unit norm in the scaled
            units (``L^2 |omega|^2 + |v_c|^2 = 1`` with ``v_c`` the velocity of the centroid).
        determined_directions: (6 - k, 6) twists spanning the other eigenvectors, the
            directions the points fix (same frame and scaling).
        characteristic_length_m: L, the RMS distance of the points from their centroid [m].
        centroid: (3,) [m] centroid of the points (workpiece frame).
        tol: the tolerance used.
    """

    observable: bool
    relative_eigenvalues: FloatArray
    eigenvalues: FloatArray
    weak_directions: FloatArray
    determined_directions: FloatArray
    characteristic_length_m: float
    centroid: FloatArray
    tol: float


def _check(points: ArrayLike, normals: ArrayLike) -> tuple[FloatArray, FloatArray]:
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
        raise AlgorithmError(f"points and normals must both be (N, 3), got {p.shape} and {n.shape}")
    if len(p) < 6:
        raise AlgorithmError(f"at least 6 points are needed to fix 6 DOF, got {len(p)}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n))):
        raise AlgorithmError("points and normals must be finite")
    return p, n


def information_rows(points: ArrayLike, normals: ArrayLike) -> FloatArray:
    """Rows ``[p_i x n_i, n_i]`` (N, 6) of the point-to-plane Jacobian (workpiece frame).

    Args:
        points: (N, 3) [m] model points (feet) in the workpiece frame.
        normals: (N, 3) unit surface normals there.
    """
    p, n = _check(points, normals)
    return np.hstack([np.cross(p, n), n])


def fisher_information(points: ArrayLike, normals: ArrayLike, sigma: float) -> FloatArray:
    """Fisher information (6, 6) of the twist ``[omega, v]`` for normal noise ``sigma`` [m]."""
    if not (np.isfinite(sigma) and sigma > 0):
        raise AlgorithmError(f"sigma must be a positive finite length [m], got {sigma}")
    J = information_rows(points, normals)
    return np.einsum("ij,ik->jk", J, J) / sigma**2


def observability(points: ArrayLike, normals: ArrayLike, tol: float = OBSERVABILITY_TOL) -> Observability:
    """Eigen-analysis of the information in consistent units (see the module docstring).

    Args:
        points: (N, 3) [m] model points in the workpiece frame.
        normals: (N, 3) unit normals (preferably of the ideal surface, not facets).
        tol: relative eigenvalue below which a direction is weak.
    """
    p, n = _check(points, normals)
    c = p.mean(axis=0)
    d = p - c
    L = float(np.sqrt(np.mean(np.einsum("ij,ij->i", d, d))))
    if not L > 0:
        L = 1.0
    H = np.empty((len(p), 6))
    cross_into(d, n, H[:, :3])
    H[:, :3] /= L
    H[:, 3:] = n
    M = np.einsum("ij,ik->jk", H, H) / len(p)  # no BLAS threads (see localization)
    w, V = np.linalg.eigh(M)
    w = np.clip(w, 0.0, None)
    wmax = w[-1] if w[-1] > 0 else 1.0
    rel = w / wmax
    weak = rel < tol

    def twists(S: FloatArray) -> FloatArray:
        """(k, 6) scaled twists about the centroid [L omega, v_c] -> about the origin."""
        out = np.empty_like(S)
        out[:, :3] = S[:, :3] / L
        # velocity of the workpiece origin: v_c = v + omega x c
        cross_into(out[:, :3], np.broadcast_to(c, (len(S), 3)), out[:, 3:])
        out[:, 3:] = S[:, 3:] - out[:, 3:]
        return out

    return Observability(
        observable=not bool(weak.any()),
        relative_eigenvalues=rel,
        eigenvalues=w,
        weak_directions=twists(V[:, weak].T),
        determined_directions=twists(V[:, ~weak].T),
        characteristic_length_m=L,
        centroid=c,
        tol=float(tol),
    )


def cross_into(a: FloatArray, b: FloatArray, out: FloatArray) -> None:
    """``out[:, :3] = a x b`` row-wise for (N, 3) rows, written in place: np.cross's arithmetic,
    without its per-call overhead (the local fit's point-to-plane rows use it at every iteration)."""
    ax, ay, az = a[:, 0], a[:, 1], a[:, 2]
    bx, by, bz = b[:, 0], b[:, 1], b[:, 2]
    out[:, 0] = ay * bz - az * by
    out[:, 1] = az * bx - ax * bz
    out[:, 2] = ax * by - ay * bx


def crlb(points: ArrayLike, normals: ArrayLike, sigma: float, tol: float = OBSERVABILITY_TOL) -> FloatArray:
    """Cramer-Rao lower bound (6, 6) on the covariance of the pose twist ``[omega, v]``.

    ``sigma^2 (sum g_i g_i^T)^-1`` with ``g_i = [p_i x n_i, n_i]``, for Gaussian noise of
    standard deviation ``sigma`` [m] along the normals; units rad^2, rad m, m^2.

    Raises:
        AlgorithmError: when the points do not fix all six DOF (the bound is infinite).
    """
    if not (np.isfinite(sigma) and sigma > 0):
        raise AlgorithmError(f"sigma must be a positive finite length [m], got {sigma}")
    obs = observability(points, normals, tol)
    if not obs.observable:
        raise AlgorithmError(
            f"the points do not fix all six DOF ({len(obs.weak_directions)} weakly constrained "
            "direction(s)): the Cramer-Rao bound is infinite"
        )
    J = information_rows(points, normals)
    return sym_inverse(np.einsum("ij,ik->jk", J, J)) * sigma**2


def sym_inverse(A: FloatArray) -> FloatArray:
    """Inverse of a symmetric positive-definite matrix, scaled for conditioning."""
    s = 1.0 / np.sqrt(np.diag(A))
    B = A * s[:, None] * s[None, :]
    Binv = np.linalg.inv(B)
    out = Binv * s[:, None] * s[None, :]
    return 0.5 * (out + out.T)


def estimate_sigma(residuals: ArrayLike, n_params: int = 6) -> float:
    """Noise estimate [m] from point-to-surface residuals: ``sqrt(sum r^2 / (N - n_params))``."""
    r = np.asarray(residuals, dtype=np.float64).reshape(-1)
    dof = len(r) - n_params
    if dof <= 0:
        raise AlgorithmError(f"need more than {n_params} residuals to estimate sigma, got {len(r)}")
    return float(np.sqrt(np.sum(r * r) / dof))


def pose_error_twist(T_est: ArrayLike, T_true: ArrayLike) -> FloatArray:
    """The error twist ``[omega, v]`` (workpiece frame) with ``T_est = T_true exp(xi)``."""
    return log_se3(inv_pose(np.asarray(T_true, dtype=np.float64)) @ np.asarray(T_est, dtype=np.float64))


def whitened_error(xi: ArrayLike, covariance: ArrayLike) -> FloatArray:
    """Squared Mahalanobis norms ``xi^T C^-1 xi`` of error twists (M, 6) (or one (6,)).

    For an efficient estimator with covariance ``C`` their mean is 6 (chi-square, 6 DOF), so
    ``sqrt(mean / 6)`` is the RMS pose error in units of the bound: 1.0 attains it.
    """
    X = np.atleast_2d(np.asarray(xi, dtype=np.float64))
    Cinv = sym_inverse(np.asarray(covariance, dtype=np.float64))
    return np.einsum("ij,jk,ik->i", X, Cinv, X)


def unit_twists(W: ArrayLike) -> FloatArray:
    """Twists (k, 6) scaled to ``|omega| = 1`` (rotations, screws) or ``|v| = 1`` (pure
    translations): the unit rows the results report."""
    W = np.asarray(W, dtype=np.float64).reshape(-1, 6)
    out = W.copy()
    for i, x in enumerate(W):
        nw = np.linalg.norm(x[:3])
        nv = float(np.linalg.norm(x[3:]))
        out[i] = x / (nw if nw > 1e-9 * max(nv, 1e-300) else nv)
    return out


def invariant_points(index: MeshIndex, points: ArrayLike, twists: ArrayLike, step_rad: float = 0.05,
                     step_m: float = 0.005, tol_fraction: float = 0.1) -> BoolArray:
    """(N,) bool: the model points that stay on the model when moved along every twist.

    Each point is moved by a finite step both ways along each twist (``step_rad`` about a
    rotation, ``step_m`` along a translation: the prior uncertainty along a free direction,
    which the points cannot reduce) and must land within ``tol_fraction`` of its own
    displacement of the model (a tessellated curved surface is off by its chord error).

    Args:
        index: MeshIndex of the model (workpiece frame).
        points: (N, 3) points on the model [m].
        twists: (k, 6) unit twists ``[omega, v]`` in the workpiece frame.
    """
    P = np.asarray(points, dtype=np.float64)
    keep = np.ones(len(P), dtype=bool)
    for w in np.asarray(twists, dtype=np.float64).reshape(-1, 6):
        s = step_rad if np.linalg.norm(w[:3]) > 1e-9 else step_m
        for sign in (1.0, -1.0):
            T = exp_se3(sign * s * w)
            moved = P @ T[:3, :3].T + T[:3, 3]
            shift = np.linalg.norm(moved - P, axis=1)
            keep &= index.query(moved).distance <= tol_fraction * shift + 1e-9
    return keep


def part_symmetry_directions(index: MeshIndex, twists: ArrayLike, **kw: float) -> BoolArray:
    """(k,) bool: whether each free direction is a symmetry of the whole CAD model.

    The points leave a direction free either because the part is symmetric that way (a
    sphere turns onto itself) or because they miss the surfaces that would fix it (only the
    top face of a block was measured): only in the first case do the model's vertices and
    face centres stay on the model when moved along it (:func:`invariant_points`).
    """
    V, F = index.vertices, index.faces
    samples = np.vstack([V, V[F].mean(axis=1)])
    return np.array([bool(np.all(invariant_points(index, samples, w, **kw)))
                     for w in np.asarray(twists, dtype=np.float64).reshape(-1, 6)], dtype=bool)


def systematic_covariance(points: ArrayLike, normals: ArrayLike, directions: ArrayLike, bias_basis: ArrayLike,
                          bias_std: ArrayLike) -> FloatArray:
    """Covariance of the pose error that a smooth systematic error of the points causes.

    The error of point ``i`` along its normal is ``e_i = sum_k c_k phi_k(i)`` with independent
    coefficients of standard deviation ``bias_std[k]`` (a Type B evaluation, GUM 4.3: e.g. a
    sensor's linearity curve, bounded but unknown, expanded over smooth functions of the
    measured distance). Each basis function moves the least-squares pose by
    ``g_k = (A^T A)^-1 A^T phi_k`` with ``A`` the information rows along ``directions``, so
    the covariance is ``sum_k bias_std[k]^2 g_k g_k^T``. Unlike white noise, this does not
    shrink with the number of points.

    Args:
        points: (N, 3) model feet (workpiece frame).
        normals: (N, 3) unit normals at the feet (workpiece frame).
        directions: (q, 6) twists the covariance is expressed along.
        bias_basis: (N, K) the basis functions' values at the points.
        bias_std: (K,) their coefficients' standard deviations [m].
    """
    G = systematic_response(points, normals, directions, bias_basis)
    s = np.asarray(bias_std, dtype=np.float64)
    return (G * s**2) @ G.T


def systematic_response(points: ArrayLike, normals: ArrayLike, directions: ArrayLike,
                        bias_basis: ArrayLike) -> FloatArray:
    """(q, K) how the least-squares pose moves along ``directions`` per unit coefficient of each
    basis function of a systematic error along the normals: ``(A^T A)^-1 A^T phi_k``
    (:func:`systematic_covariance`)."""
    D = np.asarray(directions, dtype=np.float64).reshape(-1, 6)
    A = information_rows(points, normals) @ D.T
    return np.asarray(np.linalg.lstsq(A, np.asarray(bias_basis, dtype=np.float64), rcond=None)[0], dtype=np.float64)


def nearest_along_free(T_world_workpiece: ArrayLike, free_directions: ArrayLike, T_reference: ArrayLike,
                       iterations: int = 3) -> Pose:
    """The pose reached from ``T_world_workpiece`` along its free directions that is nearest
    ``T_reference`` (e.g. the nominal pose).

    The points do not tell apart poses that differ along free directions (a bore turned about
    its axis fits the same), so the estimate may sit anywhere along them; the prior (where the
    part was meant to be) is the honest choice there, and the determined directions are not
    touched. Each iteration writes the remaining error twist ``log(T^-1 T_ref)`` (workpiece
    frame) over the free and the other directions and moves along the free part.
    """
    T = np.asarray(T_world_workpiece, dtype=np.float64).copy()
    F = np.asarray(free_directions, dtype=np.float64).reshape(-1, 6)
    if len(F) == 0:
        return T
    # a basis of the complement of the free twists, so the split is a proper decomposition
    _, _, Vt = np.linalg.svd(F)
    basis = np.vstack([F, Vt[len(F):]])
    for _ in range(iterations):
        xi = log_se3(inv_pose(T) @ np.asarray(T_reference, dtype=np.float64))
        coef = np.linalg.solve(basis.T, xi)
        T = T @ exp_se3(F.T @ coef[: len(F)])
    return T
