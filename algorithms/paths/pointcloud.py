"""Scan-line point clouds (document 004, section 3.1): organise, filter, bound and simplify.

A laser displacement sensor swept along parallel passes gives a *scan-line* cloud: points
dense along each line (0.05 mm apart at 50 mm/s and 1 kHz) and sparse across (the line
spacing, 4 mm in document 004). Every step here keeps that structure: a :class:`LineCloud`
holds one ordered (n_i, 3) array per line, lines ordered across the part.

The steps and their parameters (the defaults are the ones ``twin run`` uses):

1. :func:`organize_scan_lines`: group the samples by their scan-line label, drop invalid
   (NaN/inf) samples and the samples between lines (label < 0), make every line run along a
   common direction (the principal direction of the lines; a line scanned the other way is
   reversed, its samples otherwise kept in acquisition order) and order the lines across it.
   A line with no valid point, or fewer
   than two lines, is an error naming the line (``empty="drop"`` drops empty lines instead).
2. :func:`remove_outliers`: a robust local-quadratic (Hampel-type) filter per line on the two
   coordinates across the line (``across`` and the height ``direction x across``, both
   functions of the position along the line): a least-squares quadratic over ``window_m`` of
   line (counted in samples at the line's median spacing, i.e. a Savitzky-Golay filter) is
   fitted around every sample, and samples whose residual norm exceeds ``k * sigma`` are
   rejected, with ``sigma = 1.4826 * median(|residual|)`` of the inliers (a robust Gaussian
   sigma) but a threshold never below ``min_residual_m``. A spike pulls the fit of its
   neighbours, so outliers are removed in passes (up to ``passes``, 8 by default): each pass
   weights out the samples above the threshold whose residual is the largest within their
   window (the spikes, not the neighbours they pull) and refits; the final test of every
   sample is against the last fit. A moving median would not do as the reference: on a
   sloped, densely sampled line each coordinate is monotone and the median returns the
   point itself, noise included.
3. :func:`extract_boundary`: split each line where consecutive points are more than
   ``max_gap_m`` apart (the beam leaving the part for the table, a hole, an occluded stretch)
   and keep the longest run: the part. The boundary polygon (:func:`boundary_polygon`) joins
   the first points of the lines and the last points in reverse order.
4. :func:`simplify_lines`: even spacing by bin averaging along the arc length: one point per
   ``spacing_m`` of line (the mean of the points in the bin). High-frequency noise is left to
   the per-line B-spline least-squares fit (:mod:`algorithms.paths.spline`), which is document
   004's smoothing step.

All points are in one frame (the robot base frame for a scan), in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.ndimage import correlate1d, maximum_filter1d

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray, IntArray
from algorithms.errors import AlgorithmError

# Outlier filter (Hampel) defaults.
OUTLIER_WINDOW_M = 0.001
OUTLIER_K = 5.0
OUTLIER_MIN_RESIDUAL_M = 5e-6
OUTLIER_PASSES = 8
# A gap wider than this splits a line (boundary extraction).
MAX_GAP_M = 0.002
# Bin length of the even-spacing simplification.
SIMPLIFY_SPACING_M = 0.0002
MIN_LINE_POINTS = 4
MAD_TO_SIGMA = 1.4826


class PointCloudError(AlgorithmError):
    """Bad scan-line input: empty lines, a single line, wrong shapes."""


@dataclass(frozen=True)
class LineCloud:
    """A scan-line cloud: ordered lines, ordered across the part.

    Attributes:
        lines: L arrays (n_i, 3) [m], each ordered along ``direction``.
        line_ids: (L,) the scan-line label each line came from.
        index: L arrays (n_i,) of row indices into the input points (-1 for points made by
            averaging or resampling).
        direction: (3,) unit along-line direction shared by all lines.
        across: (3,) unit direction in which the lines follow each other.
        removed: counts of dropped samples by reason (``invalid``, ``between_lines``,
            ``outliers``, ``off_part``, ``merged``), accumulated over the steps.
    """

    lines: tuple[FloatArray, ...]
    line_ids: IntArray
    index: tuple[IntArray, ...]
    direction: FloatArray
    across: FloatArray
    removed: dict[str, int] = field(default_factory=dict)

    @property
    def n_points(self) -> int:
        return int(sum(len(ln) for ln in self.lines))

    def stacked(self) -> FloatArray:
        """(N, 3) all points, line after line."""
        return np.concatenate(self.lines) if self.lines else np.empty((0, 3))

    def line_of_point(self) -> IntArray:
        """(N,) position of each stacked point's line in ``lines`` (0..L-1)."""
        return np.concatenate([np.full(len(ln), i) for i, ln in enumerate(self.lines)])


