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
  gamma0 vary at 30 degree granularity and beta0 is assumed known within 45 degrees. Read
  as printed (``R0 = Rz(alpha0) Ry(beta0)``, gamma0 = 0; ``start_table="liu2001"``), the 36
  rotations leave parts of SO(3) far more than 45 degrees from every start
  (``benchmarks/results_global_search.md``): they do not honour the document's premise that
  Algorithm 1 converges from within 45 degrees. The default ``"icosahedral"`` uses the 60
  rotations of the icosahedral group (covering radius 44.3 degrees), which is what the
  document's argument needs. A ``(K, 3, 3)`` array of rotations may be passed too.
  When ``noise_sigma_m`` is known and no icosahedral start passes the tests, a second round
  runs from the same 60 rotations turned by ``SECOND_ROUND_ROTVEC``.
* ``eps`` is the document's ``sum ||g^-1 y_i - x_i||^2`` (squared distance to the foot).
  ``delta2 = N (2 sigma_eff)^2`` (in the coarse phase ``N (2 sigma_eff + 3 e_field)^2``,
  e_field the field's RMS error on exact points) with
  ``sigma_eff = sqrt(sigma^2 + model_error^2)``: the RMS residual must be below twice the
  expected noise (for N >= 25 Gaussian residuals it exceeds 2 sigma with negligible
  probability). ``delta1 = 1e-3``, ``delta3 = 1e-4`` (twist norm with the translation divided
  by the characteristic length L of the points).
* ``delta_b``: a rotation of 15, 30 then 45 degrees about a random axis through the points'
  centroid plus a translation of ``L * delta_b / (2 pi)`` in a random direction; beyond 45
  degrees (the convergence radius) the start is abandoned.
* All starts run at once, batched (:func:`descend`), on the coarse nearest-surface field of
  :mod:`.fields`; the best distinct minima are then refined with exact closest points
  (:mod:`.verify`) and the best is polished with the library's local method.
* The document stops at the first start that passes all tests. Here every start runs (unless
  ``stop_at_first=True``), because the hypotheses are verified (:mod:`.verify`); once one
  start has passed, the others are no longer perturbed out of their local minima (step 6 is
  for a search that has not reached the noise level).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray, IntArray
from algorithms.errors import AlgorithmError
from algorithms.registration.global_search.fields import ExactOracle, NearestSurface, sq_dist
from algorithms.registration.global_search.poses import apply_model_motion, make_poses, rotvec_to_matrix, to_model

__all__ = [
    "CONVERGENCE_RADIUS_DEG",
    "CoarseProblem",
    "FIELD_FLOOR_FACTOR",
    "LIU2001_START_ANGLES_DEG",
    "LaneResult",
    "MULTISTART_DELTA1",
    "MULTISTART_DELTA3",
    "MultistartOutcome",
    "NOISE_ACCEPT_FACTOR",
    "PERTURBATION_STEPS_DEG",
    "SECOND_ROUND_ROTVEC",
    "StartTable",
    "StopTests",
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
#: Second-round offset [rotation vector, rad]: the icosahedral table right-multiplied by it
#: joins the first round's 60 starts; the 120 together leave no orientation more than about
#: 40 degrees from a start.
SECOND_ROUND_ROTVEC = (2.32799788, -1.06526766, 0.48524283)
#: Perturbation sizes delta_b [deg]; past the last one the start is abandoned.
PERTURBATION_STEPS_DEG = (15.0, 30.0, 45.0)

#: A start table: ``"icosahedral"``, ``"liu2001"`` or (K, 3, 3) rotations.
StartTable = str | ArrayLike


def orientation_table(name: StartTable = "icosahedral") -> FloatArray:
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
    """What :func:`descend` leaves of B lanes (one start pose each).

    Attributes:
        T: (B, 4, 4) the best pose seen per lane (workpiece to world).
        eps: (B,) [m^2] its eps, the sum of squared distances.
        accepted: (B,) the lane passed all three tests of Algorithm 5.
        iterations: (B,) pose updates, all descents of the lane together.
        perturbations: (B,) perturbations applied.
        faces: (B, N) the last feet's faces (exact oracle; -1 unknown), else None.
    """

    T: FloatArray
    eps: FloatArray
    accepted: BoolArray
    iterations: IntArray
    perturbations: IntArray
    faces: IntArray | None


@dataclass(frozen=True)
class StopTests:
    """Algorithm 5's stopping tests (step 5): ``1 - eps_k / eps_(k-1) < delta1``,
    ``eps_k < delta2``, ``||xi|| < delta3``; ``max_iter_per_descent`` caps one descent."""

    delta1: float
    delta2: float
    delta3: float
    max_iter_per_descent: int


@dataclass
class _Lanes:
    """Mutable state of B lanes during :func:`descend`."""

    T: FloatArray  # (B, 4, 4) current pose
    best_T: FloatArray  # (B, 4, 4) best pose of the lane so far
    best_eps: FloatArray  # (B,) its eps [m^2]
    eps_prev: FloatArray  # (B,) eps of the previous iterate of this descent (inf: none)
    active: BoolArray
    accepted: BoolArray
    iterations: IntArray  # pose updates, all descents
    descent_iterations: IntArray  # pose updates of the current descent
    level: IntArray  # perturbations applied
    faces: IntArray | None  # (B, N) last feet's faces (exact oracle), -1 unknown

    @classmethod
    def start(cls, T0: FloatArray, n_points: int, keep_faces: bool) -> _Lanes:
        B = len(T0)
        return cls(
            T=T0.copy(),
            best_T=T0.copy(),
            best_eps=np.full(B, np.inf),
            eps_prev=np.full(B, np.inf),
            active=np.ones(B, dtype=bool),
            accepted=np.zeros(B, dtype=bool),
            iterations=np.zeros(B, dtype=np.int64),
            descent_iterations=np.zeros(B, dtype=np.int64),
            level=np.zeros(B, dtype=np.int64),
            faces=np.full((B, n_points), -1, dtype=np.int64) if keep_faces else None,
        )

    def result(self) -> LaneResult:
        return LaneResult(self.best_T, self.best_eps, self.accepted, self.iterations, self.level, self.faces)


@dataclass(frozen=True)
class _Feet:
    """The active lanes' points and their nearest surface (model frame)."""

    x: FloatArray  # (A, N, 3) [m] the points in each lane's model frame
    normal: FloatArray  # (A, N, 3) unit normals at the feet
    r: FloatArray  # (A, N) [m] signed normal offsets
    eps: FloatArray  # (A,) [m^2] sum of squared distances


@dataclass(frozen=True)
class _Step:
    """A Gauss-Newton pose update per active lane, about the points' centroid ``c``."""

    c: FloatArray  # (A, 3) [m] model frame
    delta: FloatArray  # (A, 6) [omega (rad), v (m)], rotation capped at max_step_rad
    xi_norm: FloatArray  # (A,) twist norm, translation divided by L


def descend(
    oracle: NearestSurface,
    y: FloatArray,
    T0: FloatArray,
    *,
    L: float,
    delta1: float,
    delta2: float,
    delta3: float,
    max_iter_per_descent: int,
    rng: np.random.Generator | None,
    perturbation_deg: Sequence[float] = PERTURBATION_STEPS_DEG,
    stop_at_first: bool = False,
    max_step_rad: float = 0.5,
) -> LaneResult:
    """Algorithm 1 from B start poses at once, stopped by Algorithm 5's tests, with its
    perturbations (step 6) when ``rng`` is given and ``delta2`` is finite.

    Each pose update is a point-to-plane Gauss-Newton step about the centroid of the points
    (document 001's variable iteration centre).

    Args:
        oracle: the nearest surface (coarse field or exact).
        y: (N, 3) [m] points, world frame.
        T0: (B, 4, 4) start poses, workpiece to world.
        L: the points' characteristic length [m] (scales the translation in ``||xi||``).
        delta1, delta2, delta3, max_iter_per_descent: see :class:`StopTests`.
        rng: random generator of the perturbations (None: none).
        perturbation_deg: the perturbation sizes [deg]; past the last the lane gives up.
        stop_at_first: stop every lane once one has passed all tests.
        max_step_rad: cap on one update's rotation [rad].
    """
    tests = StopTests(delta1, delta2, delta3, max_iter_per_descent)
    lanes = _Lanes.start(T0, len(y), keep_faces=isinstance(oracle, ExactOracle))
    do_perturb = rng is not None and bool(np.isfinite(delta2)) and len(perturbation_deg) > 0
    while lanes.active.any():
        a = np.nonzero(lanes.active)[0]
        feet = _nearest_surface(oracle, lanes, a, y)
        step = _gauss_newton_step(feet, L, max_step_rad)
        local_min = _apply_stop_tests(lanes, a, feet.eps, step.xi_norm, tests)
        # step 6: once a start has passed every test, the others are not perturbed out of
        # their local minima (their minima still go to the verification)
        if do_perturb and rng is not None and not lanes.accepted.any():
            _perturb_or_give_up(lanes, a[local_min], y, L, perturbation_deg, rng)
        else:
            lanes.active[a[local_min]] = False
        # every lane still active and not just perturbed takes the step
        moving = lanes.active[a]
        if do_perturb:
            moving &= ~local_min
        _take_step(lanes, a[moving], step, moving, feet.eps)
        if stop_at_first and lanes.accepted.any():
            break
    return lanes.result()


def _nearest_surface(oracle: NearestSurface, lanes: _Lanes, a: IntArray, y: FloatArray) -> _Feet:
    """The active lanes' feet; records each lane's best pose so far."""
    x = to_model(lanes.T[a], y)  # (A, N, 3)
    hints = None
    if lanes.faces is not None:
        hints = lanes.faces[a].reshape(-1)
        hints = None if (hints < 0).any() else hints
    foot, normal, face = oracle.closest(x.reshape(-1, 3), hint=hints)
    foot = foot.reshape(x.shape)
    normal = normal.reshape(x.shape)
    if lanes.faces is not None and face is not None:
        lanes.faces[a] = np.asarray(face).reshape(len(a), len(y))
    d2, r = sq_dist(x, foot, normal, oracle.tangent_tol)
    eps = d2.sum(axis=1)
    better = eps < lanes.best_eps[a]
    lanes.best_eps[a[better]] = eps[better]
    lanes.best_T[a[better]] = lanes.T[a[better]]
    return _Feet(x, normal, r, eps)


def _gauss_newton_step(feet: _Feet, L: float, max_step_rad: float) -> _Step:
    """Point-to-plane Gauss-Newton step of each lane about its points' centroid."""
    c = feet.x.mean(axis=1)
    xc = feet.x - c[:, None, :]
    n = feet.normal
    # J = [xc x n, n], the cross product written out (np.cross's own arithmetic, bit for bit)
    J = np.empty(xc.shape[:2] + (6,))
    J[..., 0] = xc[..., 1] * n[..., 2] - xc[..., 2] * n[..., 1]
    J[..., 1] = xc[..., 2] * n[..., 0] - xc[..., 0] * n[..., 2]
    J[..., 2] = xc[..., 0] * n[..., 1] - xc[..., 1] * n[..., 0]
    J[..., 3:] = n
    Jt = J.transpose(0, 2, 1)
    H = Jt @ J
    g = (Jt @ feet.r[:, :, None])[:, :, 0]
    tr = np.trace(H, axis1=1, axis2=2)
    H = H + (1e-9 * tr + 1e-300)[:, None, None] * np.eye(6)[None]
    delta = -np.linalg.solve(H, g[:, :, None])[:, :, 0]
    th = np.linalg.norm(delta[:, :3], axis=1)
    scale = np.minimum(1.0, max_step_rad / np.maximum(th, 1e-300))
    delta *= scale[:, None]
    xi_norm = np.sqrt(np.sum(delta[:, :3] ** 2, axis=1) + np.sum((delta[:, 3:] / L) ** 2, axis=1))
    return _Step(c, delta, xi_norm)


def _apply_stop_tests(lanes: _Lanes, a: IntArray, eps: FloatArray, xi_norm: FloatArray,
                      tests: StopTests) -> BoolArray:
    """Algorithm 5's step 5 on the active lanes ``a``: lanes that pass all tests stop,
    accepted, at the pose just evaluated; lanes out of iterations with a small residual stop,
    not accepted.

    Returns:
        (A,) the lanes at a local minimum (stalled with eps above delta2).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(np.isfinite(lanes.eps_prev[a]), 1.0 - eps / lanes.eps_prev[a], np.inf)
    lanes.iterations[a] += 1
    lanes.descent_iterations[a] += 1
    exhausted = lanes.descent_iterations[a] >= tests.max_iter_per_descent
    stalled = (rel < tests.delta1) | exhausted
    small_eps = eps < tests.delta2
    done_ok = stalled & small_eps & (xi_norm < tests.delta3)
    lanes.accepted[a[done_ok]] = True
    lanes.best_T[a[done_ok]] = lanes.T[a[done_ok]]
    lanes.best_eps[a[done_ok]] = eps[done_ok]
    lanes.active[a[done_ok]] = False
    lanes.active[a[exhausted & small_eps & ~done_ok]] = False
    return stalled & ~small_eps


def _perturb_or_give_up(lanes: _Lanes, pm: IntArray, y: FloatArray, L: float, perturbation_deg: Sequence[float],
                        rng: np.random.Generator) -> None:
    """Step 6 on the lanes ``pm`` at a local minimum: past the last perturbation size the lane
    gives up; else its best pose of this descent is turned by the next size about a random
    axis through the points' centroid and moved ``L * angle / (2 pi)`` in a random direction."""
    if not len(pm):
        return
    give_up = lanes.level[pm] >= len(perturbation_deg)
    lanes.active[pm[give_up]] = False
    pm = pm[~give_up]
    if not len(pm):
        return
    ang = np.radians(np.asarray(perturbation_deg)[lanes.level[pm]])
    axis = rng.normal(size=(len(pm), 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    tdir = rng.normal(size=(len(pm), 3))
    tdir /= np.linalg.norm(tdir, axis=1, keepdims=True)
    cpm = to_model(lanes.best_T[pm], y).mean(axis=1)
    lanes.T[pm] = apply_model_motion(
        lanes.best_T[pm], rotvec_to_matrix(axis * ang[:, None]), cpm, tdir * (L * ang / (2 * np.pi))[:, None]
    )
    lanes.level[pm] += 1
    lanes.eps_prev[pm] = np.inf
    lanes.descent_iterations[pm] = 0
    if lanes.faces is not None:
        lanes.faces[pm] = -1


def _take_step(lanes: _Lanes, sa: IntArray, step: _Step, moving: BoolArray, eps: FloatArray) -> None:
    """The lanes ``sa`` (``moving`` among the active ones) take their Gauss-Newton step."""
    if not len(sa):
        return
    Rd = rotvec_to_matrix(step.delta[moving, :3])
    lanes.T[sa] = apply_model_motion(lanes.T[sa], Rd, step.c[moving], step.delta[moving, 3:])
    lanes.eps_prev[sa] = eps[moving]


def farthest_point_subset(y: FloatArray, n: int) -> IntArray:
    """Indices (n,) of n points spread over the cloud y (N, 3) (greedy farthest-point sampling)."""
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


def model_centroid(mesh: Any) -> FloatArray:
    """(3,) [m] the area centroid of the mesh's surface, in the mesh's frame."""
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    area = np.asarray(mesh.area_faces, dtype=np.float64)
    if area.sum() <= 0:
        return tri.reshape(-1, 3).mean(axis=0)
    return (tri.mean(axis=1) * area[:, None]).sum(axis=0) / area.sum()


def start_poses(R0: FloatArray, y: FloatArray, c_model: FloatArray) -> FloatArray:
    """(K, 4, 4) start poses ``(p0, R0)`` with ``p0 = mean(y) - R0 c_model`` (centroids matched)."""
    p0 = y.mean(axis=0)[None, :] - np.einsum("kij,j->ki", R0, c_model)
    return make_poses(R0, p0)


@dataclass(frozen=True)
class CoarseProblem:
    """What the coarse phases work on.

    Attributes:
        field: the coarse nearest-surface field (:mod:`.fields`).
        y: (n, 3) [m] the coarse subset of the points, world frame.
        c_model: (3,) [m] the model's area centroid, workpiece frame.
        L: the points' characteristic length [m].
        delta2: Algorithm 5's delta2 on the field [m^2] (inf: the noise is unknown).
    """

    field: NearestSurface
    y: FloatArray
    c_model: FloatArray
    L: float
    delta2: float


@dataclass(frozen=True)
class MultistartOutcome:
    """Algorithm 5's coarse phase: the lanes, the starts run, whether the second round ran."""

    lanes: LaneResult
    n_starts: int
    second_round: bool


def multistart_coarse(problem: CoarseProblem, R0: FloatArray, rng: np.random.Generator,
                      stop_at_first: bool) -> LaneResult:
    """Algorithm 5 on the coarse field from the start orientations R0 (K, 3, 3)."""
    return descend(
        problem.field,
        problem.y,
        start_poses(R0, problem.y, problem.c_model),
        L=problem.L,
        delta1=MULTISTART_DELTA1,
        delta2=problem.delta2,
        delta3=MULTISTART_DELTA3,
        max_iter_per_descent=40,
        rng=rng,
        stop_at_first=stop_at_first,
    )


def multistart_stage(problem: CoarseProblem, R0: FloatArray, start_table: StartTable, rng: np.random.Generator,
                     *, stop_at_first: bool, sigma_known: bool) -> MultistartOutcome:
    """Algorithm 5's coarse phase from every start of ``R0``, and the second round (the
    icosahedral table turned by ``SECOND_ROUND_ROTVEC``) when the noise is known and no
    start passed the tests."""
    lanes = multistart_coarse(problem, R0, rng, stop_at_first)
    if not (sigma_known and not lanes.accepted.any() and isinstance(start_table, str)
            and start_table == "icosahedral"):
        return MultistartOutcome(lanes, len(R0), False)
    R1 = R0 @ Rotation.from_rotvec(SECOND_ROUND_ROTVEC).as_matrix()
    more = multistart_coarse(problem, R1, rng, False)
    both = LaneResult(
        np.concatenate([lanes.T, more.T]),
        np.concatenate([lanes.eps, more.eps]),
        np.concatenate([lanes.accepted, more.accepted]),
        np.concatenate([lanes.iterations, more.iterations]),
        np.concatenate([lanes.perturbations, more.perturbations]),
        None,
    )
    return MultistartOutcome(both, len(R0) + len(R1), True)
