"""Fisher information, Cramer-Rao bound, observability and the pose-error convention."""

import numpy as np
import pytest
import trimesh

from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import exp_se3, make_pose, rotation_error_rad, translation_error_m
from algorithms.registration import uncertainty as U
from tests.tolerances import CONVENTION_TOL, INVERSE_TOL, NULL_REL, SPAN_TOL, WEAK_REL


def _grid_plane(n=12):
    x, y = np.meshgrid(np.linspace(-0.05, 0.05, n), np.linspace(-0.03, 0.03, n))
    p = np.c_[x.ravel(), y.ravel(), np.full(x.size, 0.01)]
    return p, np.tile([0.0, 0.0, 1.0], (len(p), 1))


def _cylinder(n=200, r=0.02, rng=None):
    rng = rng or np.random.default_rng(0)
    a = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(-0.04, 0.04, n)
    nrm = np.c_[np.cos(a), np.sin(a), np.zeros(n)]
    return nrm * r + np.c_[np.zeros((n, 2)), z] + [0.1, -0.05, 0.2], nrm


def _sphere(n=200, r=0.03, rng=None):
    rng = rng or np.random.default_rng(1)
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return nrm * r + [0.02, 0.0, 0.01], nrm


def _freeform(n=300, rng=None):
    rng = rng or np.random.default_rng(2)
    xy = rng.uniform(-0.05, 0.05, size=(n, 2))
    z = 0.01 * np.sin(40 * xy[:, 0]) * np.cos(25 * xy[:, 1]) + 0.2 * xy[:, 0] ** 2
    dzdx = 0.4 * np.cos(40 * xy[:, 0]) * np.cos(25 * xy[:, 1]) + 0.4 * xy[:, 0]
    dzdy = -0.25 * np.sin(40 * xy[:, 0]) * np.sin(25 * xy[:, 1])
    nrm = np.c_[-dzdx, -dzdy, np.ones(n)]
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return np.c_[xy, z], nrm


def test_rows_fisher_and_crlb_formulas():
    p, n = _freeform()
    J = U.information_rows(p, n)
    assert np.allclose(J, np.hstack([np.cross(p, n), n]))
    sigma = 2e-5
    F = U.fisher_information(p, n, sigma)
    assert np.allclose(F, J.T @ J / sigma**2)
    C = U.crlb(p, n, sigma)
    assert np.allclose(C @ F, np.eye(6), atol=INVERSE_TOL)
    assert np.allclose(C, C.T)


@pytest.mark.parametrize(
    "make, n_weak",
    [(_grid_plane, 3), (_cylinder, 2), (_sphere, 3)],
)
def test_symmetric_point_sets_are_unobservable(make, n_weak):
    p, n = make()
    obs = U.observability(p, n)
    assert not obs.observable
    assert obs.weak_directions.shape == (n_weak, 6)
    assert np.all(obs.relative_eigenvalues[:n_weak] < WEAK_REL)
    assert obs.relative_eigenvalues[n_weak] > U.OBSERVABILITY_TOL
    # every weak twist leaves every normal displacement zero: J xi = 0
    J = U.information_rows(p, n)
    scale = np.linalg.norm(J, axis=1).max()
    assert np.abs(J @ obs.weak_directions.T).max() < NULL_REL * scale
    with pytest.raises(AlgorithmError, match="six DOF"):
        U.crlb(p, n, 1e-5)


def test_cylinder_weak_directions_are_its_axis_motions():
    p, n = _cylinder()
    obs = U.observability(p, n)
    W = obs.weak_directions
    axis = np.array([0.0, 0.0, 1.0])
    # the weak subspace holds the translation along the axis and the rotation about it
    # (about the axis line through (0.1, -0.05)): omega = axis, v = -axis x c
    c = np.array([0.1, -0.05, 0.0])
    for xi in (np.r_[0, 0, 0, axis], np.r_[axis, -np.cross(axis, c)]):
        coef, *_ = np.linalg.lstsq(W.T, xi, rcond=None)
        assert np.allclose(W.T @ coef, xi, atol=SPAN_TOL)


def test_freeform_is_observable():
    p, n = _freeform()
    obs = U.observability(p, n)
    assert obs.observable
    assert obs.weak_directions.shape == (0, 6)
    assert obs.relative_eigenvalues[-1] == 1.0


def test_tessellated_cylinder_is_unobservable_with_smooth_normals():
    mesh = trimesh.creation.cylinder(radius=0.02, height=0.08, sections=16)
    idx = MeshIndex(mesh)
    side = np.nonzero(np.abs(mesh.face_normals[:, 2]) < 0.5)[0]
    rng = np.random.default_rng(3)
    f = rng.choice(side, 300)
    u = rng.uniform(size=(300, 2))
    u[u.sum(1) > 1] = 1 - u[u.sum(1) > 1]
    t = mesh.triangles[f]
    foot = t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0])
    # the facets alone "constrain" the roll about the axis ...
    assert U.observability(foot, mesh.face_normals[f]).relative_eigenvalues[1] > U.OBSERVABILITY_TOL
    # ... the surface they approximate does not
    obs = U.observability(foot, idx.smooth_normals(f, foot))
    assert not obs.observable and len(obs.weak_directions) == 2


