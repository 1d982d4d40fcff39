"""Global workpiece localization: a pose from any initial orientation.

Three methods from the source documents, one entry point :func:`global_localize`:

``"multistart"`` -- document 000 (Liu, Li, Dai 2001), section 8, Algorithm 5.
    Start poses ``g0 = (p0, R0)`` from a table of orientations, position from the centroids
    (``p0 = mean(y) - R0 c_model``; the document's ``p0 = mean(y)`` with the model frame at
    its centroid). From every start run the local Algorithm 1 (foot points, then a
    point-to-plane pose update) with the three stopping tests of step 5::

        1 - eps_k / eps_(k-1) < delta1   and   eps_k < delta2   and   ||xi|| < delta3

    When the first holds but not the second (a local minimum), step 6 adds a perturbation
    ``delta_b`` and descends again; when the perturbation has grown past the convergence
    radius the start is abandoned ("go to the next initial pose").

    Readings and choices:

    * The start table. The original gives "alpha0, beta0 in {30, -30, 90, -90, 150, -150}
      degrees -> 36 groups g0(p0, alpha0, beta0, gamma0)", while its prose says alpha0 and
      gamma0 vary at 30 degree granularity and beta0 is assumed known within 45 degrees. Read
      as printed (``R0 = Rz(alpha0) Ry(beta0)``, gamma0 = 0; ``start_table="liu2001"``), the 36
      rotations leave parts of SO(3) up to 94 degrees from every start (measured on 200,000
      random rotations): they do not honour the document's own premise that Algorithm 1
      converges from within 45 degrees. The default ``"icosahedral"`` uses the 60 rotations of
      the icosahedral group instead, whose covering radius is 44.3 degrees: every orientation
      is within 45 degrees of a start, which is what the document's argument needs. A
      ``(K, 3, 3)`` array of rotations may be passed too. When ``noise_sigma_m`` is known and
      no icosahedral start passes the tests, a second round runs from the same 60 rotations
      turned by a fixed offset (120 starts together: no orientation further than 39.6 degrees
      from one): on the S-surface part with 150 points, 1 random orientation in 8 needed it.
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
    * Speed: all starts run at once, batched. The first phase uses a coarse nearest-surface
      field (a voxel grid storing the nearest surface sample, built once per mesh, about a
      millimetre resolution), then the best distinct minima are refined with the exact
      closest points (:class:`algorithms.geometry.mesh_index.MeshIndex`) and the best is polished
      with the library's local method (:func:`algorithms.registration.local.localize`).
    * The document stops at the first start that passes all tests. Here every start is run
      (unless ``stop_at_first=True``), because hypotheses are verified (below).

``"genetic"`` -- document 001 (hierarchical macro/micro localization), coarse stage.
    A binary chromosome ``{X_T | Y_T | Z_T | alpha | beta | gamma}``, fitness
    ``1 / (1 + sum_i D_err,i)``, crossover probability ``Pc = 0.9``, mutation ``Pm = 0.1``,
    100 individuals, random initial genes, stop at generation 100 or best fitness >= 0.95.
    Then the fine stage (document 001's variable-iteration-centre linearised least squares,
    ``localize(..., method="fine_001", init=T_coarse)``, on the coarse subset of at most
    ``n_coarse`` points: the document's fine stage uses a few probe points) and
    ``T = T_fine @ T_coarse``; then the polish with all points.

    Readings and choices (the original does not state them):

    * Bits: 10 per parameter (60 per chromosome), plain binary code as the document says.
      Angles ``R = Rz(gamma) Ry(beta) Rx(alpha)``: alpha, gamma in [-180, 180) degrees,
      beta in [-90, 90] degrees (resolution 0.35 and 0.18 degrees, below the document's
      "a few tenths of a degree"). ``[X_T, Y_T, Z_T]`` is where the points' centroid lies in
      the model frame, relative to the model's (area) centroid:
      ``T^-1 y = R^T (y - mean(y)) + c_model + [X_T, Y_T, Z_T]``, each within half the model's
      bounding box. Document 001 first moves the part by its moment of inertia; centring on
      the centroids plays that role, and makes the best translation genes independent of the
      rotation genes (a translation of the world origin would couple them).
    * ``D_err`` in millimetres, the document's unit (its matrices are in mm). Summed over N
      points the fitness reaches 0.95 only when ``sum D_err <= 0.053 mm``, e.g. a mean
      distance of 0.35 um over 150 points: the early stop is practically unreachable and the
      GA runs its 100 generations.
    * ``Pm = 0.1`` per bit (the classical meaning of a binary GA's mutation rate, Goldberg
      1989; ``mutation="per_chromosome"`` flips one random bit of a chromosome with
      probability 0.1 instead). Selection is fitness-proportional (roulette wheel), crossover
      single-point on consecutive pairs, and the best individual is kept (elitism, 1): the
      document names none of these.
    * D_err is read from the coarse nearest-surface field (resolution about a millimetre)
      for all 100 chromosomes at once; the fine stage uses exact closest points.
    * Measured: from random orientations one GA run (100 x 100) ends in the right basin only
      25-60 % of the time on the hemisphere punch and S-surface part (it often settles on a
      near-symmetric pose, e.g. the hemisphere's points matched and the part turned 90 or
      180 degrees). So, when ``noise_sigma_m`` is known, a run is checked the way Algorithm 5
      checks a start (a short exact descent from the GA's pose; RMS residual within
      2 sigma_eff) and the GA is run again with fresh random genes, at most ``ga_restarts``
      times. ``ga_restarts=1`` is the document's single run.

``"pso"`` -- document 003 (patent CN103438844B), particle swarm fine registration after a
    coarse pre-registration: 40 particles, 100 iterations, linearly decreasing inertia
    ``w = w_max - (w_max - w_min) k / N`` from 0.9 to 0.4, time-varying acceleration
    ``c1 = 2.5 + (0.5 - 2.5) k / N``, ``c2 = 0.5 + (2.5 - 0.5) k / N`` (k = 1..N),
    ``v <- w v + c1 r1 (p_best - x) + c2 r2 (g_best - x)`` with r1, r2 uniform in [0, 1] per
    dimension, ``|v| <= v_max = x_max - x_min``, fitness ``sum ||g Q_i - P_i||^2`` with P_i
    the nearest model point (exact closest points by default), final matrix = initial @ PSO.

    Readings and choices: the coarse pre-registration ("any rough method") is the first,
    coarse phase of the multistart above (its best minimum). A particle is
    ``x = [omega (3), t (3)]``: a rotation vector about the points' centroid (model frame)
    and a translation, ``Delta(x) = [R(omega), c - R(omega) c + t]``, in the ranges
    ``+-pso_rotation_range_rad`` and ``+-pso_translation_range_m``; positions are clipped to
    the range, initial velocities uniform in ``[-v_max/2, v_max/2]``. The PSO result is then
    polished with the library's local method so results reach 1e-6 m / 1e-6 rad (the swarm
    alone stops at its own resolution, recorded in ``extra["pso_only_T"]``).

Hypothesis verification (all methods): the best pose is a success only if its RMS residual
is consistent with the noise (``rms <= 2 sigma_eff``) and the points constrain all six
degrees of freedom (:func:`algorithms.registration.uncertainty.observability` with smooth normals). The
best is compared with the second-best *distinct* solution found (rotation differing by more
than 2 degrees or translation by more than 1 % of the part's size, refined with exact closest
points on the same points): if the two are statistically indistinguishable
(``eps_2 - eps_1 <= 2 chi2_0.999(6) sigma_eff^2``, about 45 sigma_eff^2) the result is
*ambiguous*: ``status`` says so, ``ambiguous`` is True and ``equivalent_poses`` lists the
equally good poses. A symmetric or near-symmetric part is therefore never reported as a confident unique
success. The distinct solutions come from the multistart's coarse minima (for ``"genetic"``
and ``"pso"`` too: the coarse multistart phase runs for them as pre-registration or as this
check), at most ``max_candidates`` of them, refined on ``n_verify`` points. Outliers are not
expected: filter the points first (the residual check uses every point).
"""

