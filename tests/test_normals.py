"""Normals of scan-line clouds: cross-line triangulation (document 004) and k-NN PCA."""

import dataclasses

import numpy as np
import pytest

from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.paths.normals import NormalsError, angle_deg, pca_normals, smooth_line_normals, triangulation_normals
from algorithms.paths.pointcloud import prepare_scan_lines
from algorithms.paths.spline import fit_lines
from tests.helpers import scenario
from tests.tolerances import EXACT_DEG, TRIANGULATION_BAR_DEG
from twin.parts import s_surface_normal
from twin.scan import scan_scenario


def lines_on(z, dz, n_lines=6, n=80, along=0.001, across=0.004):
    """Scan lines on z(x, y) with the analytic unit normal, lines along x, stacked along y."""
    L, N = [], []
    for i in range(n_lines):
        x = np.arange(n) * along
        y = np.full(n, i * across)
        L.append(np.column_stack([x, y, z(x, y)]))
        gx, gy = dz(x, y)
        nn = np.column_stack([-gx, -gy, np.ones(n)])
        N.append(nn / np.linalg.norm(nn, axis=1, keepdims=True))
    return L, N


def test_plane_normals_are_exact_everywhere_including_boundaries():
    L, N = lines_on(lambda x, y: 0.2 * x - 0.1 * y + 0.03, lambda x, y: (np.full_like(x, 0.2), np.full_like(x, -0.1)))
    est = triangulation_normals(L)
    for e, n in zip(est, N, strict=True):
        assert angle_deg(e, n).max() < EXACT_DEG
    flipped = triangulation_normals(L, orient=[0, 0, -1])
    assert np.allclose(np.concatenate(flipped), -np.concatenate(est))


def test_fan_is_exact_on_quadrics_and_second_order_elsewhere():
    # The fan sums to the central difference (a - b) x (n+ - n-): exact on a quadric when the
    # neighbours sit symmetrically (here they do), O(h^2) on other surfaces.
    k = 30.0  # curvature [1/m], like the S-surface's tightest
    L, N = lines_on(lambda x, y: 0.5 * k * (x - 0.04) ** 2 + 2.0 * y**2, lambda x, y: (k * (x - 0.04), 4.0 * y))
    est = triangulation_normals(L)
    assert max(angle_deg(e, n)[1:-1].max() for e, n in zip(est[1:-1], N[1:-1], strict=True)) < EXACT_DEG
    def z(x, y):
        return 0.01 * np.sin(50 * x) + 0.002 * np.sin(100 * y)

    def dz(x, y):
        return 0.5 * np.cos(50 * x), 0.2 * np.cos(100 * y)

    errs = []
    for h in (0.002, 0.001):
        L, N = lines_on(z, dz, along=h, across=4 * h, n=int(0.08 / h), n_lines=int(0.024 / (4 * h)))
        est = triangulation_normals(L)
        inner = [angle_deg(e, n)[2:-2] for e, n in zip(est[1:-1], N[1:-1], strict=True)]
        errs.append(np.sqrt(np.mean(np.concatenate(inner) ** 2)))
    # halving the spacing divides the interior error by about four
    assert 3.0 < errs[0] / errs[1] < 5.0


def test_pca_fails_on_scan_lines_where_triangulation_does_not():
    # Dense along the lines (0.05 mm), sparse across (4 mm): the k nearest neighbours all lie
    # on the point's own line, so the PCA plane is the line's osculating plane.
    def z(x, y):
        return 0.01 * np.sin(50 * x) + 0.05 * y

    def dz(x, y):
        return 0.5 * np.cos(50 * x), np.full_like(x, 0.05)

    L, N = lines_on(z, dz, along=5e-5, n=2000)
    n_true = np.concatenate(N)
    tri = np.concatenate(triangulation_normals(L, orient=[0, 0, 1]))
    pca = pca_normals(np.concatenate(L), k=16, orient=[0, 0, 1])
    assert np.sqrt(np.mean(angle_deg(tri, n_true) ** 2)) < 0.5
    assert np.median(angle_deg(pca, n_true, unsigned=True)) > 45.0


def test_smoothing_keeps_the_surface_variation():
    def z(x, y):
        return 0.01 * np.sin(50 * x) + 0.05 * y

    def dz(x, y):
        return 0.5 * np.cos(50 * x), np.full_like(x, 0.05)

    L, N = lines_on(z, dz, along=0.001, n=100)
    sm = smooth_line_normals(L, triangulation_normals(L), 0.004)
    a = angle_deg(np.concatenate(sm), np.concatenate(N))
    assert np.sqrt(np.mean(a**2)) < 0.5


def test_bad_input():
    L, _ = lines_on(lambda x, y: x * 0, lambda x, y: (x * 0, x * 0))
    with pytest.raises(NormalsError, match="at least 2 lines"):
        triangulation_normals(L[:1])
    bad = [line.copy() for line in L]
    bad[2][5] = np.nan
    with pytest.raises(NormalsError, match="line 2 contains NaN"):
        triangulation_normals(bad)
    with pytest.raises(NormalsError, match="line 1 is empty"):
        triangulation_normals([L[0], np.empty((0, 3))])
    with pytest.raises(NormalsError, match="k must be"):
        pca_normals(np.concatenate(L), k=2)


def test_triangulation_normals_on_the_s_surface_scan():
    sc = scenario("s_surface", scan={"max_lines": 4})
    scan = scan_scenario(dataclasses.replace(sc, noise=sc.noise.all_off()))
    cloud = prepare_scan_lines(scan.points_base[:, 0], scan.line)
    fits = fit_lines(cloud.lines, 0.001)
    pts = np.concatenate(fits.lines)
    est = np.concatenate(triangulation_normals(fits.lines, orient=scan.T_base_workpiece_nominal[:3, 2]))
    T = scan.T_base_workpiece_true
    p_wp = transform_points(inv_pose(T), pts)
    n_true = s_surface_normal(p_wp[:, 0], p_wp[:, 1]) @ T[:3, :3].T
    a = angle_deg(est, n_true)
    assert np.sqrt(np.mean(a**2)) < TRIANGULATION_BAR_DEG
    assert np.sqrt(np.mean(a**2)) < 0.5  # measured about 0.2 deg on four lines (boundary lines included)