def _count(removed: dict[str, int], key: str, n: int) -> dict[str, int]:
    out = dict(removed)
    out[key] = out.get(key, 0) + int(n)
    return out


def organize_scan_lines(points: ArrayLike, line: ArrayLike, empty: str = "error", min_points: int = MIN_LINE_POINTS,
                        order: str = "input") -> LineCloud:
    """Group samples by scan line and order them along and across the lines.

    Args:
        points: (N, 3) [m] samples, NaN rows where the sensor gave no valid distance.
        line: (N,) int scan-line label per sample; negative between lines.
        empty: ``"error"`` (default): a line with fewer than ``min_points`` valid samples is
            an error naming it; ``"drop"``: such lines are dropped (and counted).
        min_points: fewest valid points a line must have.
        order: ``"input"`` (default): the samples of a line keep their acquisition order (a
            scan's samples come in time order), reversed where the line runs against the
            common direction; ``"projection"``: sorted by their position along the common
            direction (for points in no particular order). Acquisition order is the safer one
            for filtering: an outlier displaced across the line also moves along it and would
            be sorted in among the wrong neighbours.

    Returns:
        LineCloud with at least two lines.

    Raises:
        PointCloudError: shapes, no labelled line, an empty line (``empty="error"``), or
            fewer than two lines.
    """
    P, lab = _check_scan_input(points, line, empty, order)
    rows, line_ids, removed = _valid_lines(P, lab, empty, min_points)
    direction, across, means = _line_axes(P, rows)
    return _ordered_cloud(P, rows, line_ids, direction, across, means, order, removed)


def _check_scan_input(points: ArrayLike, line: ArrayLike, empty: str, order: str) -> tuple[FloatArray, IntArray]:
    P = np.asarray(points, dtype=np.float64)
    lab = np.asarray(line)
    if P.ndim != 2 or P.shape[1] != 3:
        raise PointCloudError(f"points must be (N, 3), got shape {P.shape}")
    if lab.shape != (len(P),) or not np.issubdtype(lab.dtype, np.integer):
        raise PointCloudError(
            f"line must be (N,) integers pairing with points (N = {len(P)}), got {lab.shape} {lab.dtype}"
        )
    if order not in ("input", "projection"):
        raise PointCloudError(f"order must be 'input' or 'projection', got {order!r}")
    if empty not in ("error", "drop"):
        raise PointCloudError(f"empty must be 'error' or 'drop', got {empty!r}")
    return P, lab


def _valid_lines(P: FloatArray, lab: IntArray, empty: str, min_points: int
                 ) -> tuple[list[IntArray], list[int], dict[str, int]]:
    """Rows of the finite samples of every line with at least ``min_points`` of them (in input
    order), the lines' labels, and the counts of the samples dropped.

    Raises:
        PointCloudError: no labelled sample, a line too short (``empty="error"``), or fewer
            than two lines left.
    """
    finite = np.all(np.isfinite(P), axis=1)
    on_line = lab >= 0
    labels = np.unique(lab[on_line])
    if len(labels) == 0:
        raise PointCloudError("no scan line: every sample has a negative line label")
    removed = {"invalid": int((~finite & on_line).sum()), "between_lines": int((~on_line).sum())}
    keep_idx, keep_ids = [], []
    for lid in labels:
        rows = np.flatnonzero((lab == lid) & finite)
        if len(rows) < min_points:
            total = int((lab == lid).sum())
            if empty == "error":
                raise PointCloudError(
                    f"scan line {int(lid)} has {len(rows)} valid points of {total} samples "
                    f"(at least {min_points} needed); drop it with empty='drop' or rescan"
                )
            removed = _count(removed, "empty_line_points", len(rows))
            continue
        keep_idx.append(rows)
        keep_ids.append(int(lid))
    if len(keep_idx) < 2:
        which = f"scan line {keep_ids[0]}" if keep_ids else "no line"
        raise PointCloudError(
            f"a scan-line cloud needs at least 2 lines with valid points, got {len(keep_idx)} "
            f"({which}): normals across lines cannot be formed"
        )
    return keep_idx, keep_ids, removed


