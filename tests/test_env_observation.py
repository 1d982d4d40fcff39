"""The active-localization observation's pieces (twin.env.observation): bounded, scale-free,
and saying which directions are known."""

import numpy as np
import pytest
import trimesh

from twin.env.observation import (
    NORMAL_BINS,
    covariance_features,
    coverage,
    flat,
    normal_bins,
    observation_space,
    scaled_joints,
    scaled_std,
    surface_shares,
)


def test_scaled_std_is_one_at_the_prior_zero_at_the_tolerance_and_clipped():
    prior, tol = np.array([1e-3]), np.array([1e-5])
    assert scaled_std(prior, prior, tol)[0] == pytest.approx(1.0)
    assert scaled_std(tol, prior, tol)[0] == pytest.approx(0.0)
    assert scaled_std(np.array([1e-4]), prior, tol)[0] == pytest.approx(0.5)
    assert scaled_std(np.array([1.0]), prior, tol)[0] == 1.0
    assert scaled_std(np.array([0.0]), prior, tol)[0] == -1.0


def test_covariance_features_recover_the_standard_deviations_and_a_correlation():
    std = np.array([1e-3, 2e-3, 3e-3, 1e-4, 2e-4, 3e-4])
    corr = np.eye(6)
    corr[2, 3] = corr[3, 2] = -0.8   # a turn about z traded against a shift along x
    C = corr * np.outer(std, std)
    prior, tol = np.array([1e-2] * 3 + [1e-3] * 3), np.array([1e-5] * 3 + [1e-6] * 3)
    s, c = covariance_features(C, prior, tol)
    assert s == pytest.approx(scaled_std(std, prior, tol))
    upper = np.triu_indices(6, 1)
    k = [i for i, (r, q) in enumerate(zip(*upper, strict=True)) if (r, q) == (2, 3)][0]
    assert c[k] == pytest.approx(-0.8) and np.abs(np.delete(c, k)).max() < 1e-12


def test_normal_bins_and_surface_shares_of_a_box():
    assert normal_bins(np.array([[0, 0, 1.0], [0, -1.0, 0], [0.6, 0.6, 0.53]])).tolist() == [2, 4, 13]
    box = trimesh.creation.box(extents=[0.1, 0.2, 0.4])
    share = surface_shares(box.face_normals, box.area_faces)
    # faces normal to x: 0.2 x 0.4 each, to y: 0.1 x 0.4, to z: 0.1 x 0.2 (total 0.14 m^2)
    assert share[[0, 3]] == pytest.approx([0.08 / 0.28] * 2)
    assert share[[2, 5]] == pytest.approx([0.02 / 0.28] * 2)
    assert share[6:].sum() == 0 and share.sum() == pytest.approx(1.0)
    assert len(NORMAL_BINS) == 14 and np.allclose(np.linalg.norm(NORMAL_BINS, axis=1), 1.0)


def test_coverage_and_joints_are_bounded():
    assert coverage(np.array([0, 30, 1e6])) == pytest.approx([0.0, 1 - np.exp(-1), 1.0])
    lo, hi = np.full(6, -np.pi), np.full(6, np.pi)
    assert scaled_joints(np.array([-np.pi, 0, np.pi, 10, -10, np.pi / 2]), lo, hi) == \
        pytest.approx([-1, 0, 1, 1, -1, 0.5])


def test_the_space_is_float32_bounded_and_flattens_as_gymnasium_does():
    import gymnasium as gym

    space = observation_space()
    assert all(b.dtype == np.float32 and b.low.min() >= -1 and b.high.max() <= 1 for b in space.spaces.values())
    x = space.sample()
    assert np.array_equal(flat(x), gym.spaces.flatten(space, x)) and flat(x).shape == (66,)
