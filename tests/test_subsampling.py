"""Document 000's Algorithm 4 (pseudo-Hammersley subsampling) and its comparison samplers."""

import numpy as np
import pytest

from algorithms.errors import AlgorithmError
from algorithms.registration.subsampling import (
    bit_reverse,
    full_grid,
    pseudo_hammersley_columns,
    pseudo_hammersley_subsample,
    random_subsample,
    uniform_subsample,
)

# Worked by hand for the document's own 10 x 10 example (figure 1): N = 10, n = 3, k = 4.
# Row s: s-1 in 4 bits, mirrored -> m, offset ceil(10 m / 16), z = offset + 0/3/6, t = z or z mod 10.
HAND_10x10 = [
    [0, 3, 6],  # s=1:  0000 -> 0000 = 0,  offset 0
    [5, 8, 1],  # s=2:  0001 -> 1000 = 8,  offset 5;   z = 11 -> 1
    [3, 6, 9],  # s=3:  0010 -> 0100 = 4,  offset ceil(2.5) = 3
    [8, 1, 4],  # s=4:  0011 -> 1100 = 12, offset ceil(7.5) = 8;  z = 11, 14
    [2, 5, 8],  # s=5:  0100 -> 0010 = 2,  offset ceil(1.25) = 2
    [7, 10, 3],  # s=6: 0101 -> 1010 = 10, offset ceil(6.25) = 7; z = 10 stays, 13 -> 3
    [4, 7, 10],  # s=7: 0110 -> 0110 = 6,  offset ceil(3.75) = 4
    [9, 2, 5],  # s=8:  0111 -> 1110 = 14, offset ceil(8.75) = 9
    [1, 4, 7],  # s=9:  1000 -> 0001 = 1,  offset ceil(0.625) = 1
    [6, 9, 2],  # s=10: 1001 -> 1001 = 9,  offset ceil(5.625) = 6
]


def test_bit_reverse_examples():
    assert bit_reverse(1, 4) == 8
    assert bit_reverse(3, 4) == 12
    assert bit_reverse(6, 4) == 6
    assert bit_reverse(9, 4) == 9
    assert bit_reverse(0, 4) == 0
    assert bit_reverse(1, 3) == 4
    with pytest.raises(AlgorithmError):
        bit_reverse(16, 4)


def test_literal_formula_matches_hand_worked_10x10():
    t = pseudo_hammersley_columns(10, 10)
    np.testing.assert_array_equal(t, np.array(HAND_10x10))


def test_subsample_10x10_zero_column_is_column_N():
    sub = pseudo_hammersley_subsample(10, 10)
    expected_cols = (np.array(HAND_10x10) - 1) % 10  # t = 0 read as column N (0-based 9)
    np.testing.assert_array_equal(sub.cols.reshape(10, 3), expected_cols)
    np.testing.assert_array_equal(sub.rows, np.repeat(np.arange(10), 3))
    assert sub.cols[0] == 9
    assert sub.count == 30 and sub.fraction == pytest.approx(0.3)
    assert sub.duplicates_in_formula == 0
    # every column is used exactly 3 times over the 10 rows: the point of a Hammersley set
    assert np.all(np.bincount(sub.cols, minlength=10) == 3)


def test_hand_worked_12_columns_repeats_and_resolution():
    # N = 12: n = 4, k = 4. Row 1: z = 0, 4, 8, 12 -> t = 0, 4, 8, 12: 0 and 12 are both
    # column 12. Row 2: m = 8, offset 6, z = 6, 10, 14, 18 -> t = 6, 10, 2, 6: 6 repeats.
    t = pseudo_hammersley_columns(2, 12)
    np.testing.assert_array_equal(t, [[0, 4, 8, 12], [6, 10, 2, 6]])
    keep = pseudo_hammersley_subsample(2, 12, on_duplicate="keep")
    np.testing.assert_array_equal(keep.cols, [11, 3, 7, 11, 5, 9, 1, 5])
    assert keep.duplicates_in_formula == 2
    drop = pseudo_hammersley_subsample(2, 12, on_duplicate="drop")
    np.testing.assert_array_equal(drop.cols, [11, 3, 7, 5, 9, 1])
    nxt = pseudo_hammersley_subsample(2, 12, on_duplicate="next_free")
    np.testing.assert_array_equal(nxt.cols, [11, 3, 7, 0, 5, 9, 1, 6])


@pytest.mark.parametrize("M,N", [(1, 3), (3, 4), (7, 10), (10, 10), (16, 31), (20, 50), (64, 100), (30, 30)])
def test_counts_range_and_uniqueness(M, N):
    sub = pseudo_hammersley_subsample(M, N)
    n = N // 3
    assert sub.count == M * n
    assert sub.rows.min() >= 0 and sub.rows.max() < M
    assert sub.cols.min() >= 0 and sub.cols.max() < N
    for r in range(M):
        c = sub.cols[sub.rows == r]
        assert c.size == n and np.unique(c).size == n


@pytest.mark.parametrize("N", list(range(3, 61)))
def test_literal_rule_repeats_only_for_multiples_of_three_from_12(N):
    sub = pseudo_hammersley_subsample(min(N, 16), N, on_duplicate="keep")
    has_repeats = sub.duplicates_in_formula > 0
    assert has_repeats == (N % 3 == 0 and N >= 12)


def test_input_checks():
    with pytest.raises(AlgorithmError, match="M <= N"):
        pseudo_hammersley_subsample(11, 10)
    with pytest.raises(AlgorithmError, match="N >= 3|>= 3"):
        pseudo_hammersley_subsample(1, 2)
    with pytest.raises(AlgorithmError):
        pseudo_hammersley_subsample(3, 10, on_duplicate="ignore")
    with pytest.raises(AlgorithmError):
        random_subsample(3, 10, rng=0)


def test_uniform_and_random_same_count():
    M, N = 20, 40
    ph = pseudo_hammersley_subsample(M, N)
    un = uniform_subsample(M, N)
    rnd = random_subsample(M, N, np.random.default_rng(3))
    assert ph.count == un.count == rnd.count == M * (N // 3)
    assert np.unique(un.flat).size == un.count
    assert np.unique(rnd.flat).size == rnd.count
    assert rnd.flat.max() < M * N
    again = random_subsample(M, N, np.random.default_rng(3))
    np.testing.assert_array_equal(rnd.flat, again.flat)
    assert full_grid(M, N).count == M * N


def test_take_and_mask():
    grid = np.arange(10 * 10 * 3, dtype=float).reshape(10, 10, 3)
    sub = pseudo_hammersley_subsample(10, 10)
    pts = sub.take(grid)
    assert pts.shape == (30, 3)
    np.testing.assert_array_equal(pts, grid.reshape(-1, 3)[sub.flat])
    assert sub.mask().sum() == 30
    with pytest.raises(AlgorithmError):
        sub.take(np.zeros((9, 10, 3)))
