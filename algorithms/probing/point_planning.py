"""Planned fine probe points: where to touch a part to localize it best.

Document 001's fine stage probes a handful of hand-picked points and fits the pose to them.
Here the points are chosen: candidates are spread over the CAD surface
(:func:`sample_candidates`), those the probe cannot reach are removed
(:func:`feasible_candidates`), and of the rest ``m`` are picked to maximise the information
they give about the pose (:func:`d_optimal`).

Information. A touch at model point ``p`` with outward unit normal ``n`` measures the pose
along the row ``g = [p x n, n]`` (:func:`algorithms.registration.uncertainty.information_rows`),
so ``m`` touches with noise ``sigma`` along their normals give the pose twist ``[omega, v]``
the covariance ``sigma^2 (sum g_i g_i^T)^-1``. A D-optimal design maximises
``log det sum g_i g_i^T``, i.e. minimises the volume of the confidence ellipsoid. Moving the
reference point of the rotation from the origin to ``c`` multiplies every row by the same
matrix of determinant 1, so the log-determinant does not depend on it; the rows here are taken
about the centroid of the candidates (or of the points) to keep the 6x6 matrices well
conditioned.

Everything is in the workpiece (mesh) frame, in metres.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray, IntArray
from algorithms.errors import AlgorithmError
from algorithms.registration.uncertainty import information_rows, sym_inverse

if TYPE_CHECKING:
    from algorithms.geometry.mesh_index import MeshIndex

__all__ = [
    "REASONS",
    "Candidates",
    "Feasibility",
    "d_optimal",
    "feasible_candidates",
    "log_det_information",
    "predicted_pose_std",
    "random_points",
    "sample_candidates",
    "spread_points",
]

#: Most uniform samples :func:`sample_candidates` draws before thinning.
MAX_RAW_SAMPLES = 2_000_000
#: Ridge added to the information while fewer than 6 points are chosen, relative to the
#: trace of the information of all allowed candidates: it makes the greedy step prefer the
#: candidate that adds a new direction, and is far below any real eigenvalue.
RIDGE_REL = 1e-12
#: An exchange is made only if it raises the log-determinant by more than this.
EXCHANGE_GAIN = 1e-9
MAX_EXCHANGE_PASSES = 20
#: The information is singular when its smallest eigenvalue, in consistent units (rotations
#: scaled by the RMS distance from the centroid), is below this fraction of the largest.
SINGULAR_REL = 1e-10

#: Reason codes of :func:`feasible_candidates`, by index (``reason == 0``: feasible).
REASONS = ("ok", "faces_away", "near_edge", "ball_blocked", "stylus_collision")
#: Tangent directions tried around a point by the edge test.
EDGE_DIRECTIONS = 8
#: Tolerance [m] of the ball tests: a ball touching only at its contact point is not blocked.
BALL_TOL_M = 1e-6
#: Longest step [m] between samples along the stylus and body.
MAX_SAMPLE_STEP_M = 1e-3
#: Most sample points sent to one signed-distance query (bounds the memory of the stylus test).
MAX_QUERY_POINTS = 2_000_000


@dataclass(frozen=True)
class Candidates:
    """Candidate probe points on a mesh (workpiece frame).

    Attributes:
        points: (N, 3) [m] points on the surface.
        normals: (N, 3) outward unit normals of the faces they lie on.
        faces: (N,) index of each point's face.
    """

    points: FloatArray
    normals: FloatArray
    faces: IntArray


@dataclass(frozen=True)
class Feasibility:
    """Which candidates a probe can touch (see :func:`feasible_candidates`).

    Attributes:
        mask: (N,) True where the candidate is feasible.
        reason: (N,) int code, an index into ``REASONS`` (0 = ``"ok"``): the first test the
            candidate failed.
        counts: how many candidates each reason got, for every name in ``REASONS``; the
            counts sum to N.
    """

    mask: BoolArray
    reason: IntArray
    counts: dict[str, int]


# ------------------------------------------------------------------------------ candidates
def sample_candidates(mesh: trimesh.Trimesh, spacing_m: float, rng: np.random.Generator) -> Candidates:
    """Points spread over a mesh's surface about ``spacing_m`` apart, with their face normals.

    Random sequential sampling: ``4 area / spacing^2`` uniform samples
    (``trimesh.sample.sample_surface``), thinned in turn so that no two are closer than
    ``spacing_m``; about ``0.5 area / spacing^2`` remain. The normals are
    the faces' (facets on a tessellated curved surface; use
    :meth:`MeshIndex.smooth_normals` where the ideal surface's are wanted).

    Args:
        mesh: ``trimesh.Trimesh`` in the workpiece frame [m].
        spacing_m: smallest distance between two candidates [m].
        rng: the random stream.

    Raises:
        AlgorithmError: a mesh without area, a spacing that is not a positive finite length
            or so small that more than two million samples would be drawn.
    """
    if not isinstance(rng, np.random.Generator):
        raise AlgorithmError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if not (np.isfinite(spacing_m) and spacing_m > 0):
        raise AlgorithmError(f"spacing_m must be a positive finite length [m], got {spacing_m}")
    area = float(getattr(mesh, "area", 0.0))
    if not area > 0:
        raise AlgorithmError("mesh must be a trimesh.Trimesh with a positive surface area")
    count = int(np.ceil(4.0 * area / spacing_m**2))
    if count > MAX_RAW_SAMPLES:
        raise AlgorithmError(f"spacing_m = {spacing_m} m would draw {count} samples on {area:.3g} m^2; "
                             f"allowed: at most {MAX_RAW_SAMPLES}")
    raw, face = trimesh.sample.sample_surface(mesh, count, seed=rng)
    raw = np.asarray(raw, dtype=np.float64)
    keep = _thin(raw, spacing_m)
    faces = np.asarray(face, dtype=np.int64)[keep]
    normals = np.asarray(mesh.face_normals, dtype=np.float64)[faces]
    return Candidates(points=raw[keep], normals=normals, faces=faces)


def _thin(points: FloatArray, spacing_m: float) -> IntArray:
    """Indices of a subset with no two points closer than ``spacing_m``: each point in turn
    is kept unless a kept one is that close (random sequential adsorption).

    ``trimesh.points.remove_close`` drops one point of every close pair at once, which also
    drops points whose only close neighbour is dropped too: it thins far more (the counts are
    in ``benchmarks/results_history_symmetric_paths.md``).
    """
    pairs = cKDTree(points).query_pairs(spacing_m, output_type="ndarray")
    first = np.concatenate([pairs[:, 0], pairs[:, 1]])
    second = np.concatenate([pairs[:, 1], pairs[:, 0]])
    order = np.argsort(first, kind="stable")
    neighbours = second[order]
    start = np.concatenate([[0], np.cumsum(np.bincount(first, minlength=len(points)))])
    removed = np.zeros(len(points), dtype=bool)
    keep = []
    for i in range(len(points)):
        if not removed[i]:
            keep.append(i)
            removed[neighbours[start[i]:start[i + 1]]] = True
    return np.array(keep, dtype=np.int64)


# --------------------------------------------------------------------------- information
def _rows_about_centroid(points: ArrayLike, normals: ArrayLike, centre: FloatArray | None = None) -> FloatArray:
    """Information rows (N, 6) with the rotation about ``centre`` (default: the centroid)."""
    p = np.asarray(points, dtype=np.float64)
    c = p.mean(axis=0) if centre is None else centre
    return information_rows(p - c, normals)


def log_det_information(points: ArrayLike, normals: ArrayLike) -> float:
    """``log det sum g_i g_i^T`` of the information rows (-inf when singular).

    Args:
        points: (N, 3) [m] model points, workpiece frame, N >= 6.
        normals: (N, 3) their outward unit normals.
    """
    G = _rows_about_centroid(points, normals)
    sign, value = np.linalg.slogdet(G.T @ G)
    return float(value) if sign > 0 else -np.inf


def predicted_pose_std(points: ArrayLike, normals: ArrayLike, sigma_m: float) -> FloatArray:
    """Predicted standard deviations (6,) of the pose twist ``[omega (rad), v (m)]``.

    The square roots of the diagonal of ``sigma^2 (J^T J)^-1`` with rows
    ``[(p_i - c) x n_i, n_i]``, ``c`` the centroid of the points: the translation part is
    that of the point at the centroid (about the workpiece origin it would also carry the
    lever arm of the rotation). Assumes independent noise ``sigma_m`` along the normals.

    Args:
        points: (N, 3) [m] model points, workpiece frame, N >= 6.
        normals: (N, 3) their outward unit normals.
        sigma_m: standard deviation of one touch along its normal [m].

    Raises:
        AlgorithmError: a bad sigma, or points that do not fix all six pose directions.
    """
    if not (np.isfinite(sigma_m) and sigma_m > 0):
        raise AlgorithmError(f"sigma_m must be a positive finite length [m], got {sigma_m}")
    G = _rows_about_centroid(points, normals)
    if _is_singular(G):
        raise AlgorithmError("the points do not fix all six pose directions: the information is singular")
    return np.sqrt(np.diag(sym_inverse(G.T @ G))) * float(sigma_m)


def _is_singular(G: FloatArray) -> bool:
    """Whether rows ``[(p - c) x n, n]`` about the centroid leave a pose direction free."""
    # consistent units (as in uncertainty.observability): rotations times the RMS lever arm
    scale = np.sqrt(np.mean(np.sum(G[:, :3] ** 2, axis=1)))
    H = G.copy()
    if scale > 0:
        H[:, :3] /= scale
    w = np.linalg.eigvalsh(H.T @ H)
    return bool(w[0] <= SINGULAR_REL * w[-1])


# ------------------------------------------------------------------------------ selection
def _allowed(n_candidates: int, m: int, candidates_mask: ArrayLike | None) -> IntArray:
    """Checked indices of the allowed candidates, at least ``m`` of them."""
    if isinstance(m, bool) or not isinstance(m, int | np.integer) or m < 1:
        raise AlgorithmError(f"m must be a positive integer, got {m!r}")
    if candidates_mask is None:
        allowed = np.arange(n_candidates)
    else:
        mask = np.asarray(candidates_mask)
        if mask.dtype != bool or mask.shape != (n_candidates,):
            raise AlgorithmError(f"candidates_mask must be a bool array of shape ({n_candidates},), got "
                                 f"{mask.dtype} {mask.shape}")
        allowed = np.flatnonzero(mask)
    if len(allowed) < m:
        raise AlgorithmError(f"m = {m} points requested but only {len(allowed)} candidates are allowed")
    return allowed


def d_optimal(points: ArrayLike, normals: ArrayLike, m: int, *, candidates_mask: ArrayLike | None = None,
              max_passes: int = MAX_EXCHANGE_PASSES) -> IntArray:
    """Choose ``m`` candidates maximising ``log det sum g_i g_i^T`` (D-optimal design).

    Greedy forward selection (each step adds the candidate with the largest
    ``g^T M^-1 g``, i.e. the largest rise of the log-determinant; a ridge of
    ``RIDGE_REL`` times the trace keeps ``M`` invertible until six are chosen), then
    Fedorov exchange passes: each chosen point in turn is swapped for the unchosen one that
    raises the log-determinant most, when that is more than ``EXCHANGE_GAIN``; passes stop
    when one swaps nothing, or after ``max_passes``. Deterministic (ties go to the lower
    index).

    Args:
        points: (N, 3) [m] candidate points, workpiece frame.
        normals: (N, 3) their outward unit normals.
        m: number of points to choose, >= 6.
        candidates_mask: optional (N,) bool, the candidates allowed (e.g. the feasible ones).
        max_passes: exchange passes at most (0: greedy selection alone).

    Returns:
        (m,) int indices into the candidates, in the order chosen and then exchanged.

    Raises:
        AlgorithmError: bad shapes, m < 6, fewer than m allowed candidates, or allowed
            candidates that cannot fix all six pose directions.
    """
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
        raise AlgorithmError(f"points and normals must both be (N, 3), got {p.shape} and {n.shape}")
    if isinstance(m, bool) or not isinstance(m, int | np.integer) or m < 6:
        raise AlgorithmError(f"m must be an integer >= 6 (six pose directions), got {m!r}")
    if isinstance(max_passes, bool) or not isinstance(max_passes, int | np.integer) or max_passes < 0:
        raise AlgorithmError(f"max_passes must be an integer >= 0, got {max_passes!r}")
    allowed = _allowed(len(p), m, candidates_mask)
    G = _rows_about_centroid(p[allowed], n[allowed])
    if _is_singular(G):
        raise AlgorithmError("the allowed candidates cannot fix all six pose directions (their information is "
                             "singular): allow candidates on surfaces facing more directions")
    chosen = _greedy(G, int(m))
    chosen = _exchange(G, chosen, int(max_passes))
    return allowed[chosen]


def _greedy(G: FloatArray, m: int) -> IntArray:
    """Greedy forward selection of ``m`` rows of G (indices into G)."""
    ridge = RIDGE_REL * float(np.einsum("ij,ij->", G, G)) * np.eye(6)
    chosen: list[int] = []
    free = np.ones(len(G), dtype=bool)
    M = np.zeros((6, 6))
    for _ in range(m):
        A = M + ridge if len(chosen) < 6 else M
        gain = np.einsum("ij,ji->i", G, np.linalg.solve(A, G.T))
        gain[~free] = -np.inf
        k = int(np.argmax(gain))
        chosen.append(k)
        free[k] = False
        M += np.outer(G[k], G[k])
    return np.array(chosen)


def _exchange(G: FloatArray, chosen: IntArray, max_passes: int) -> IntArray:
    """Fedorov exchange passes on a chosen set (indices into G)."""
    chosen = chosen.copy()
    free = np.ones(len(G), dtype=bool)
    free[chosen] = False
    if not free.any():
        return chosen
    for _ in range(max_passes):
        swapped = False
        for slot in range(len(chosen)):
            Gc = G[chosen]
            Minv = sym_inverse(Gc.T @ Gc)
            # det(M - g_i g_i^T + g_j g_j^T) / det(M) = (1 - d_i)(1 + d_j) + d_ij^2
            MinvG = G @ Minv
            i = chosen[slot]
            d = np.einsum("ij,ij->i", MinvG, G)
            d_ij = MinvG @ G[i]
            ratio = (1.0 - d[i]) * (1.0 + d) + d_ij**2
            ratio[~free] = -np.inf
            j = int(np.argmax(ratio))
            if ratio[j] > 0 and np.log(ratio[j]) > EXCHANGE_GAIN:
                chosen[slot] = j
                free[i], free[j] = True, False
                swapped = True
        if not swapped:
            break
    return chosen


def spread_points(points: ArrayLike, m: int, *, candidates_mask: ArrayLike | None = None) -> IntArray:
    """Farthest-point sampling of ``m`` candidates (a geometric, information-blind baseline).

    Starts from the allowed candidate farthest from their centroid, then repeatedly adds the
    one farthest from those chosen. Deterministic.

    Args:
        points: (N, 3) [m] candidate points.
        m: number of points to choose, >= 1.
        candidates_mask: optional (N,) bool, the candidates allowed.

    Returns:
        (m,) int indices into the candidates, in the order chosen.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise AlgorithmError(f"points must be (N, 3), got {p.shape}")
    allowed = _allowed(len(p), m, candidates_mask)
    q = p[allowed]
    k = int(np.argmax(np.linalg.norm(q - q.mean(axis=0), axis=1)))
    chosen = [k]
    nearest = np.linalg.norm(q - q[k], axis=1)
    for _ in range(int(m) - 1):
        k = int(np.argmax(nearest))
        chosen.append(k)
        nearest = np.minimum(nearest, np.linalg.norm(q - q[k], axis=1))
    return allowed[np.array(chosen)]


