"""Document 000 (Liu, Li, Dai 2001), section 8, Algorithm 5: the multistart global search.

Start poses ``g0 = (p0, R0)`` from a table of orientations, position from the centroids
(``p0 = mean(y) - R0 c_model``; the document's ``p0 = mean(y)`` with the model frame at its
centroid). From every start run the local Algorithm 1 (foot points, then a point-to-plane
pose update) with the three stopping tests of step 5::

    1 - eps_k / eps_(k-1) < delta1   and   eps_k < delta2   and   ||xi|| < delta3

When the first holds but not the second (a local minimum), step 6 adds a perturbation
``delta_b`` and descends again; when the perturbation has grown past the convergence radius
the start is abandoned ("go to the next initial pose").

Readings and choices:

* The start table. The original gives "alpha0, beta0 in {30, -30, 90, -90, 150, -150}
  degrees -> 36 groups g0(p0, alpha0, beta0, gamma0)", while its prose says alpha0 and
  gamma0 vary at 30 degree granularity and beta0 is assumed known within 45 degrees. Read as
  printed (``R0 = Rz(alpha0) Ry(beta0)``, gamma0 = 0; ``start_table="liu2001"``), the 36
  rotations leave parts of SO(3) far more than 45 degrees from every start (the measured gap
  is in ``benchmarks/results_localization.md``): they do not honour the document's own
  premise that Algorithm 1 converges from within 45 degrees. The default ``"icosahedral"``
  uses the 60 rotations of the icosahedral group instead, whose covering radius is 44.3
  degrees: every orientation is within 45 degrees of a start, which is what the document's
  argument needs. A ``(K, 3, 3)`` array of rotations may be passed too. When
  ``noise_sigma_m`` is known and no icosahedral start passes the tests, a second round runs
  from the same 60 rotations turned by a fixed offset (120 starts together: no orientation
  further than about 40 degrees from one; see ``benchmarks/results_global_search.md``).
* ``eps`` is the document's ``sum ||g^-1 y_i - x_i||^2`` (squared distance to the foot).
  ``delta2`` is set from the noise: ``delta2 = N (2 sigma_eff)^2`` (in the coarse phase
  ``N (2 sigma_eff + 3 e_field)^2``, e_field the field's RMS error on exact points) with
  ``sigma_eff = sqrt(sigma^2 + model_error^2)``, i.e. the RMS residual must be below twice
  the expected noise (for N >= 25 Gaussian residuals the RMS exceeds 2 sigma with
  negligible probability). ``delta1 = 1e-3``, ``delta3 = 1e-4`` (twist norm with the
  translation divided by the characteristic length L of the points).
* ``delta_b``: a rotation of 15, 30 then 45 degrees about a random axis through the
  points' centroid plus a translation of ``L * delta_b / (2 pi)`` in a random direction;
  beyond 45 degrees (the convergence radius) the start is abandoned.
* Speed: all starts run at once, batched (:func:`descend`), on the coarse nearest-surface
  field of :mod:`.fields`; the best distinct minima are then refined with the exact closest
  points (:mod:`.verify`) and the best is polished with the library's local method
  (:func:`algorithms.registration.local.localize`).
* The document stops at the first start that passes all tests. Here every start is run
  (unless ``stop_at_first=True``), because hypotheses are verified (:mod:`.verify`); but once
  one start has passed, the others are no longer perturbed out of their local minima (step 6
  is for a search that has not reached the noise level; each start's own minimum still goes
  to the verification).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.errors import AlgorithmError
from algorithms.registration.global_search.fields import ExactOracle, sq_dist
from algorithms.registration.global_search.poses import apply_model_motion, make_poses, rotvec_to_matrix, to_model

__all__ = [
    "CONVERGENCE_RADIUS_DEG",
    "FIELD_FLOOR_FACTOR",
    "LIU2001_START_ANGLES_DEG",
    "LaneResult",
    "MULTISTART_DELTA1",
    "MULTISTART_DELTA3",
    "NOISE_ACCEPT_FACTOR",
    "PERTURBATION_STEPS_DEG",
    "SECOND_ROUND_ROTVEC",
    "descend",
    "farthest_point_subset",
    "model_centroid",
    "multistart_stage",
    "orientation_table",
]

#: alpha0, beta0 of the printed start table [deg].
LIU2001_START_ANGLES_DEG = (30.0, -30.0, 90.0, -90.0, 150.0, -150.0)
#: The document's convergence radius of Algorithm 1 [deg].
CONVERGENCE_RADIUS_DEG = 45.0
MULTISTART_DELTA1 = 1e-3
MULTISTART_DELTA3 = 1e-4
#: delta2 = N (NOISE_ACCEPT_FACTOR * sigma_eff)^2.
NOISE_ACCEPT_FACTOR = 2.0
#: The coarse phase's delta2 allows this many times the field's RMS error on exact points.
FIELD_FLOOR_FACTOR = 3.0
#: Second-round offset: when no start of the icosahedral table passes Algorithm 5's tests, the
#: table right-multiplied by this rotation is tried too (the 120 rotations together leave no
#: orientation more than about 40 degrees from a start; chosen among 30 random offsets).
SECOND_ROUND_ROTVEC = (2.32799788, -1.06526766, 0.48524283)
#: Perturbation sizes delta_b [deg]; past the last one the start is abandoned.
PERTURBATION_STEPS_DEG = (15.0, 30.0, 45.0)


def orientation_table(name="icosahedral") -> np.ndarray:
    """Start orientations for Algorithm 5: (K, 3, 3) rotation matrices.

    Args:
        name: ``"liu2001"`` (36: ``Rz(alpha0) Ry(beta0)``, alpha0, beta0 in
            {+-30, +-90, +-150} deg, the table as printed in document 000),
            ``"icosahedral"`` (60: the rotation group of the icosahedron, every rotation within
            44.3 deg of one of them), or a (K, 3, 3) array of rotations.
    """
    if isinstance(name, str):
        if name == "liu2001":
            a = np.radians(LIU2001_START_ANGLES_DEG)
            ang = np.array([[al, be] for al in a for be in a])
            return Rotation.from_euler("ZY", ang).as_matrix()
        if name == "icosahedral":
            return Rotation.create_group("I").as_matrix()
        raise AlgorithmError(f"start_table must be 'liu2001', 'icosahedral' or a (K, 3, 3) array, got {name!r}")
    R = np.asarray(name, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or len(R) < 1:
        raise AlgorithmError(f"start_table array must be (K, 3, 3), got {R.shape}")
    err = np.abs(np.einsum("kji,kjl->kil", R, R) - np.eye(3)).max()
    if err > 1e-6 or np.any(np.linalg.det(R) < 0):
        raise AlgorithmError("start_table rotations must be proper orthonormal matrices")
    return R



@dataclass
class LaneResult:
    T: np.ndarray  # (B, 4, 4) best pose seen per lane
    eps: np.ndarray  # (B,) its eps (sum of squared distances)
    accepted: np.ndarray  # (B,) passed all three tests
    iterations: np.ndarray  # (B,)
    perturbations: np.ndarray  # (B,)
    faces: np.ndarray | None  # (B, N) last feet faces (exact oracle) for hints


def descend(
    oracle,
    y: np.ndarray,
    T0: np.ndarray,
    *,
    L: float,
    delta1: float,
    delta2: float,
    delta3: float,
    max_iter_per_descent: int,
    rng: np.random.Generator | None,
    perturbation_deg=PERTURBATION_STEPS_DEG,
    stop_at_first: bool = False,
    max_step_rad: float = 0.5,
) -> LaneResult:
    """Algorithm 1 from B start poses at once (point-to-plane Gauss-Newton about the centroid
    of the points, document 001's variable iteration centre), stopped by Algorithm 5's tests,
    with its perturbations when ``rng`` is given and ``delta2`` is finite."""
    B, N = len(T0), len(y)
    T = T0.copy()
    best_T = T0.copy()
    best_eps = np.full(B, np.inf)
    eps_prev = np.full(B, np.inf)
    active = np.ones(B, dtype=bool)
    accepted = np.zeros(B, dtype=bool)
    its = np.zeros(B, dtype=np.int64)
    desc_its = np.zeros(B, dtype=np.int64)
    level = np.zeros(B, dtype=np.int64)
    hints = None
    faces_out = np.full((B, N), -1, dtype=np.int64) if isinstance(oracle, ExactOracle) else None
    do_perturb = rng is not None and np.isfinite(delta2) and len(perturbation_deg) > 0
    ttol = oracle.tangent_tol
    while active.any():
        a = np.nonzero(active)[0]
        x = to_model(T[a], y)  # (A, N, 3)
        if faces_out is not None:
            hints = faces_out[a].reshape(-1)
            hints = None if (hints < 0).any() else hints
        foot, normal, face = oracle.closest(x.reshape(-1, 3), hint=hints)
        foot = foot.reshape(x.shape)
        normal = normal.reshape(x.shape)
        if faces_out is not None and face is not None:
            faces_out[a] = np.asarray(face).reshape(len(a), N)
        d2, r = sq_dist(x, foot, normal, ttol)
        eps = d2.sum(axis=1)
        better = eps < best_eps[a]
        best_eps[a[better]] = eps[better]
        best_T[a[better]] = T[a[better]]
        # Gauss-Newton step on the point-to-plane residual, about the centroid c
        c = x.mean(axis=1)
        xc = x - c[:, None, :]
        # J = [xc x n, n], the cross product written out (np.cross's own arithmetic, bit for bit; 1.7x
        # faster than np.cross + concatenate at 60 lanes x 150 points)
        J = np.empty(xc.shape[:2] + (6,))
        J[..., 0] = xc[..., 1] * normal[..., 2] - xc[..., 2] * normal[..., 1]
        J[..., 1] = xc[..., 2] * normal[..., 0] - xc[..., 0] * normal[..., 2]
        J[..., 2] = xc[..., 0] * normal[..., 1] - xc[..., 1] * normal[..., 0]
        J[..., 3:] = normal
        Jt = J.transpose(0, 2, 1)
        H = Jt @ J
        g = (Jt @ r[:, :, None])[:, :, 0]
        tr = np.trace(H, axis1=1, axis2=2)
        H = H + (1e-9 * tr + 1e-300)[:, None, None] * np.eye(6)[None]
        delta = -np.linalg.solve(H, g[:, :, None])[:, :, 0]
        th = np.linalg.norm(delta[:, :3], axis=1)
        scale = np.minimum(1.0, max_step_rad / np.maximum(th, 1e-300))
        delta *= scale[:, None]
        xi_norm = np.sqrt(np.sum(delta[:, :3] ** 2, axis=1) + np.sum((delta[:, 3:] / L) ** 2, axis=1))
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.where(np.isfinite(eps_prev[a]), 1.0 - eps / eps_prev[a], np.inf)
        its[a] += 1
        desc_its[a] += 1
        exhausted = desc_its[a] >= max_iter_per_descent
        stalled = (rel < delta1) | exhausted
        small_eps = eps < delta2
        done_ok = stalled & small_eps & (xi_norm < delta3)
        local_min = stalled & ~small_eps
        # lanes that pass every test stop here (their pose is the one just evaluated)
        accepted[a[done_ok]] = True
        best_T[a[done_ok]] = T[a[done_ok]]
        best_eps[a[done_ok]] = eps[done_ok]
        active[a[done_ok]] = False
        # out of iterations with a small residual but still moving: stop, not accepted
        active[a[exhausted & small_eps & ~done_ok]] = False
        # step 6: perturb out of a local minimum, or give the start up
        # once a start has passed every test, the others are not perturbed out of their local
        # minima: each has given its minimum to the verification, and the perturbations are for
        # a search that has not yet reached the noise level
        if do_perturb and rng is not None and not accepted.any():
            pm = a[local_min]
            if len(pm):
                give_up = level[pm] >= len(perturbation_deg)
                active[pm[give_up]] = False
                pm = pm[~give_up]
                if len(pm):
                    ang = np.radians(np.asarray(perturbation_deg)[level[pm]])
                    axis = rng.normal(size=(len(pm), 3))
                    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
                    tdir = rng.normal(size=(len(pm), 3))
                    tdir /= np.linalg.norm(tdir, axis=1, keepdims=True)
                    # perturb the best pose of this descent, not the last iterate
                    cpm = to_model(best_T[pm], y).mean(axis=1)
                    T[pm] = apply_model_motion(
                        best_T[pm], rotvec_to_matrix(axis * ang[:, None]), cpm, tdir * (L * ang / (2 * np.pi))[:, None]
                    )
                    level[pm] += 1
                    eps_prev[pm] = np.inf
                    desc_its[pm] = 0
                    if faces_out is not None:
                        faces_out[pm] = -1
        else:
            active[a[local_min]] = False
        # everyone still active and not just perturbed takes the step
        step = np.zeros(len(a), dtype=bool)
        step[:] = active[a]
        if do_perturb:
            step &= ~local_min
        sa = a[step]
        if len(sa):
            Rd = rotvec_to_matrix(delta[step, :3])
            T[sa] = apply_model_motion(T[sa], Rd, c[step], delta[step, 3:])
            eps_prev[sa] = eps[step]
        if stop_at_first and accepted.any():
            break
    return LaneResult(best_T, best_eps, accepted, its, level, faces_out)



def farthest_point_subset(y: np.ndarray, n: int) -> np.ndarray:
    """Indices of n points spread over the cloud (greedy farthest-point sampling)."""
    if n >= len(y):
        return np.arange(len(y))
    c = y.mean(axis=0)
    first = int(np.argmax(np.einsum("ij,ij->i", y - c, y - c)))
    idx = np.empty(n, dtype=np.int64)
    idx[0] = first
    d = np.einsum("ij,ij->i", y - y[first], y - y[first])
    for i in range(1, n):
        j = int(np.argmax(d))
        idx[i] = j
        e = y - y[j]
        np.minimum(d, np.einsum("ij,ij->i", e, e), out=d)
    return idx


def model_centroid(mesh) -> np.ndarray:
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    area = np.asarray(mesh.area_faces, dtype=np.float64)
    if area.sum() <= 0:
        return tri.reshape(-1, 3).mean(axis=0)
    return (tri.mean(axis=1) * area[:, None]).sum(axis=0) / area.sum()



def start_poses(R0: np.ndarray, y: np.ndarray, c_model: np.ndarray) -> np.ndarray:
    p0 = y.mean(axis=0)[None, :] - np.einsum("kij,j->ki", R0, c_model)
    return make_poses(R0, p0)


def multistart_coarse(field, y_c, R0, c_model, L, delta2_field, rng, stop_at_first):
    T0 = start_poses(R0, y_c, c_model)
    return descend(
        field,
        y_c,
        T0,
        L=L,
        delta1=MULTISTART_DELTA1,
        delta2=delta2_field,
        delta3=MULTISTART_DELTA3,
        max_iter_per_descent=40,
        rng=rng,
        stop_at_first=stop_at_first,
    )



def multistart_stage(field, y_c, R0, start_table, c_model, L, delta2_field, rng, stop_at_first: bool,
                     sigma_known: bool) -> tuple[LaneResult, int, bool]:
    """Algorithm 5's coarse phase from every start of ``R0`` (and the second round).

    Returns:
        (the lanes, the number of starts run, whether the second round ran).
    """
    lanes = multistart_coarse(field, y_c, R0, c_model, L, delta2_field, rng, stop_at_first)
    second_round = False
    if (
        sigma_known
        and not lanes.accepted.any()
        and isinstance(start_table, str)
        and start_table == "icosahedral"
    ):
        # no start reached the noise level: try the offset table as well (more initial poses)
        R1 = R0 @ Rotation.from_rotvec(SECOND_ROUND_ROTVEC).as_matrix()
        more = multistart_coarse(field, y_c, R1, c_model, L, delta2_field, rng, False)
        lanes = LaneResult(
            np.concatenate([lanes.T, more.T]),
            np.concatenate([lanes.eps, more.eps]),
            np.concatenate([lanes.accepted, more.accepted]),
            np.concatenate([lanes.iterations, more.iterations]),
            np.concatenate([lanes.perturbations, more.perturbations]),
            None,
        )
        R0 = np.concatenate([R0, R1])
        second_round = True
    return lanes, len(R0), second_round
