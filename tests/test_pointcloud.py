"""Scan-line clouds and per-line B-spline fits (document 004, section 3.1)."""

import dataclasses

import numpy as np
import pytest

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.paths.pointcloud import (
    PointCloudError,
    boundary_polygon,
    extract_boundary,
    organize_scan_lines,
    prepare_scan_lines,
    remove_outliers,
    simplify_lines,
)
from algorithms.paths.spline import SplineError, centripetal_parameters, fit_line, fit_lines
from tests.helpers import scenario
from tests.tolerances import ANALYTIC_CURVE_M, EVEN_SPACING_REL, ON_TRUE_SURFACE_M
from twin.realize import load_workpiece_mesh
from twin.scan import scan_scenario
from twin.sensors.laser import sensor_sigma_m


def raster(n_lines=4, n=400, spacing=0.004, length=0.1, z=lambda x, y: 0.01 * np.sin(40 * x) + 0.1 * y):
    """A synthetic boustrophedon scan: points, labels, with lines alternating direction."""
    pts, lab = [], []
    for i in range(n_lines):
        x = np.linspace(0, length, n)
        if i % 2:
            x = x[::-1]
        y = np.full(n, i * spacing)
        pts.append(np.column_stack([x, y, z(x, y)]))
        lab.append(np.full(n, i))
        pts.append(np.full((7, 3), 0.5))  # samples between lines
        lab.append(np.full(7, -1))
    return np.vstack(pts), np.concatenate(lab)


def test_scan_order_is_kept_and_reversed_lines_turned():
    P, lab = raster()
    c = organize_scan_lines(P, lab)
    for lid, line, ix in zip(c.line_ids, c.lines, c.index, strict=True):
        assert np.all(np.diff(line @ c.direction) > 0)
        # line 1 and 3 were scanned backwards: their samples come reversed, in one piece
        rows = np.flatnonzero(lab == lid)
        np.testing.assert_array_equal(ix, rows[::-1] if lid % 2 else rows)


def test_unordered_points_are_ordered_along_and_across():
    P, lab = raster()
    rng = np.random.default_rng(1)
    perm = rng.permutation(len(P))
    c = organize_scan_lines(P[perm], lab[perm], order="projection")
    assert len(c.lines) == 4 and c.removed["between_lines"] == 28
    for line in c.lines:
        assert np.all(np.diff(line @ c.direction) >= 0)
        assert np.all(np.diff(line[:, 0]) * np.sign(c.direction[0]) >= 0)
    across = [line.mean(axis=0) @ c.across for line in c.lines]
    assert np.all(np.diff(across) > 0)
    # indices point back into the input
    for line, ix in zip(c.lines, c.index, strict=True):
        np.testing.assert_array_equal(P[perm][ix], line)


def test_invalid_samples_are_dropped_and_counted():
    P, lab = raster()
    P[[3, 10, 500]] = np.nan
    c = organize_scan_lines(P, lab)
    assert c.removed["invalid"] == 3
    assert c.n_points == 4 * 400 - 3


def test_empty_line_is_an_error_naming_it_or_dropped():
    P, lab = raster()
    P[lab == 2] = np.nan
    with pytest.raises(PointCloudError, match="scan line 2 has 0 valid points of 400"):
        organize_scan_lines(P, lab)
    c = organize_scan_lines(P, lab, empty="drop")
    assert list(c.line_ids) == [0, 1, 3]


def test_single_line_is_an_error():
    P, lab = raster(n_lines=1)
    with pytest.raises(PointCloudError, match="at least 2 lines.*scan line 0"):
        organize_scan_lines(P, lab)
    with pytest.raises(PointCloudError, match="negative line label"):
        organize_scan_lines(P, np.full(len(P), -1))
    with pytest.raises(PointCloudError, match=r"points must be \(N, 3\)"):
        organize_scan_lines(P[:, :2], lab)


def test_outlier_filter_removes_spikes_and_keeps_noise():
    rng = np.random.default_rng(7)
    P, lab = raster(n=2000)
    on = lab >= 0
    P[on, 2] += rng.normal(0, 2e-6, on.sum())
    spikes = rng.choice(np.flatnonzero(on), 40, replace=False)
    P[spikes, 2] += rng.choice([-1, 1], 40) * rng.uniform(5e-5, 3e-3, 40)
    c = remove_outliers(organize_scan_lines(P, lab))
    kept = np.concatenate(c.index)
    assert not np.isin(spikes, kept).any()
    assert c.removed["outliers"] <= 40 + 0.001 * on.sum()