def random_points(n_candidates: int, m: int, rng: np.random.Generator, *,
                  candidates_mask: ArrayLike | None = None) -> IntArray:
    """``m`` distinct candidates drawn uniformly (a baseline).

    Args:
        n_candidates: number of candidates N.
        m: number of points to choose, >= 1.
        rng: the random stream.
        candidates_mask: optional (N,) bool, the candidates allowed.

    Returns:
        (m,) int indices into the candidates.
    """
    if not isinstance(rng, np.random.Generator):
        raise AlgorithmError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if isinstance(n_candidates, bool) or not isinstance(n_candidates, int | np.integer) or n_candidates < 1:
        raise AlgorithmError(f"n_candidates must be a positive integer, got {n_candidates!r}")
    allowed = _allowed(int(n_candidates), m, candidates_mask)
    return rng.choice(allowed, size=int(m), replace=False)


# ----------------------------------------------------------------------------- feasibility
def feasible_candidates(index: MeshIndex, points: ArrayLike, normals: ArrayLike, *, stylus_axis: ArrayLike,
                        ball_radius_m: float, stylus_radius_m: float, stylus_length_m: float, body_radius_m: float,
                        body_length_m: float, approach_m: float, search_m: float, edge_margin_m: float,
                        clearance_m: float, max_normal_change_deg: float = 10.0) -> Feasibility:
    """Which candidates a touch probe with a fixed stylus direction can touch.

    The probe approaches each point ``p`` along its normal ``n``: the ball centre (radius
    ``r``) moves from ``c0 = p + (r + approach_m) n`` through the touch position
    ``ct = p + r n`` toward the search end ``c1 = p + (r - search_m) n``, and stops at the
    touch. Relative to the part, the centre therefore stays between ``ct`` and
    ``c0 + search_m n``: if the part lies up to ``search_m`` farther away than at the
    estimated pose, the probe starts that much farther from it and touches it at ``ct``
    relative to it; it never reaches the points beyond ``ct`` of the part it touches. The
    ball and stylus tests sample that stretch (``c0 + search_m n`` to ``ct``), ball centres
    ``min(r, stylus_radius_m, body_radius_m, 1 mm) / 2`` apart.

    Tests, in order; a candidate gets the reason of the first it fails (each test runs on
    the candidates that passed the ones before, with one mesh query for all of them):

    1. ``"faces_away"``: ``-n`` is not a sense direction of the probe (``n . a > 0``, ``a``
       the stylus axis; see :mod:`algorithms.probing.pretravel`).
    2. ``"near_edge"``: the surface within ``edge_margin_m`` of ``p`` is not one smooth
       patch (normals within ``max_normal_change_deg``; see :meth:`_Probe.near_edge`).
    3. ``"ball_blocked"``: the ball would touch anything before ``ct``, or touches another
       surface too at ``ct`` (a groove narrower than the ball).
    4. ``"stylus_collision"``: the stylus (radius ``stylus_radius_m``, from the ball centre
       along ``-a`` to ``stylus_length_m``) or the probe body (the next ``body_length_m``,
       radius ``body_radius_m``) comes within ``clearance_m`` of the part at any sampled
       ball centre.

    Args:
        index: :class:`algorithms.geometry.mesh_index.MeshIndex` of the workpiece mesh
            (closed, for the signed distances), workpiece frame.
        points: (N, 3) [m] candidate points on the mesh.
        normals: (N, 3) their outward unit normals.
        stylus_axis: (3,) unit vector from the probe body to the ball (workpiece frame), the
            same for every point (e.g. straight down).
        ball_radius_m: ball radius ``r`` [m].
        stylus_radius_m: radius of the stylus stem [m].
        stylus_length_m: from the ball centre to the probe body [m], > ``r``.
        body_radius_m: radius of the probe body [m].
        body_length_m: length of the probe body checked [m].
        approach_m: start distance of the ball from the surface [m], >= 0.
        search_m: how far past the touch the probe searches [m], >= 0.
        edge_margin_m: radius of the smooth patch required around a point [m].
        clearance_m: least distance kept between stylus or body and the part [m], >= 0.
        max_normal_change_deg: largest normal change within the patch [deg], in (0, 90).

    Raises:
        AlgorithmError: bad shapes, non-unit normals or axis, or bad lengths.
    """
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    a = np.asarray(stylus_axis, dtype=np.float64)
    _check_feasibility_input(p, n, a, ball_radius_m=ball_radius_m, stylus_radius_m=stylus_radius_m,
                             stylus_length_m=stylus_length_m, body_radius_m=body_radius_m,
                             body_length_m=body_length_m, approach_m=approach_m, search_m=search_m,
                             edge_margin_m=edge_margin_m, clearance_m=clearance_m,
                             max_normal_change_deg=max_normal_change_deg)
    r = float(ball_radius_m)
    step = min(r, stylus_radius_m, body_radius_m, MAX_SAMPLE_STEP_M) / 2.0
    reach = approach_m + search_m
    axis_s, radius = _probe_samples(r, stylus_radius_m, stylus_length_m, body_radius_m, body_length_m)
    probe = _Probe(index=index, axis=a, ball_radius_m=r,
                   offsets=r + np.linspace(reach, 0.0, int(np.ceil(reach / step)) + 1),
                   axis_s=axis_s, threshold=radius + clearance_m, edge_margin_m=edge_margin_m,
                   max_normal_change_deg=max_normal_change_deg)
    # in the order of REASONS[1:]
    reason = _first_failed(p, n, (probe.faces_away, probe.near_edge, probe.ball_blocked, probe.collides))
    counts = {name: int(np.sum(reason == code)) for code, name in enumerate(REASONS)}
    return Feasibility(mask=reason == 0, reason=reason, counts=counts)


