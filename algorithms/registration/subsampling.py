"""Subsampling of gridded measurements: document 000's pseudo-Hammersley rule (Algorithm 4).

Document 000 (Liu, Li, Dai 2001, section 7) measures a surface on a uniform ``M x N`` grid
(``M`` rows, ``N`` columns, ``M <= N``) and keeps, in every row ``s = 1..M``, the
``n = floor(N / 3)`` columns

    t_sj = z_sj               if z_sj <= N
           z_sj mod N         if z_sj >  N
    z_sj = ceil(N * m_(s-1) / 2^k) + (j - 1) * n,     j = 1..n,   k = ceil(log2 N)

where ``m_(s-1)`` is "the k-bit binary mirror of s - 1".

Readings (where the original leaves a choice):

* ``m_(s-1)`` is the *integer* whose k-bit binary expansion is that of ``s - 1`` reversed
  (``s - 1 = 0b0001``, k = 4 -> ``m = 0b1000 = 8``). Then ``m / 2^k`` is the base-2 radical
  inverse (van der Corput number) of ``s - 1`` in [0, 1), so ``ceil(N m / 2^k)`` is a
  row offset in ``0..N``: the Hammersley construction the name promises. Reading ``m`` as a
  binary fraction instead would divide by ``2^k`` twice and put every offset at 0 or 1.
  ``M <= N <= 2^k`` guarantees ``s - 1 < 2^k``, which is why the document asks for M <= N.
* Columns are 1-based in the document (``X(s, t)``, t = 1..N). ``z_sj = 0`` happens (s = 1,
  j = 1: ``m_0 = 0``), and ``z mod N = 0`` happens when z is a multiple of N. Neither is a
  valid 1-based column; both are read as the residue class of 0 mod N, i.e. column N. With
  that reading the 0-based column is simply ``(z_sj - 1) mod N`` for every z.
* ``floor`` and ``ceil`` are applied to non-negative numbers only, so the document's
  "floor toward zero" and the usual floor agree.
* Duplicates: with stride n and n columns a row spans n^2 ~ N^2/9 columns and wraps around.
  The literal rule then repeats a column within a row exactly when ``N`` is a multiple of 3
  and ``N >= 12`` (for N = 3n the step 3n = N is a whole turn). For every other N (the
  document's 10 x 10 example included) the n columns of a row are distinct. What to do with
  a repeat is not in the document; ``on_duplicate`` chooses: ``"next_free"`` (default) moves
  a repeated column to the next unused column of that row (cyclically), keeping the
  document's count of n per row; ``"drop"`` keeps each column once (fewer than n); ``"keep"``
  returns the literal formula, repeats included. When the rule has no repeats all three
  return the same indices.

Document 000 claims (section 9): with the subsampled data the localization keeps >= 90 % of
the full-data accuracy at 30-39 % of the time. ``python -m benchmarks.bench_subsampling`` measures it.

All indices returned here are 0-based (row, column) into the ``M x N`` grid, row-major flat
index ``row * N + col``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import ArrayLike, BoolArray, IntArray
from algorithms.errors import AlgorithmError

#: The choices of ``on_duplicate`` (module docstring).
ON_DUPLICATE = ("next_free", "drop", "keep")


@dataclass(frozen=True)
class GridSubsample:
    """A subset of an ``M x N`` grid.

    Attributes:
        rows: (K,) int64, 0-based row indices in ``0..M-1``.
        cols: (K,) int64, 0-based column indices in ``0..N-1``.
        shape: ``(M, N)`` of the grid.
        method: which rule made it (``"pseudo_hammersley"``, ``"uniform"``, ``"random"``).
        duplicates_in_formula: how many (row, column) repeats the literal formula produced
            before ``on_duplicate`` was applied (0 for the other methods).
    """

    rows: IntArray
    cols: IntArray
    shape: tuple[int, int]
    method: str
    duplicates_in_formula: int = 0

    @property
    def flat(self) -> IntArray:
        """(K,) row-major flat indices ``row * N + col`` into the grid."""
        return self.rows * self.shape[1] + self.cols

    @property
    def count(self) -> int:
        """K: the number of kept nodes."""
        return int(self.rows.size)

    @property
    def fraction(self) -> float:
        """Kept fraction of the grid."""
        return self.count / float(self.shape[0] * self.shape[1])

    def mask(self) -> BoolArray:
        """(M, N) bool mask of the kept grid nodes."""
        m = np.zeros(self.shape, dtype=bool)
        m[self.rows, self.cols] = True
        return m

    def take(self, grid_values: ArrayLike) -> np.ndarray:
        """Pick the kept nodes from an ``(M, N, ...)`` array -> ``(K, ...)``, of its dtype."""
        grid_values = np.asarray(grid_values)
        if grid_values.shape[:2] != self.shape:
            raise AlgorithmError(
                f"grid_values must start with the grid shape {self.shape}, "
                f"got {grid_values.shape}"
            )
        return grid_values[self.rows, self.cols]


def _check_grid(M: int, N: int, *, need_m_le_n: bool) -> tuple[int, int]:
    for name, v in (("M", M), ("N", N)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise AlgorithmError(f"{name} must be an integer, got {v!r}")
    M, N = int(M), int(N)
    if M < 1:
        raise AlgorithmError(f"M (rows) must be >= 1, got {M}")
    if N < 3:
        raise AlgorithmError(f"N (columns) must be >= 3 so that floor(N/3) >= 1, got {N}")
    if need_m_le_n and M > N:
        raise AlgorithmError(
            f"document 000's rule needs M <= N (rows <= columns), got M={M}, N={N}; "
            "transpose the grid so the longer direction is the columns"
        )
    return M, N


def bit_reverse(x: int, k: int) -> int:
    """The k-bit binary mirror of ``x``: ``bit_reverse(1, 4) == 8``; requires 0 <= x < 2^k."""
    if k < 0 or x < 0 or x >= (1 << k):
        raise AlgorithmError(f"bit_reverse needs 0 <= x < 2^k, got x={x}, k={k}")
    out = 0
    for _ in range(k):
        out = (out << 1) | (x & 1)
        x >>= 1
    return out


def pseudo_hammersley_columns(M: int, N: int) -> IntArray:
    """Document 000's ``t_sj`` exactly as written: (M, n) int array of 1-based columns.

    ``t_sj = 0`` is left as 0 here (the literal value); see the module docstring for how
    :func:`pseudo_hammersley_subsample` reads it (column N).
    """
    M, N = _check_grid(M, N, need_m_le_n=True)
    n = N // 3
    k = math.ceil(math.log2(N))
    t = np.empty((M, n), dtype=np.int64)
    for s in range(1, M + 1):
        m = bit_reverse(s - 1, k)
        offset = -((-N * m) // (1 << k))  # exact integer ceil(N * m / 2^k)
        z = offset + np.arange(n, dtype=np.int64) * n
        t[s - 1] = np.where(z <= N, z, z % N)
    return t


def pseudo_hammersley_subsample(M: int, N: int, *, on_duplicate: str = "next_free") -> GridSubsample:
    """Document 000's Algorithm 4 on an ``M x N`` grid (``M <= N``, ``N >= 3``).

    Args:
        M: number of rows (the shorter grid direction).
        N: number of columns.
        on_duplicate: ``"next_free"`` | ``"drop"`` | ``"keep"`` (see the module docstring;
            only matters when N is a multiple of 3 and N >= 12).

    Returns:
        GridSubsample with ``M * floor(N/3)`` nodes (fewer with ``"drop"`` when the rule
        repeats a column), row by row, columns in the order j = 1..n.
    """
    if on_duplicate not in ON_DUPLICATE:
        raise AlgorithmError(f"on_duplicate must be one of {ON_DUPLICATE}, got {on_duplicate!r}")
    t = pseudo_hammersley_columns(M, N)
    M, n = t.shape
    cols0 = (t - 1) % N  # 1-based -> 0-based; t = 0 (and z mod N = 0) is column N
    rows_out, cols_out = [], []
    n_dup = 0
    for r in range(M):
        row_cols = cols0[r]
        seen = np.zeros(N, dtype=bool)
        kept = []
        for c in row_cols:
            c = int(c)
            if seen[c]:
                n_dup += 1
                if on_duplicate == "drop":
                    continue
                if on_duplicate == "next_free":
                    while seen[c]:
                        c = (c + 1) % N
            seen[c] = True
            kept.append(c)
        rows_out.append(np.full(len(kept), r, dtype=np.int64))
        cols_out.append(np.asarray(kept, dtype=np.int64))
    return GridSubsample(
        rows=np.concatenate(rows_out),
        cols=np.concatenate(cols_out),
        shape=(M, N),
        method="pseudo_hammersley",
        duplicates_in_formula=n_dup,
    )


def uniform_subsample(M: int, N: int, per_row: int | None = None) -> GridSubsample:
    """A regular sub-grid with the same count as Algorithm 4: ``per_row`` evenly spaced columns
    (default ``floor(N/3)``), the same columns in every row.

    Columns are ``floor((j + 1/2) * N / per_row)``, j = 0..per_row-1 (centred strides).
    """
    M, N = _check_grid(M, N, need_m_le_n=False)
    n = N // 3 if per_row is None else int(per_row)
    if not 1 <= n <= N:
        raise AlgorithmError(f"per_row must be in 1..N={N}, got {per_row}")
    cols = np.floor((np.arange(n) + 0.5) * N / n).astype(np.int64)
    rows = np.repeat(np.arange(M, dtype=np.int64), n)
    return GridSubsample(rows=rows, cols=np.tile(cols, M), shape=(M, N), method="uniform")


def random_subsample(M: int, N: int, rng: np.random.Generator, count: int | None = None) -> GridSubsample:
    """``count`` grid nodes drawn uniformly without replacement (default ``M * floor(N/3)``,
    Algorithm 4's count), sorted row-major."""
    if not isinstance(rng, np.random.Generator):
        raise AlgorithmError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    M, N = _check_grid(M, N, need_m_le_n=False)
    K = M * (N // 3) if count is None else int(count)
    if not 1 <= K <= M * N:
        raise AlgorithmError(f"count must be in 1..M*N={M * N}, got {count}")
    flat = np.sort(rng.choice(M * N, size=K, replace=False)).astype(np.int64)
    return GridSubsample(rows=flat // N, cols=flat % N, shape=(M, N), method="random")


def full_grid(M: int, N: int) -> GridSubsample:
    """Every node of the grid (the reference the subsamples are compared with)."""
    M, N = _check_grid(M, N, need_m_le_n=False)
    flat = np.arange(M * N, dtype=np.int64)
    return GridSubsample(rows=flat // N, cols=flat % N, shape=(M, N), method="full")


__all__ = [
    "GridSubsample",
    "bit_reverse",
    "pseudo_hammersley_columns",
    "pseudo_hammersley_subsample",
    "uniform_subsample",
    "random_subsample",
    "full_grid",
]