def test_error_twist_convention_and_whitening():
    rng = np.random.default_rng(4)
    T_true = make_pose(exp_se3([0.3, -0.2, 0.1, 0, 0, 0])[:3, :3], [0.1, 0.2, -0.05])
    xi = np.array([1e-3, -2e-3, 5e-4, 1e-4, 2e-4, -3e-4])
    T_est = T_true @ exp_se3(xi)
    assert np.allclose(U.pose_error_twist(T_est, T_true), xi, atol=CONVENTION_TOL)
    # metrics of document 000
    assert np.isclose(U.rotation_error_rad(T_est, T_true), np.linalg.norm(xi[:3]))
    assert U.translation_error_m is translation_error_m and U.rotation_error_rad is rotation_error_rad
    # whitened errors of draws from N(0, C) have mean 6
    p, n = _freeform()
    C = U.crlb(p, n, 1e-5)
    X = rng.multivariate_normal(np.zeros(6), C, size=4000)
    assert abs(U.whitened_error(X, C).mean() / 6 - 1) < 0.05


def test_sigma_estimate_and_bad_input():
    r = np.random.default_rng(5).normal(size=10000) * 3e-5
    assert abs(U.estimate_sigma(r) / 3e-5 - 1) < 0.03
    with pytest.raises(AlgorithmError):
        U.estimate_sigma(r[:6])
    p, n = _freeform()
    with pytest.raises(AlgorithmError, match="sigma"):
        U.crlb(p, n, 0.0)
    with pytest.raises(AlgorithmError, match="at least 6"):
        U.observability(p[:5], n[:5])
    with pytest.raises(AlgorithmError, match=r"\(N, 3\)"):
        U.information_rows(p, n[:, :2])


def test_part_symmetry_tells_a_sphere_from_a_block():
    sphere = MeshIndex(trimesh.creation.icosphere(4, 0.05))
    block = MeshIndex(trimesh.creation.box((0.1, 0.08, 0.05)))
    rotations = np.hstack([np.eye(3), np.zeros((3, 3))])
    assert U.part_symmetry_directions(sphere, rotations).all()
    # the block turns onto itself about no axis by a small step, nor slides
    assert not U.part_symmetry_directions(block, rotations).any()
    assert not U.part_symmetry_directions(block, np.hstack([np.zeros((3, 3)), np.eye(3)])).any()
    # ... but points of its top face stay on it when turned about z or slid in x, y
    top = np.column_stack([np.random.default_rng(0).uniform(-0.02, 0.02, (50, 2)), np.full(50, 0.025)])
    slide_xy = np.array([[0, 0, 0, 1.0, 0, 0], [0, 0, 0, 0, 1.0, 0], [0, 0, 1.0, 0, 0, 0]])
    assert U.invariant_points(block, top, slide_xy).all()
    # a turn about x lifts or sinks the points away from y = 0 (near it, it slides them)
    far = np.abs(top[:, 1]) > 0.01
    assert not U.invariant_points(block, top[far], rotations[:1]).any()


def test_a_constant_bias_along_the_normals_moves_the_pose_as_predicted():
    # Points on the six faces of a box; a bias b along every normal moves the least-squares
    # pose by b * g; the systematic covariance of a constant basis is b^2 g g^T.
    box = trimesh.creation.box((0.1, 0.08, 0.05))
    pts, face = trimesh.sample.sample_surface_even(box, 600, seed=1)
    nrm = box.face_normals[face]
    D = np.eye(6)
    C = U.systematic_covariance(pts, nrm, D, np.ones((len(pts), 1)), [2e-6])
    A = U.information_rows(pts, nrm)
    shift = np.linalg.lstsq(A, np.full(len(pts), 2e-6), rcond=None)[0]
    assert np.allclose(C, np.outer(shift, shift), atol=1e-20)
    # it does not shrink with more points: the same bias on twice the points
    C2 = U.systematic_covariance(np.vstack([pts, pts]), np.vstack([nrm, nrm]), D, np.ones((2 * len(pts), 1)), [2e-6])
    assert np.allclose(C2, C, rtol=1e-9, atol=1e-24)


def test_an_estimate_moves_along_its_free_directions_to_the_reference_only():
    T_ref = make_pose(p=[0.45, 0.12, 0.0])
    free = np.array([0.0, 0.0, 1.0, 0.006, -0.012, 0.0])       # a turn about a vertical axis
    determined = np.array([1e-4, 0.0, 0.0, 0.0, 0.0, 2e-5])
    T = T_ref @ exp_se3(0.35 * free) @ exp_se3(determined)
    xi = U.log_se3(U.inv_pose(T_ref) @ U.nearest_along_free(T, [free], T_ref))
    assert abs(xi[2]) < 1e-9 and np.allclose(xi[[0, 5]], determined[[0, 5]], rtol=0.1)
    assert np.array_equal(U.nearest_along_free(T, np.zeros((0, 6)), T_ref), T)