def _line_axes(P: FloatArray, rows: list[IntArray]) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The unit along-line direction (3,), the unit across direction (3,) and the line means (L, 3).

    Along: the principal direction of the per-line spreads (pooled covariance of the lines
    about their own means), robust to the across-line spread of the raster. Across: the
    spread of the line means, orthogonal to it. Signs: along the first line's travel, across
    from the first line to the last.
    """
    C = np.zeros((3, 3))
    for r in rows:
        q = P[r] - P[r].mean(axis=0)
        C += q.T @ q
    _, V = np.linalg.eigh(C)
    direction = V[:, -1]
    means = np.array([P[r].mean(axis=0) for r in rows])
    dm = means - means.mean(axis=0)
    dm -= np.outer(dm @ direction, direction)
    if np.linalg.norm(dm) == 0:
        across = V[:, -2]
    else:
        _, _, vt = np.linalg.svd(dm, full_matrices=False)
        across = vt[0]
    first = P[rows[0]]
    if (first[-1] - first[0]) @ direction < 0:
        direction = -direction
    if (means[-1] - means[0]) @ across < 0:
        across = -across
    return direction, across, means


def _ordered_cloud(P: FloatArray, rows: list[IntArray], line_ids: list[int], direction: FloatArray,
                   across: FloatArray, means: FloatArray, order: str, removed: dict[str, int]) -> LineCloud:
    """The lines ordered across, their samples along ``direction`` (see ``order``)."""
    lines, idx = [], []
    line_order = np.argsort(means @ across, kind="stable")
    for k in line_order:
        r = rows[k]
        if order == "projection":
            r = r[np.argsort(P[r] @ direction, kind="stable")]
        elif (P[r[-1]] - P[r[0]]) @ direction < 0:
            r = r[::-1]
        lines.append(P[r])
        idx.append(r)
    return LineCloud(tuple(lines), np.array(line_ids)[line_order], tuple(idx), direction, across, removed)


def _local_quadratic(y: FloatArray, w: FloatArray, half: int) -> tuple[FloatArray, BoolArray]:
    """Weighted least-squares quadratic over +-``half`` samples around every sample, its value there.

    ``y`` (n, d), weights ``w`` (n,) (0 excludes a sample). With all weights 1 this is the
    Savitzky-Golay filter; zero weights leave the fit undisturbed by the excluded samples and
    near the ends the window is one-sided. Returns the fit and a mask of samples with enough
    support (at least 5 weighted samples in the window).
    """
    j = np.arange(-half, half + 1, dtype=np.float64)
    M = [correlate1d(w, j**k, mode="constant") for k in range(5)]
    wy = w[:, None] * y
    Bk = [correlate1d(wy, j**k, axis=0, mode="constant") for k in range(3)]
    A = np.stack([np.stack([M[0], M[1], M[2]], -1), np.stack([M[1], M[2], M[3]], -1),
                  np.stack([M[2], M[3], M[4]], -1)], -2)
    supported = M[0] >= 5
    A[~supported] = np.eye(3)
    rhs = np.stack(Bk, axis=1)  # (n, 3, d)
    fit = np.linalg.solve(A, rhs)[:, 0, :]
    fit[~supported] = y[~supported]
    return fit, supported


def _robust_mask(c: FloatArray, half: int, k: float, floor: float, passes: int) -> BoolArray:
    """Inliers of the (n, 2) cross-line coordinates ``c`` of an ordered line.

    The local fits run over the sample index (samples come evenly in time). Each pass
    excludes, among the samples above the threshold, those with the largest residual within
    their window (the spikes themselves, not the neighbours they pull), and refits; the
    final test is against the last fit.
    """
    if len(c) < 5:
        return np.ones(len(c), dtype=bool)
    half = min(half, (len(c) - 1) // 2)
    excluded = np.zeros(len(c), dtype=bool)
    for _ in range(passes):
        fit, _ = _local_quadratic(c, (~excluded).astype(np.float64), half)
        r = np.linalg.norm(c - fit, axis=1)
        thr = max(k * MAD_TO_SIGMA * np.median(r[~excluded]), floor)
        cand = np.where((r > thr) & ~excluded, r, 0.0)
        peaks = (cand > 0) & (cand >= maximum_filter1d(cand, 2 * half + 1, mode="constant"))
        if not peaks.any():
            break
        excluded |= peaks
    fit, _ = _local_quadratic(c, (~excluded).astype(np.float64), half)
    r = np.linalg.norm(c - fit, axis=1)
    thr = max(k * MAD_TO_SIGMA * np.median(r[~excluded]), floor)
    return r <= thr


def remove_outliers(cloud: LineCloud, window_m: float = OUTLIER_WINDOW_M, k: float = OUTLIER_K,
                    min_residual_m: float = OUTLIER_MIN_RESIDUAL_M, passes: int = OUTLIER_PASSES) -> LineCloud:
    """Robust local-quadratic outlier filter per line (see the module docstring)."""
    if not (window_m > 0 and k > 0 and min_residual_m >= 0 and passes >= 1):
        raise PointCloudError(
            f"outlier filter needs window_m > 0, k > 0, min_residual_m >= 0, passes >= 1; got "
            f"{window_m}, {k}, {min_residual_m}, {passes}"
        )
    a = cloud.across - (cloud.across @ cloud.direction) * cloud.direction
    a /= np.linalg.norm(a)
    cross = np.stack([a, np.cross(cloud.direction, a)])
    lines, idx = [], []
    n_out = 0
    for p, ix in zip(cloud.lines, cloud.index, strict=True):
        if len(p) >= 5:
            spacing = np.median(np.diff(p @ cloud.direction))
            half = int(max(2, round(0.5 * window_m / max(spacing, 1e-12))))
            ok = _robust_mask(p @ cross.T, half, k, min_residual_m, passes)
            n_out += int((~ok).sum())
            p, ix = p[ok], ix[ok]
        lines.append(p)
        idx.append(ix)
    return replace(cloud, lines=tuple(lines), index=tuple(idx), removed=_count(cloud.removed, "outliers", n_out))


def extract_boundary(cloud: LineCloud, max_gap_m: float = MAX_GAP_M, min_points: int = MIN_LINE_POINTS) -> LineCloud:
    """Keep, per line, the longest run of points with no gap above ``max_gap_m``.

    Raises:
        PointCloudError: a line keeps fewer than ``min_points`` points.
    """
    if not max_gap_m > 0:
        raise PointCloudError(f"max_gap_m must be > 0, got {max_gap_m}")
    lines, idx = [], []
    off = 0
    for lid, p, ix in zip(cloud.line_ids, cloud.lines, cloud.index, strict=True):
        gaps = np.linalg.norm(np.diff(p, axis=0), axis=1) > max_gap_m
        cuts = np.flatnonzero(gaps) + 1
        starts = np.concatenate([[0], cuts])
        ends = np.concatenate([cuts, [len(p)]])
        j = int(np.argmax(ends - starts))
        a, b = starts[j], ends[j]
        if b - a < min_points:
            raise PointCloudError(
                f"scan line {int(lid)} keeps only {b - a} points after splitting at gaps > {max_gap_m:g} m"
            )
        off += len(p) - (b - a)
        lines.append(p[a:b])
        idx.append(ix[a:b])
    return replace(cloud, lines=tuple(lines), index=tuple(idx), removed=_count(cloud.removed, "off_part", off))


def boundary_polygon(cloud: LineCloud) -> FloatArray:
    """(2L + 1, 3) closed boundary: the first points of the lines, then the last points backwards."""
    first = np.array([ln[0] for ln in cloud.lines])
    last = np.array([ln[-1] for ln in cloud.lines])
    ring = np.concatenate([first, last[::-1]])
    return np.vstack([ring, ring[:1]])


def simplify_lines(cloud: LineCloud, spacing_m: float = SIMPLIFY_SPACING_M) -> LineCloud:
    """Even spacing: the mean of the points in each ``spacing_m`` bin of arc length, per line."""
    if not spacing_m > 0:
        raise PointCloudError(f"spacing_m must be > 0, got {spacing_m}")
    lines, idx = [], []
    merged = 0
    for p in cloud.lines:
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        b = np.floor(s / spacing_m).astype(np.int64)
        _, inv, counts = np.unique(b, return_inverse=True, return_counts=True)
        sums = np.zeros((len(counts), 3))
        np.add.at(sums, inv, p)
        q = sums / counts[:, None]
        merged += len(p) - len(q)
        lines.append(q)
        idx.append(np.full(len(q), -1))
    return replace(cloud, lines=tuple(lines), index=tuple(idx), removed=_count(cloud.removed, "merged", merged))


@dataclass(frozen=True)
class CloudParams:
    """Parameters of :func:`prepare_scan_lines` (SI units)."""

    outlier_window_m: float = OUTLIER_WINDOW_M
    outlier_k: float = OUTLIER_K
    outlier_min_residual_m: float = OUTLIER_MIN_RESIDUAL_M
    max_gap_m: float = MAX_GAP_M
    simplify_spacing_m: float = SIMPLIFY_SPACING_M
    empty: str = "error"


def prepare_scan_lines(points: ArrayLike, line: ArrayLike, params: CloudParams = CloudParams()) -> LineCloud:
    """Steps 1-4 of the module docstring in order: organise, outliers, boundary, simplify."""
    cloud = organize_scan_lines(points, line, empty=params.empty)
    cloud = remove_outliers(cloud, params.outlier_window_m, params.outlier_k, params.outlier_min_residual_m)
    cloud = extract_boundary(cloud, params.max_gap_m)
    return simplify_lines(cloud, params.simplify_spacing_m)