def _first_failed(p: FloatArray, n: FloatArray,
                  tests: tuple[Callable[[FloatArray, FloatArray], BoolArray], ...]) -> IntArray:
    """(N,) 1 + the index of the first test each point fails, 0 where it passes all; each
    test sees the points (k, 3) and normals (k, 3) that passed the ones before."""
    reason = np.zeros(len(p), dtype=np.int64)
    pending = np.arange(len(p))
    for code, failed in enumerate(tests, start=1):
        bad = failed(p[pending], n[pending])
        reason[pending[bad]] = code
        pending = pending[~bad]
    return reason


@dataclass(frozen=True)
class _Probe:
    """A touch probe's geometry and sweep, workpiece frame, metres.

    Attributes:
        index: the workpiece mesh.
        axis: (3,) unit stylus axis ``a``, from the body to the ball.
        ball_radius_m: ``r``.
        offsets: (K,) ball-centre heights above ``p`` along ``n``, from ``c0 + search_m n``
            down to ``ct`` (``r``, last).
        axis_s: (S,) distances of the stylus and body samples from the ball centre along ``-a``.
        threshold: (S,) their radii plus the clearance: a sample collides below it.
        edge_margin_m: radius of the smooth patch required around a point.
        max_normal_change_deg: largest normal change within the patch [deg].
    """

    index: MeshIndex
    axis: FloatArray
    ball_radius_m: float
    offsets: FloatArray
    axis_s: FloatArray
    threshold: FloatArray
    edge_margin_m: float
    max_normal_change_deg: float

    def faces_away(self, p: FloatArray, n: FloatArray) -> BoolArray:
        """(N,) bool: the motion ``u = -n`` is not a sense direction (``u . a < 0``)."""
        return n @ self.axis > 1e-9

    def near_edge(self, p: FloatArray, n: FloatArray) -> BoolArray:
        """(N,) bool: the surface within the margin of p is not one smooth patch (:func:`_near_edge`)."""
        return _near_edge(self.index, p, n, self.edge_margin_m, self.max_normal_change_deg)

    def ball_blocked(self, p: FloatArray, n: FloatArray) -> BoolArray:
        """(N,) bool: the ball meets the part on its way in, or at the touch elsewhere than p
        (:func:`_ball_blocked`)."""
        return _ball_blocked(self.index, p, n, self.ball_radius_m, self.offsets)

    def collides(self, p: FloatArray, n: FloatArray) -> BoolArray:
        """(N,) bool: a stylus or body sample comes within the clearance of the part
        (:func:`_probe_collides`)."""
        return _probe_collides(self.index, p, n, self.axis, self.offsets, self.axis_s, self.threshold)