from __future__ import annotations

import math
import time
import weakref
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import ndimage
from scipy.spatial.transform import Rotation

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.errors import AlgorithmError
from algorithms.registration.local import LocalizationResult, localize
from algorithms.geometry.se3 import inv_pose, rotation_error_rad, translation_error_m

__all__ = [
    "GLOBAL_METHODS",
    "GlobalLocalizationResult",
    "global_localize",
    "orientation_table",
    "GA_POPULATION",
    "GA_GENERATIONS",
    "GA_CROSSOVER_PROB",
    "GA_MUTATION_PROB",
    "GA_FITNESS_STOP",
    "GA_BITS",
    "PSO_PARTICLES",
    "PSO_ITERATIONS",
    "PSO_W_MAX",
    "PSO_W_MIN",
    "PSO_C1_INITIAL",
    "PSO_C1_FINAL",
    "PSO_C2_INITIAL",
    "PSO_C2_FINAL",
]

GLOBAL_METHODS = ("multistart", "genetic", "pso")

# ---- document 000, Algorithm 5 -------------------------------------------------------------
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
#: orientation more than 39.6 degrees from a start; chosen among 30 random offsets).
SECOND_ROUND_ROTVEC = (2.32799788, -1.06526766, 0.48524283)
#: Perturbation sizes delta_b [deg]; past the last one the start is abandoned.
PERTURBATION_STEPS_DEG = (15.0, 30.0, 45.0)

# ---- document 001, genetic algorithm ---------------------------------------------------------
GA_POPULATION = 100
GA_GENERATIONS = 100
GA_CROSSOVER_PROB = 0.9
GA_MUTATION_PROB = 0.1
GA_FITNESS_STOP = 0.95
#: Our choice (the document does not give it): bits per parameter.
GA_BITS = 10
#: Fine stage stop value d [rad^2 + m^2] and iteration cap (our choices; the polish follows).
FINE_001_D = 1e-16
FINE_001_MAX_ITERATIONS = 300

# ---- document 003, particle swarm ------------------------------------------------------------
PSO_PARTICLES = 40
PSO_ITERATIONS = 100
PSO_W_MAX = 0.9
PSO_W_MIN = 0.4
PSO_C1_INITIAL = 2.5
PSO_C1_FINAL = 0.5
PSO_C2_INITIAL = 0.5
PSO_C2_FINAL = 2.5

# ---- verification ----------------------------------------------------------------------------
#: 2 * chi-square 0.999 quantile with 6 DOF: two fits of the same points whose eps differ by
#: less than this many sigma^2 cannot be told apart.
AMBIGUITY_CHI2 = 2.0 * 22.4577
DISTINCT_ROTATION_RAD = math.radians(2.0)
DISTINCT_TRANSLATION_FRAC = 0.01
#: Default allowance for model (tessellation) error when checking residuals [m].
DEFAULT_MODEL_ERROR_M = 1e-6
#: The local method used to polish (document 000 finds Hong-Tan best).
DEFAULT_POLISH = "hong_tan"