def test_boundary_keeps_the_part_and_simplify_spaces_evenly():
    P, lab = raster(n=1000)
    # the first 100 samples of line 1 fall off the part onto the table, 30 mm below
    rows = np.flatnonzero(lab == 1)[:100]
    P[rows, 2] -= 0.03
    c = extract_boundary(organize_scan_lines(P, lab))
    assert c.removed["off_part"] == 100
    ring = boundary_polygon(c)
    assert ring.shape == (2 * 4 + 1, 3) and np.allclose(ring[0], ring[-1])
    s = simplify_lines(c, 0.001)
    for line in s.lines:
        d = np.linalg.norm(np.diff(line, axis=0), axis=1)
        assert np.median(d) == pytest.approx(0.001, rel=0.1)


def test_centripetal_parameters():
    p = np.array([[0, 0, 0], [1, 0, 0], [5, 0, 0]], dtype=float)
    u = centripetal_parameters(p)
    np.testing.assert_allclose(u, [0, 1 / 3, 1])
    with pytest.raises(SplineError):
        centripetal_parameters(np.zeros((3, 3)))


def test_spline_fits_a_smooth_curve_and_resamples_evenly():
    t = np.linspace(0, 1, 3000)
    curve = np.column_stack([0.1 * t, 0.005 * np.sin(6 * t), 0.01 * np.cos(4 * t)])
    f = fit_line(curve, knot_spacing_m=0.002)
    assert f.max_error_m < ANALYTIC_CURVE_M
    pts, tan = f.resample(0.001)
    d = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    assert np.ptp(d) / d.mean() < EVEN_SPACING_REL
    assert d.mean() == pytest.approx(0.001, rel=0.02)
    # resampled points lie on the curve: compare with a dense evaluation of the truth
    tt = np.linspace(0, 1, 200001)
    truth = np.column_stack([0.1 * tt, 0.005 * np.sin(6 * tt), 0.01 * np.cos(4 * tt)])
    from scipy.spatial import cKDTree
    assert cKDTree(truth).query(pts)[0].max() < ANALYTIC_CURVE_M
    np.testing.assert_allclose(np.linalg.norm(tan, axis=1), 1.0)


def test_spline_states_the_noise_it_removes():
    rng = np.random.default_rng(3)
    t = np.linspace(0, 1, 3000)
    curve = np.column_stack([0.1 * t, np.zeros_like(t), 0.01 * np.sin(5 * t)])
    noisy = curve + np.column_stack([np.zeros_like(t), np.zeros_like(t), rng.normal(0, 5e-6, len(t))])
    f = fit_line(noisy)
    # The stated error is the scatter about the curve: about the noise sigma.
    assert 3e-6 < f.rms_error_m < 6e-6
    with pytest.raises(SplineError, match="at least 4 points"):
        fit_line(curve[:3])
    with pytest.raises(SplineError, match="spacing must be > 0"):
        f.resample(0.0)


# --- on the S-surface scan (document 004's part) -------------------------------------------

@pytest.fixture(scope="module")
def s_mesh():
    return load_workpiece_mesh(scenario("s_surface"))


@pytest.fixture(scope="module")
def s_index(s_mesh):
    return MeshIndex(s_mesh)


def _contact_points(scan, spacing=0.001):
    cloud = prepare_scan_lines(scan.points_base[:, 0], scan.line)
    return cloud, fit_lines(cloud.lines, spacing)


def _surface_distance(points_base, scan, index):
    return index.query(transform_points(inv_pose(scan.T_base_workpiece_true), points_base)).distance


@pytest.mark.parametrize("noise", ["off", "on"])
def test_planned_contact_points_lie_on_the_true_surface(noise, s_mesh, s_index):
    sc = scenario("s_surface", scan={"max_lines": 3})
    if noise == "off":
        sc = dataclasses.replace(sc, noise=sc.noise.all_off())
    scan = scan_scenario(sc, mesh=s_mesh)
    cloud, fits = _contact_points(scan)
    assert len(fits.lines) == 3
    d = _surface_distance(np.concatenate(fits.lines), scan, s_index)
    if noise == "off":
        assert d.max() < ON_TRUE_SURFACE_M
        assert d.max() < 1e-5  # in fact about a micrometre (tessellation and fit)
    else:
        assert d.max() < 3 * sensor_sigma_m(sc) + fits.max_error_m