def _check_feasibility_input(p: FloatArray, n: FloatArray, a: FloatArray, **lengths: float) -> None:
    if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
        raise AlgorithmError(f"points and normals must both be (N, 3), got {p.shape} and {n.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n))):
        raise AlgorithmError("points and normals must be finite")
    bad = np.abs(np.linalg.norm(n, axis=1) - 1.0) > 1e-6
    if bad.any():
        raise AlgorithmError(f"normals must be unit vectors: {int(bad.sum())} of {len(n)} are not")
    if a.shape != (3,) or not np.all(np.isfinite(a)) or abs(np.linalg.norm(a) - 1.0) > 1e-6:
        raise AlgorithmError(f"stylus_axis must be a (3,) unit vector, got {a!r}")
    for name, value in lengths.items():
        if not np.isfinite(value):
            raise AlgorithmError(f"{name} must be finite, got {value}")
    for name in ("ball_radius_m", "stylus_radius_m", "stylus_length_m", "body_radius_m", "body_length_m",
                 "edge_margin_m"):
        if not lengths[name] > 0:
            raise AlgorithmError(f"{name} must be a positive length [m], got {lengths[name]}")
    for name in ("approach_m", "search_m", "clearance_m"):
        if not lengths[name] >= 0:
            raise AlgorithmError(f"{name} must be a length >= 0 [m], got {lengths[name]}")
    if not lengths["stylus_length_m"] > lengths["ball_radius_m"]:
        raise AlgorithmError(f"stylus_length_m ({lengths['stylus_length_m']}) must exceed ball_radius_m "
                             f"({lengths['ball_radius_m']})")
    if not 0 < lengths["max_normal_change_deg"] < 90:
        raise AlgorithmError(f"max_normal_change_deg must be in (0, 90), got {lengths['max_normal_change_deg']}")


def _tangent_basis(n: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Two unit vectors (N, 3) each, orthogonal to each other and to the unit normals n."""
    # cross with the world axis least aligned with n, so the result never degenerates
    helper = np.eye(3)[np.argmin(np.abs(n), axis=1)]
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(n, e1)


def _near_edge(index: MeshIndex, p: FloatArray, n: FloatArray, margin: float, max_change_deg: float) -> BoolArray:
    """(N,) bool: the surface within ``margin`` [m] of p is not one smooth patch.

    The closest points of ``p + rho t_k`` for 8 tangent directions ``t_k``, with
    ``rho = margin / cos(22.5 deg)`` so that any straight edge within the margin is crossed
    by one of them, must lie within ``0.1 margin`` of the tangent plane, on faces whose
    normals are within ``max_change_deg`` of ``n``, and, where the query is off the surface,
    in a direction within that angle of ``n`` (off a face's edge the closest point is on the
    edge, in the tangent plane, on either face; the direction tells it apart from a smooth
    bend).
    """
    if len(p) == 0:
        return np.zeros(0, dtype=bool)
    e1, e2 = _tangent_basis(n)
    angles = 2.0 * np.pi * np.arange(EDGE_DIRECTIONS) / EDGE_DIRECTIONS
    rho = margin / np.cos(np.pi / EDGE_DIRECTIONS)
    t = np.cos(angles)[None, :, None] * e1[:, None, :] + np.sin(angles)[None, :, None] * e2[:, None, :]
    q = (p[:, None, :] + rho * t).reshape(-1, 3)
    nk = np.repeat(n, EDGE_DIRECTIONS, axis=0)
    pk = np.repeat(p, EDGE_DIRECTIONS, axis=0)
    cp = index.query(q)
    cos_max = np.cos(np.deg2rad(max_change_deg))
    off_plane = np.abs(np.einsum("ij,ij->i", cp.foot - pk, nk)) > 0.1 * margin
    turned = np.einsum("ij,ij->i", cp.normal, nk) < cos_max
    # a query off the surface by more than rounding: its offset must run along the normal
    off = cp.distance > 1e-9 * margin
    along = np.abs(np.einsum("ij,ij->i", q - cp.foot, nk)) >= cos_max * cp.distance
    bad = off_plane | turned | (off & ~along)
    return bad.reshape(-1, EDGE_DIRECTIONS).any(axis=1)


def _ball_blocked(index: MeshIndex, p: FloatArray, n: FloatArray, r: float, offsets: FloatArray) -> BoolArray:
    """(N,) bool: the ball meets the part on its way in, or at the touch elsewhere than p.

    The signed distance of the ball centres ``p + offsets n`` is below ``r - BALL_TOL_M``
    before the touch (the last offset excluded), or differs from ``r`` by more than
    ``BALL_TOL_M`` at it (the ball touches another surface too).
    """
    if len(p) == 0:
        return np.zeros(0, dtype=bool)
    centres = p[:, None, :] + offsets[None, :, None] * n[:, None, :]
    sd = index.signed_distance(centres.reshape(-1, 3)).reshape(len(p), len(offsets))
    return np.any(sd[:, :-1] < r - BALL_TOL_M, axis=1) | (np.abs(sd[:, -1] - r) > BALL_TOL_M)


def _probe_samples(r: float, stylus_radius: float, stylus_length: float, body_radius: float,
                   body_length: float) -> tuple[FloatArray, FloatArray]:
    """Distances (S,) [m] from the ball centre along -a of the stylus and body samples, and their radii (S,)."""
    stylus = np.linspace(r, stylus_length, int(np.ceil((stylus_length - r) / min(stylus_radius,
                                                                                  MAX_SAMPLE_STEP_M))) + 1)
    body = np.linspace(stylus_length, stylus_length + body_length,
                       int(np.ceil(body_length / min(body_radius, MAX_SAMPLE_STEP_M))) + 1)
    return (np.concatenate([stylus, body]),
            np.concatenate([np.full(len(stylus), stylus_radius), np.full(len(body), body_radius)]))


def _probe_collides(index: MeshIndex, p: FloatArray, n: FloatArray, a: FloatArray, offsets: FloatArray,
                    axis_s: FloatArray, threshold: FloatArray) -> BoolArray:
    """(N,) bool: a stylus or body sample comes within its threshold of the part.

    At every ball centre ``p + offsets n`` the stylus and body are sampled on their axis
    (``centre - axis_s a``, every ``min(radius, 1 mm)``); a sample collides when its signed
    distance is below its threshold (between samples a cylinder is approximated by spheres).
    The candidates go in groups of at most ``MAX_QUERY_POINTS`` samples.
    """
    if len(p) == 0:
        return np.zeros(0, dtype=bool)
    out = np.zeros(len(p), dtype=bool)
    lo_box, hi_box = np.asarray(index.mesh.bounds, dtype=np.float64)
    # candidates in groups, so the (group, K, S, 3) sample array stays within memory
    group = max(1, MAX_QUERY_POINTS // (len(offsets) * len(axis_s)))
    for lo in range(0, len(p), group):
        centres = p[lo:lo + group, None, :] + offsets[None, :, None] * n[lo:lo + group, None, :]   # (G, K, 3)
        samples = (centres[:, :, None, :] - axis_s[None, None, :, None] * a).reshape(-1, 3)        # (G*K*S, 3)
        thr = np.broadcast_to(threshold, (len(centres), len(offsets), len(axis_s))).reshape(-1)
        # A sample farther from the part's bounding box than its threshold cannot collide
        # (the signed distance outside is at least the distance to the box): no query.
        box = np.maximum(lo_box - samples, samples - hi_box).max(axis=1)
        near = box < thr
        hit = np.zeros(len(samples), dtype=bool)
        if near.any():
            hit[near] = index.signed_distance(samples[near]) < thr[near]
        out[lo:lo + group] = hit.reshape(len(centres), -1).any(axis=1)
    return out