# =============================================================================================
# small batched SE(3) helpers
# =============================================================================================
def _rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    """(B, 3) rotation vectors -> (B, 3, 3) rotations (Rodrigues)."""
    th = np.linalg.norm(w, axis=1)
    small = th < 1e-12
    ths = np.where(small, 1.0, th)
    k = w / ths[:, None]
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1] = -k[:, 2]
    K[:, 0, 2] = k[:, 1]
    K[:, 1, 0] = k[:, 2]
    K[:, 1, 2] = -k[:, 0]
    K[:, 2, 0] = -k[:, 1]
    K[:, 2, 1] = k[:, 0]
    s = np.where(small, 0.0, np.sin(th))[:, None, None]
    c = np.where(small, 0.0, 1.0 - np.cos(th))[:, None, None]
    R = np.eye(3)[None] + s * K + c * (K @ K)
    if small.any():  # first order for tiny angles
        W = np.zeros((int(small.sum()), 3, 3))
        ws = w[small]
        W[:, 0, 1] = -ws[:, 2]
        W[:, 0, 2] = ws[:, 1]
        W[:, 1, 0] = ws[:, 2]
        W[:, 1, 2] = -ws[:, 0]
        W[:, 2, 0] = -ws[:, 1]
        W[:, 2, 1] = ws[:, 0]
        R[small] = np.eye(3)[None] + W
    return R


def _to_model(T: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Points y (N, 3) [world] into the model frames of poses T (B, 4, 4) -> (B, N, 3)."""
    return (y[None, :, :] - T[:, None, :3, 3]) @ T[:, :3, :3]


def _apply_model_motion(T: np.ndarray, Rd: np.ndarray, c: np.ndarray, v: np.ndarray) -> np.ndarray:
    """New poses when model-frame points move by ``x' = Rd (x - c) + c + v``.

    ``x = T^-1 y``, so the new ``T^-1 = M T^-1`` and ``T_new = T M^-1``.
    """
    B = len(T)
    Minv = np.tile(np.eye(4), (B, 1, 1))
    RdT = Rd.transpose(0, 2, 1)
    t = c - np.einsum("bij,bj->bi", Rd, c) + v
    Minv[:, :3, :3] = RdT
    Minv[:, :3, 3] = -np.einsum("bij,bj->bi", RdT, t)
    return T @ Minv


def _make_poses(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.tile(np.eye(4), (len(R), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = p
    return T


# =============================================================================================
# nearest-surface oracles
# =============================================================================================
class _CoarseField:
    """Nearest surface sample of every node of a voxel grid around the model.

    Built with one Euclidean distance transform (scipy.ndimage) of the voxels that contain
    surface samples; a query rounds to the nearest node and returns that node's nearest
    sample and its face normal. Accuracy: a few voxels (``cell`` = extent / 64 by default);
    it is only used for the coarse phases, never for a reported pose.
    """

    def __init__(self, mesh, cells_per_extent: int = 64, pad_frac: float = 0.6):
        import trimesh  # local: only needed here

        V = np.asarray(mesh.vertices, dtype=np.float64)
        lo, hi = V.min(axis=0), V.max(axis=0)
        extent = float(np.linalg.norm(hi - lo))
        if not extent > 0:
            raise AlgorithmError("mesh has zero extent")
        cell = extent / cells_per_extent
        pad = pad_frac * extent
        self.origin = lo - pad
        self.cell = cell
        self.shape = tuple(int(s) for s in np.ceil((hi - lo + 2 * pad) / cell).astype(int) + 1)
        face_normals = np.asarray(mesh.face_normals, dtype=np.float64)
        n = int(min(2_000_000, max(20_000, 6.0 * float(mesh.area) / cell**2)))
        s, fi = trimesh.sample.sample_surface(mesh, n, seed=0)
        tri = np.asarray(mesh.triangles, dtype=np.float64)
        s = np.vstack([s, tri.mean(axis=1)])
        fi = np.concatenate([fi, np.arange(len(tri))])
        self.samples = s
        self.normals = face_normals[fi]
        ijk = np.rint((s - self.origin) / cell).astype(np.int64)
        table = np.full(self.shape, -1, dtype=np.int32)
        table[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = np.arange(len(s), dtype=np.int32)
        ind = ndimage.distance_transform_edt(table < 0, return_distances=False, return_indices=True)
        self.nearest = table[ind[0], ind[1], ind[2]]
        self._flat = self.nearest.reshape(-1)
        self._hi = np.asarray(self.shape, dtype=np.float64) - 1.0
        self._strides = np.array([self.shape[1] * self.shape[2], self.shape[2], 1], dtype=np.int64)
        # tangential tolerance: a node's sample is within about one cell of the true foot
        self.tangent_tol = cell
        # the field's own residual for points exactly on the surface (its floor)
        chk, cfi = trimesh.sample.sample_surface(mesh, 2000, seed=1)
        foot, normal, _ = self.closest(chk)
        d2, _ = _sq_dist(chk, foot, normal, self.tangent_tol)
        self.floor_rms = float(np.sqrt(np.mean(d2)))

    def closest(self, x: np.ndarray, hint=None):
        f = np.rint((x - self.origin) * (1.0 / self.cell))
        np.clip(f, 0.0, self._hi, out=f)
        k = self._flat[f.astype(np.int64) @ self._strides]
        return self.samples[k], self.normals[k], None


class _ExactOracle:
    tangent_tol = 0.0

    def __init__(self, index):
        self.index = index

    def closest(self, x: np.ndarray, hint=None):
        try:
            cp = self.index.query(x, hint=hint)
        except TypeError:  # an index without hints
            cp = self.index.query(x)
        return cp.foot, cp.normal, cp.face


_FIELD_CACHE: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _coarse_field(mesh) -> _CoarseField:
    try:
        f = _FIELD_CACHE.get(mesh)
    except TypeError:
        f = None
    if f is None:
        f = _CoarseField(mesh)
        try:
            _FIELD_CACHE[mesh] = f
        except TypeError:
            pass
    return f


def _sq_dist(x, foot, normal, tangent_tol):
    """Squared distance estimate: exact for exact feet (tangent_tol = 0); for a field sample,
    the normal offset plus the tangential offset beyond the sample's patch."""
    d = x - foot
    rn = np.einsum("...i,...i->...", d, normal)
    dd = np.einsum("...i,...i->...", d, d)
    if tangent_tol <= 0:
        return dd, rn
    tang = np.sqrt(np.maximum(dd - rn * rn, 0.0))
    ex = np.maximum(tang - tangent_tol, 0.0)
    return rn * rn + ex * ex, rn


# =============================================================================================
# start tables
# =============================================================================================
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


# =============================================================================================
# batched Algorithm 1 with Algorithm 5's tests
# =============================================================================================
@dataclass
class _LaneResult:
    T: np.ndarray  # (B, 4, 4) best pose seen per lane
    eps: np.ndarray  # (B,) its eps (sum of squared distances)
    accepted: np.ndarray  # (B,) passed all three tests
    iterations: np.ndarray  # (B,)
    perturbations: np.ndarray  # (B,)
    faces: np.ndarray | None  # (B, N) last feet faces (exact oracle) for hints


def _descend(
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
) -> _LaneResult:
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
    faces_out = np.full((B, N), -1, dtype=np.int64) if isinstance(oracle, _ExactOracle) else None
    do_perturb = rng is not None and np.isfinite(delta2) and len(perturbation_deg) > 0
    ttol = oracle.tangent_tol
    while active.any():
        a = np.nonzero(active)[0]
        x = _to_model(T[a], y)  # (A, N, 3)
        if faces_out is not None:
            hints = faces_out[a].reshape(-1)
            hints = None if (hints < 0).any() else hints
        foot, normal, face = oracle.closest(x.reshape(-1, 3), hint=hints)
        foot = foot.reshape(x.shape)
        normal = normal.reshape(x.shape)
        if faces_out is not None and face is not None:
            faces_out[a] = np.asarray(face).reshape(len(a), N)
        d2, r = _sq_dist(x, foot, normal, ttol)
        eps = d2.sum(axis=1)
        better = eps < best_eps[a]
        best_eps[a[better]] = eps[better]
        best_T[a[better]] = T[a[better]]
        # Gauss-Newton step on the point-to-plane residual, about the centroid c
        c = x.mean(axis=1)
        xc = x - c[:, None, :]
        J = np.concatenate([np.cross(xc, normal), normal], axis=2)
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
        if do_perturb:
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
                    cpm = _to_model(best_T[pm], y).mean(axis=1)
                    T[pm] = _apply_model_motion(
                        best_T[pm], _rotvec_to_matrix(axis * ang[:, None]), cpm, tdir * (L * ang / (2 * np.pi))[:, None]
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
            Rd = _rotvec_to_matrix(delta[step, :3])
            T[sa] = _apply_model_motion(T[sa], Rd, c[step], delta[step, 3:])
            eps_prev[sa] = eps[step]
        if stop_at_first and accepted.any():
            break
    return _LaneResult(best_T, best_eps, accepted, its, level, faces_out)


# =============================================================================================
# helpers: inputs, subsampling, clustering
# =============================================================================================
def _check_points(points) -> np.ndarray:
    y = np.asarray(points, dtype=np.float64)
    if y.ndim != 2 or y.shape[1] != 3 or len(y) < 6:
        raise AlgorithmError(f"points must be (N, 3) with N >= 6, got {y.shape}")
    if not np.all(np.isfinite(y)):
        raise AlgorithmError("points contain NaN or infinite coordinates")
    return y


def _farthest_point_subset(y: np.ndarray, n: int) -> np.ndarray:
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


def _model_centroid(mesh) -> np.ndarray:
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    area = np.asarray(mesh.area_faces, dtype=np.float64)
    if area.sum() <= 0:
        return tri.reshape(-1, 3).mean(axis=0)
    return (tri.mean(axis=1) * area[:, None]).sum(axis=0) / area.sum()


def _distinct(Ts: np.ndarray, order: np.ndarray, size: float, k: int) -> list[int]:
    """Greedy: indices (in ``order``) of up to k mutually distinct poses."""
    picked: list[int] = []
    for i in order:
        ok = True
        for j in picked:
            if (
                rotation_error_rad(Ts[i], Ts[j]) < DISTINCT_ROTATION_RAD
                and translation_error_m(Ts[i], Ts[j]) < DISTINCT_TRANSLATION_FRAC * size
            ):
                ok = False
                break
        if ok:
            picked.append(int(i))
            if len(picked) >= k:
                break
    return picked


def _is_distinct(A, B, size) -> bool:
    return (
        rotation_error_rad(A, B) >= DISTINCT_ROTATION_RAD
        or translation_error_m(A, B) >= DISTINCT_TRANSLATION_FRAC * size
    )


# =============================================================================================
# the three methods' search phases
# =============================================================================================
def _start_poses(R0: np.ndarray, y: np.ndarray, c_model: np.ndarray) -> np.ndarray:
    p0 = y.mean(axis=0)[None, :] - np.einsum("kij,j->ki", R0, c_model)
    return _make_poses(R0, p0)


def _multistart_coarse(field, y_c, R0, c_model, L, delta2_field, rng, stop_at_first):
    T0 = _start_poses(R0, y_c, c_model)
    return _descend(
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


def _decode(bits: np.ndarray, lo: np.ndarray, hi: np.ndarray, nbits: int) -> np.ndarray:
    """(P, 6*nbits) 0/1 plain binary code -> (P, 6) parameters, each linear in [lo, hi]."""
    P = len(bits)
    b = bits.reshape(P, 6, nbits).astype(np.int64)
    w = (1 << np.arange(nbits - 1, -1, -1)).astype(np.int64)
    ints = b @ w
    return lo + (hi - lo) * ints / float((1 << nbits) - 1)


def _ga_poses(params: np.ndarray, y_mean: np.ndarray, c_model: np.ndarray) -> np.ndarray:
    """Poses of chromosomes: ``R = Rz(gamma) Ry(beta) Rx(alpha)``, and ``[X_T, Y_T, Z_T]`` the
    model-frame position of the points' centroid relative to the model centroid, so that
    ``T^-1 y = R^T (y - mean(y)) + c_model + [X_T, Y_T, Z_T]`` (the best translation genes do
    not depend on the rotation genes)."""
    R = Rotation.from_euler("ZYX", params[:, [5, 4, 3]]).as_matrix()
    p = y_mean[None, :] - np.einsum("kij,kj->ki", R, c_model[None, :] + params[:, :3])
    return _make_poses(R, p)


def _ga_fitness(field, y, T) -> np.ndarray:
    x = _to_model(T, y)
    foot, normal, _ = field.closest(x.reshape(-1, 3))
    d2, _ = _sq_dist(x.reshape(-1, 3), foot, normal, field.tangent_tol)
    dist_mm = 1e3 * np.sqrt(d2).reshape(len(T), len(y))
    return 1.0 / (1.0 + dist_mm.sum(axis=1))


def _genetic(field, y_g, c_model, half_size, rng, *, nbits, mutation, population, generations):
    lo = np.concatenate([-half_size, [-np.pi, -np.pi / 2, -np.pi]])
    hi = np.concatenate([half_size, [np.pi, np.pi / 2, np.pi]])
    nb = 6 * nbits
    y_mean = y_g.mean(axis=0)
    pop = rng.integers(0, 2, size=(population, nb), dtype=np.int8)
    best_bits, best_fit = None, -1.0
    history = []
    hall: list[tuple[float, np.ndarray]] = []
    gen = 0
    for gen in range(1, generations + 1):
        params = _decode(pop, lo, hi, nbits)
        T = _ga_poses(params, y_mean, c_model)
        fit = _ga_fitness(field, y_g, T)
        i = int(np.argmax(fit))
        if fit[i] > best_fit:
            best_fit, best_bits = float(fit[i]), pop[i].copy()
        history.append(float(fit.max()))
        # the distinct good chromosomes of every generation, for hypothesis verification
        top = np.argsort(-fit)[:5]
        hall.extend((float(fit[t]), T[t]) for t in top)
        if best_fit >= GA_FITNESS_STOP or gen == generations:
            break
        # roulette-wheel selection
        prob = fit / fit.sum()
        parents = pop[rng.choice(population, size=population, p=prob)]
        # single-point crossover on consecutive pairs with probability Pc
        children = parents.copy()
        for k in range(0, population - 1, 2):
            if rng.random() < GA_CROSSOVER_PROB:
                cut = int(rng.integers(1, nb))
                children[k, cut:] = parents[k + 1, cut:]
                children[k + 1, cut:] = parents[k, cut:]
        # mutation with probability Pm
        if mutation == "per_bit":
            flip = rng.random(children.shape) < GA_MUTATION_PROB
            children ^= flip.astype(np.int8)
        else:
            who = np.nonzero(rng.random(population) < GA_MUTATION_PROB)[0]
            bit = rng.integers(0, nb, size=len(who))
            children[who, bit] ^= 1
        # elitism: the best so far replaces one child
        children[int(rng.integers(0, population))] = best_bits
        pop = children
    T_best = _ga_poses(_decode(best_bits[None], lo, hi, nbits), y_mean, c_model)[0]
    return T_best, best_fit, gen, np.asarray(history), hall


def _pso(oracle, y_p, T_init, L, rng, *, rot_range, trans_range, particles, iterations):
    z = (y_p - T_init[:3, 3]) @ T_init[:3, :3]  # points in the initial model frame
    c = z.mean(axis=0)
    x_max = np.array([rot_range] * 3 + [trans_range] * 3)
    x_min = -x_max
    v_max = x_max - x_min

    def poses(X):
        R = _rotvec_to_matrix(X[:, :3])
        t = c[None, :] - np.einsum("kij,j->ki", R, c) + X[:, 3:]
        return _make_poses(R, t)

    hints = [None]

    def fitness(X):
        D = poses(X)
        x = _to_model(D, z)  # Delta^-1 z
        h = hints[0]
        foot, normal, face = oracle.closest(x.reshape(-1, 3), hint=h)
        if face is not None:
            hints[0] = np.asarray(face)
        d2, _ = _sq_dist(x.reshape(-1, 3), foot, normal, oracle.tangent_tol)
        return d2.reshape(len(X), len(z)).sum(axis=1)

    X = rng.uniform(x_min, x_max, size=(particles, 6))
    V = rng.uniform(-v_max / 2, v_max / 2, size=(particles, 6))
    f = fitness(X)
    pbest, pbest_f = X.copy(), f.copy()
    g = int(np.argmin(f))
    gbest, gbest_f = X[g].copy(), float(f[g])
    history = [gbest_f]
    N = iterations
    for k in range(1, N + 1):
        w = PSO_W_MAX - (PSO_W_MAX - PSO_W_MIN) * k / N
        c1 = PSO_C1_INITIAL + (PSO_C1_FINAL - PSO_C1_INITIAL) * k / N
        c2 = PSO_C2_INITIAL + (PSO_C2_FINAL - PSO_C2_INITIAL) * k / N
        r1 = rng.random((particles, 6))
        r2 = rng.random((particles, 6))
        V = w * V + c1 * r1 * (pbest - X) + c2 * r2 * (gbest[None, :] - X)
        V = np.clip(V, -v_max, v_max)
        X = np.clip(X + V, x_min, x_max)
        f = fitness(X)
        imp = f < pbest_f
        pbest[imp] = X[imp]
        pbest_f[imp] = f[imp]
        g = int(np.argmin(pbest_f))
        if pbest_f[g] < gbest_f:
            gbest, gbest_f = pbest[g].copy(), float(pbest_f[g])
        history.append(gbest_f)
    D = poses(gbest[None])[0]
    return T_init @ D, gbest, gbest_f, np.asarray(history), T_init @ poses(pbest)


# =============================================================================================
# result
# =============================================================================================
@dataclass(frozen=True)
class GlobalLocalizationResult(LocalizationResult):
    """:class:`algorithms.registration.local.LocalizationResult` of a global search, plus:

    Attributes:
        success: True only for a unique pose whose residual is consistent with the noise and
            whose points fix all six DOF.
        ambiguous: two or more distinct poses fit equally well (symmetric part).
        equivalent_poses: (4, 4) poses that fit as well as the result (the result first); just
            the result when unique.
        candidates: ``(T_world_workpiece, rms_m)`` of the distinct minima refined with exact
            closest points on the verification points, the result first.
        extra: method-specific diagnostics (start table, GA/PSO histories, coarse and fine
            transforms, timings; see :func:`global_localize`).

    ``method`` is the global method's name; ``iterations``, ``converged``, ``history``,
    ``covariance`` and the observability fields are those of the final polish.
    """

    success: bool = False
    ambiguous: bool = False
    equivalent_poses: tuple = ()
    candidates: tuple = ()
    extra: dict = field(default_factory=dict, repr=False)


# =============================================================================================
# public entry point
# =============================================================================================
def global_localize(
    points,
    mesh=None,
    method: str = "multistart",
    *,
    rng: np.random.Generator | None = None,
    index=None,
    noise_sigma_m: float | None = None,
    model_error_m: float = DEFAULT_MODEL_ERROR_M,
    polish: str | None = DEFAULT_POLISH,
    outlier=None,
    start_table="icosahedral",
    stop_at_first: bool = False,
    n_coarse: int = 150,
    n_verify: int = 400,
    max_candidates: int = 6,
    ga_bits: int = GA_BITS,
    ga_mutation: str = "per_bit",
    ga_population: int = GA_POPULATION,
    ga_generations: int = GA_GENERATIONS,
    ga_restarts: int = 10,
    pso_particles: int = PSO_PARTICLES,
    pso_iterations: int = PSO_ITERATIONS,
    pso_rotation_range_rad: float = math.radians(5.0),
    pso_translation_range_m: float | None = None,
    pso_fitness: str = "exact",
):
    """Localize a workpiece from any initial pose: document 000's multistart (Algorithm 5),
    document 001's genetic coarse + fine stages, or document 003's particle swarm.

    Args:
        points: (N, 3) [m] measured points, world frame, N >= 6, finite, outlier-free (the
            residual checks use every point).
        mesh: the CAD model (``trimesh.Trimesh``) in the workpiece frame [m]; may be None when
            ``index`` is given.
        method: ``"multistart"`` | ``"genetic"`` | ``"pso"``.
        rng: random generator (perturbations, GA, PSO, subsets); default
            ``np.random.default_rng(0)`` so that a call is reproducible.
        index: a prebuilt :class:`algorithms.geometry.mesh_index.MeshIndex` of ``mesh``.
        noise_sigma_m: measurement noise sigma [m] along the normals. Sets Algorithm 5's
            ``delta2`` and the residual check. None: estimated from the best fit (the residual
            check then cannot reject the best pose; ambiguity is still tested).
        model_error_m: allowance for model error (tessellation, form) [m], added in
            quadrature to sigma in the residual and ambiguity tests.
        polish: local method of :func:`algorithms.registration.local.localize` applied to the
            best pose with all points (None: no polish; the GA's fine stage still runs).
        outlier: passed to ``localize`` for the polish (default None: keep every point).
        start_table: multistart start orientations (see :func:`orientation_table`).
        stop_at_first: document 000's literal rule: stop at the first start passing all
            tests (no second-best comparison from the other starts).
        n_coarse: points used in the coarse phases (farthest-point subset).
        n_verify: points used to refine and compare candidate minima (random subset).
        max_candidates: distinct coarse minima refined with exact closest points.
        ga_bits, ga_mutation, ga_population, ga_generations: GA settings (defaults: the
            document's 100 / 100 and our 10 bits, per-bit mutation).
        ga_restarts: at most this many GA runs; a run is accepted when a short exact descent
            from its pose leaves an RMS residual within 2 sigma_eff (needs ``noise_sigma_m``;
            without it one run is made). One run is the document's algorithm.
        pso_particles, pso_iterations: PSO settings (defaults: the patent's 40 / 100).
        pso_rotation_range_rad, pso_translation_range_m: PSO search range around the coarse
            pre-registration (defaults 5 degrees and 2 % of the model's size).
        pso_fitness: ``"exact"`` (patent: nearest model points) or ``"field"`` (coarse field).

    Returns:
        GlobalLocalizationResult (a LocalizationResult with ``success``, ``ambiguous``,
        ``equivalent_poses``, ``candidates`` and ``extra``). ``status`` begins with ``"ok"``,
        ``"ambiguous"``, ``"unobservable"`` or ``"failed"``.
    """
    t0 = time.perf_counter()
    if method not in GLOBAL_METHODS:
        raise AlgorithmError(f"method must be one of {', '.join(GLOBAL_METHODS)}; got {method!r}")
    y = _check_points(points)
    if rng is None:
        rng = np.random.default_rng(0)
    elif not isinstance(rng, np.random.Generator):
        raise AlgorithmError(f"rng must be a numpy.random.Generator or None, got {type(rng).__name__}")
    if index is None:
        if mesh is None:
            raise AlgorithmError("give a mesh (or a prebuilt index)")
        index = MeshIndex(mesh)
    if mesh is None:
        mesh = index.mesh
    if noise_sigma_m is not None and not (np.isfinite(noise_sigma_m) and noise_sigma_m >= 0):
        raise AlgorithmError(f"noise_sigma_m must be a length >= 0 [m] or None, got {noise_sigma_m}")
    if not (np.isfinite(model_error_m) and model_error_m >= 0):
        raise AlgorithmError(f"model_error_m must be a length >= 0 [m], got {model_error_m}")
    if ga_mutation not in ("per_bit", "per_chromosome"):
        raise AlgorithmError(f"ga_mutation must be 'per_bit' or 'per_chromosome', got {ga_mutation!r}")
    if pso_fitness not in ("exact", "field"):
        raise AlgorithmError(f"pso_fitness must be 'exact' or 'field', got {pso_fitness!r}")
    for name, v, lo in (
        ("n_coarse", n_coarse, 6),
        ("n_verify", n_verify, 6),
        ("max_candidates", max_candidates, 1),
        ("ga_bits", ga_bits, 2),
        ("ga_population", ga_population, 2),
        ("ga_generations", ga_generations, 1),
        ("ga_restarts", ga_restarts, 1),
        ("pso_particles", pso_particles, 1),
        ("pso_iterations", pso_iterations, 1),
    ):
        if int(v) < lo:
            raise AlgorithmError(f"{name} must be >= {lo}, got {v}")
    R0 = orientation_table(start_table)

    extent = float(index.extent)
    c_model = _model_centroid(mesh)
    cfield = _coarse_field(mesh)
    exact = _ExactOracle(index)
    timings = {}

    idx_c = _farthest_point_subset(y, int(n_coarse))
    y_c = y[idx_c]
    if len(y) > n_verify:
        y_v = y[np.sort(rng.choice(len(y), size=int(n_verify), replace=False))]
    else:
        y_v = y
    dc = y_c - y_c.mean(axis=0)
    L = float(np.sqrt(np.mean(np.einsum("ij,ij->i", dc, dc)))) or extent
    sigma_known = noise_sigma_m is not None
    if sigma_known:
        sig_eff = math.hypot(float(noise_sigma_m), model_error_m)
        # the field's own error is heavy-tailed (exact for most points, up to a few cells near
        # edges): the RMS over a 150-point subset reaches about twice its floor
        delta2_field = len(y_c) * (NOISE_ACCEPT_FACTOR * sig_eff + FIELD_FLOOR_FACTOR * cfield.floor_rms) ** 2
    else:
        sig_eff = None
        delta2_field = np.inf
    extra: dict = {"method": method, "polish": polish, "field_cell_m": cfield.cell}

    # ---------------------------------------------------------------- search
    primary = None  # GA / PSO: the method's own result before verification
    t = time.perf_counter()
    need_multistart = method in ("multistart", "pso", "genetic")
    lanes = None
    if need_multistart:
        lanes = _multistart_coarse(cfield, y_c, R0, c_model, L, delta2_field, rng, stop_at_first and method == "multistart")
        extra["second_round"] = False
        if (
            sigma_known
            and not lanes.accepted.any()
            and isinstance(start_table, str)
            and start_table == "icosahedral"
        ):
            # no start reached the noise level: try the offset table as well (more initial poses)
            R1 = R0 @ Rotation.from_rotvec(SECOND_ROUND_ROTVEC).as_matrix()
            more = _multistart_coarse(cfield, y_c, R1, c_model, L, delta2_field, rng, False)
            lanes = _LaneResult(
                np.concatenate([lanes.T, more.T]),
                np.concatenate([lanes.eps, more.eps]),
                np.concatenate([lanes.accepted, more.accepted]),
                np.concatenate([lanes.iterations, more.iterations]),
                np.concatenate([lanes.perturbations, more.perturbations]),
                None,
            )
            R0 = np.concatenate([R0, R1])
            extra["second_round"] = True
        extra["n_starts"] = len(R0)
        extra["starts_accepted"] = int(lanes.accepted.sum())
        extra["coarse_iterations"] = int(lanes.iterations.sum())
        extra["perturbations"] = int(lanes.perturbations.sum())
    timings["coarse_multistart_s"] = time.perf_counter() - t

    if method == "genetic":
        t = time.perf_counter()
        half_size = 0.5 * np.ptp(np.asarray(mesh.vertices, dtype=np.float64), axis=0)
        runs = []
        for run in range(int(ga_restarts)):
            T_ga, fit, gens, hist, hall = _genetic(
                cfield,
                y_c,
                c_model,
                half_size,
                rng,
                nbits=int(ga_bits),
                mutation=ga_mutation,
                population=int(ga_population),
                generations=int(ga_generations),
            )
            # Algorithm 5's acceptance applied to the GA: a short exact descent from the
            # coarse pose; a residual above the noise means the GA found a wrong basin
            chk = _descend(exact, y_c, T_ga[None], L=L, delta1=1e-9, delta2=np.inf, delta3=1e-9,
                           max_iter_per_descent=30, rng=None)
            rms_chk = math.sqrt(float(chk.eps[0]) / len(y_c))
            runs.append((rms_chk, T_ga, fit, gens, hist))
            if not sigma_known or rms_chk <= NOISE_ACCEPT_FACTOR * sig_eff:
                break
        rms_chk, T_ga, fit, gens, hist = min(runs, key=lambda z: z[0])
        timings["ga_s"] = time.perf_counter() - t
        extra.update(
            ga_best_fitness=fit,
            ga_generations=gens,
            ga_fitness_history=hist,
            ga_runs=len(runs),
            ga_run_check_rms_m=[r[0] for r in runs],
            T_coarse=T_ga,
            ga_bits=int(ga_bits),
            ga_mutation=ga_mutation,
        )
        t = time.perf_counter()
        # document 001's fine stage works on a few probe points (m >= 6): the coarse subset
        # d of document 001's stop test: sum dtheta^2 + sum dDelta^2 < FINE_001_D (steps below
        # 1e-8 rad / 1e-8 m; the polish that follows converges quadratically from there)
        fine = localize(y_c, method="fine_001", init=T_ga, index=index, sigma=noise_sigma_m or None,
                        outlier=outlier, tolerance=FINE_001_D, max_iterations=FINE_001_MAX_ITERATIONS)
        timings["fine_001_s"] = time.perf_counter() - t
        primary = fine.T_world_workpiece
        extra["T_fine"] = primary @ inv_pose(T_ga)
        extra["fine_001_rmse_m"] = fine.rmse_m
        extra["fine_001_iterations"] = fine.iterations
    elif method == "pso":
        order = np.argsort(lanes.eps)
        T_init = lanes.T[order[0]]
        t = time.perf_counter()
        trange = 0.02 * extent if pso_translation_range_m is None else float(pso_translation_range_m)
        oracle = exact if pso_fitness == "exact" else cfield
        T_pso, gbest, gbest_f, hist, pbest_T = _pso(
            oracle,
            y_c,
            T_init,
            L,
            rng,
            rot_range=float(pso_rotation_range_rad),
            trans_range=trange,
            particles=int(pso_particles),
            iterations=int(pso_iterations),
        )
        timings["pso_s"] = time.perf_counter() - t
        primary = T_pso
        extra.update(
            T_initial=T_init,
            pso_only_T=T_pso,
            pso_best_vector=gbest,
            pso_best_fitness_m2=gbest_f,
            pso_fitness_history=hist,
            pso_rotation_range_rad=float(pso_rotation_range_rad),
            pso_translation_range_m=trange,
            pso_fitness=pso_fitness,
        )

    # ---------------------------------------------------------------- candidates
    t = time.perf_counter()
    cand_T = []
    if primary is not None:
        cand_T.append(primary)
    if lanes is not None:
        order = np.argsort(lanes.eps)
        pick = _distinct(lanes.T, order, extent, int(max_candidates))
        cand_T.extend(lanes.T[i] for i in pick)
    cand_T = np.asarray(cand_T)
    keep = _distinct(cand_T, np.arange(len(cand_T)), extent, len(cand_T))
    cand_T = cand_T[keep]
    ref = _descend(
        exact,
        y_v,
        cand_T,
        L=L,
        delta1=1e-6,
        delta2=np.inf,
        delta3=1e-7,
        max_iter_per_descent=15,
        rng=None,
    )
    timings["refine_s"] = time.perf_counter() - t
    refined_T, refined_eps = ref.T, ref.eps

    # ---------------------------------------------------------------- the answer and polish
    t = time.perf_counter()
    if primary is not None:
        T_best = primary
    else:
        T_best = refined_T[int(np.argmin(refined_eps))]
    if polish is not None:
        res = localize(y, method=polish, init=T_best, index=index, sigma=noise_sigma_m or None, outlier=outlier)
    else:
        res = localize(y, method=DEFAULT_POLISH, init=T_best, index=index, sigma=noise_sigma_m or None,
                       outlier=outlier, max_iterations=1)
        res = replace(res, T_world_workpiece=T_best)
    timings["polish_s"] = time.perf_counter() - t
    T_final = res.T_world_workpiece

    # ---------------------------------------------------------------- verification
    x = (y_v - T_final[:3, 3]) @ T_final[:3, :3]
    eps_final = float(np.sum(index.query(x).distance ** 2))
    nv = len(y_v)
    if not sigma_known:
        sig_eff = math.hypot(math.sqrt(eps_final / max(nv - 6, 1)), model_error_m)
    thr = AMBIGUITY_CHI2 * sig_eff**2
    rms_final = math.sqrt(eps_final / nv)
    consistent = rms_final <= NOISE_ACCEPT_FACTOR * sig_eff
    # distinct from the answer and from each other (refinement can merge coarse minima)
    others = []
    for i in np.argsort(refined_eps):
        T, e = refined_T[i], float(refined_eps[i])
        if np.isfinite(e) and _is_distinct(T, T_final, extent) and all(
            _is_distinct(T, To, extent) for _, To in others
        ):
            others.append((e, T))
    equivalent = [T_final] + [T for e, T in others if abs(e - eps_final) <= thr]
    better = [T for e, T in others if e < eps_final - thr]
    ambiguous = len(equivalent) > 1
    candidates = [(T_final, rms_final)] + [(T, math.sqrt(e / nv)) for e, T in others]
    if better:
        status = (
            f"failed: a distinct pose fits better (rms {math.sqrt(others[0][0] / nv):.3g} m vs "
            f"{rms_final:.3g} m): the {method} search ended in a local minimum"
        )
    elif not consistent:
        status = (
            f"failed: rms residual {rms_final:.3g} m is above {NOISE_ACCEPT_FACTOR:g} x the expected "
            f"noise {sig_eff:.3g} m: no start reached the true pose (or the points have outliers)"
        )
    elif ambiguous:
        status = (
            f"ambiguous: {len(equivalent)} distinct poses fit equally well (rms within the noise "
            f"{sig_eff:.3g} m): the part is symmetric for these points; equivalent_poses lists them"
        )
    elif not res.observable:
        status = "unobservable: " + res.status.split(":", 1)[-1].strip()
    else:
        status = (
            f"ok: unique pose, rms {rms_final:.3g} m consistent with the noise {sig_eff:.3g} m; "
            f"second-best distinct pose rms "
            + (f"{math.sqrt(others[0][0] / nv):.3g} m" if others else "none found")
        )
    success = status.startswith("ok")
    extra.update(
        timings_s=timings,
        sigma_eff_m=sig_eff,
        sigma_known=sigma_known,
        rms_verify_m=rms_final,
        n_verify=nv,
        n_coarse=len(y_c),
        polish_status=res.status,
    )
    base = {f: getattr(res, f) for f in res.__dataclass_fields__}
    base.update(
        T_world_workpiece=T_final,
        method=method,
        status=status,
        time_s=time.perf_counter() - t0,
        success=success,
        ambiguous=ambiguous,
        equivalent_poses=tuple(equivalent),
        candidates=tuple(candidates),
        extra=extra,
    )
    return GlobalLocalizationResult(**base)
