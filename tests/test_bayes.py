"""Localization with a placement prior (algorithms/registration/bayes.py): a known pose is
recovered, the prior holds what the points leave free, per-reading offsets are estimated,
ball centres fit the offset surface, and the innovations tell a right pose from a wrong one."""

import numpy as np
import pytest
import trimesh

from algorithms.errors import AlgorithmError
from algorithms.geometry.edges import SharpEdges
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import exp_se3, inv_pose, log_se3
from algorithms.registration.bayes import localize_map, normalized_innovations
from tests.tolerances import INNOVATION_RMS_OK, INNOVATION_RMS_WRONG, MAP_BIAS_M, MAP_EXACT_M, MAP_PRIOR_HOLD_REL

PRIOR = np.diag([np.radians(0.5) ** -2] * 3 + [1e-3 ** -2] * 3)
T_NOMINAL = np.array([[1, 0, 0, 0.45], [0, 1, 0, 0.12], [0, 0, 1, 0.0], [0, 0, 0, 1.0]])
XI_TRUE = np.array([0.004, -0.003, 0.006, 0.0008, -0.0012, 0.0005])


@pytest.fixture(scope="module")
def block():
    mesh = trimesh.creation.box(extents=[0.12, 0.08, 0.025])
    mesh.apply_translation([0.06, 0.04, 0.0125])
    return mesh, MeshIndex(mesh)


def _on_faces(mesh, n, seed):
    """Points on the faces (not within 5 mm of an edge) with their face normals."""
    P, face = trimesh.sample.sample_surface(mesh, 4 * n, seed=seed)
    lo, hi = mesh.bounds
    inner = np.sum((P > lo + 0.005) & (P < hi - 0.005), axis=1) >= 2
    return P[inner][:n], mesh.face_normals[face[inner][:n]]


def _world(P, T):
    return P @ T[:3, :3].T + T[:3, 3]


def test_known_pose_recovered_from_noise_free_points(block):
    mesh, index = block
    T_true = T_NOMINAL @ exp_se3(XI_TRUE)
    P, _ = _on_faces(mesh, 600, 1)
    res = localize_map(_world(P, T_true), index, T_NOMINAL, PRIOR, 2e-6)
    err = log_se3(inv_pose(T_true) @ res.T_world_workpiece)
    assert res.converged
    assert np.linalg.norm(err[3:]) < MAP_EXACT_M and np.linalg.norm(err[:3]) < MAP_EXACT_M
    assert res.inliers.all()


def test_prior_holds_the_directions_a_plane_leaves_free(block):
    mesh, index = block
    P, n = _on_faces(mesh, 2000, 2)
    top = n[:, 2] > 0.99
    T_true = T_NOMINAL @ exp_se3(XI_TRUE)
    res = localize_map(_world(P[top], T_true), index, T_NOMINAL, PRIOR, 2e-6)
    xi = log_se3(inv_pose(T_NOMINAL) @ res.T_world_workpiece)
    # the top face fixes z, roll and pitch; x, y and yaw stay at the prior mean
    assert abs(xi[3]) < MAP_PRIOR_HOLD_REL * 1e-3 and abs(xi[4]) < MAP_PRIOR_HOLD_REL * 1e-3
    assert abs(xi[2]) < MAP_PRIOR_HOLD_REL * np.radians(0.5)
    # and keep the prior's uncertainty, the fixed ones get the points'
    C = res.covariance
    assert np.sqrt(C[3, 3]) == pytest.approx(1e-3, rel=1e-3)
    assert np.sqrt(C[5, 5]) < 1e-6


def test_per_group_offsets_along_the_beams_are_estimated(block):
    mesh, index = block
    T_true = T_NOMINAL @ exp_se3(XI_TRUE)
    P, _ = _on_faces(mesh, 1500, 3)
    rng = np.random.default_rng(0)
    beams = rng.normal(size=(3, 3)) + [0, 0, -2.0]
    beams /= np.linalg.norm(beams, axis=1, keepdims=True)
    groups = rng.integers(0, 3, len(P))
    offsets = np.array([8e-6, -5e-6, 2e-6])
    U = beams[groups]
    Y = _world(P, T_true) + offsets[groups][:, None] * U
    res = localize_map(Y, index, T_NOMINAL, PRIOR, 2e-6, groups=groups, beams=U, bias_sigma_m=7e-6)
    err = log_se3(inv_pose(T_true) @ res.T_world_workpiece)
    assert np.linalg.norm(err[3:]) < MAP_EXACT_M * 100
    assert np.abs(res.biases_m - offsets).max() < MAP_BIAS_M * 100
    # the offsets cost information: the bound with them unknown is wider than without
    plain = localize_map(Y - offsets[groups][:, None] * U, index, T_NOMINAL, PRIOR, 2e-6)
    assert np.trace(res.covariance[3:, 3:]) > np.trace(plain.covariance[3:, 3:])


def test_ball_centres_fit_the_offset_surface(block):
    mesh, index = block
    T_true = T_NOMINAL @ exp_se3(XI_TRUE)
    P, n = _on_faces(mesh, 300, 4)
    radius = 0.001
    res = localize_map(_world(P + radius * n, T_true), index, T_NOMINAL, PRIOR, 1e-6, offset_m=radius)
    err = log_se3(inv_pose(T_true) @ res.T_world_workpiece)
    assert np.linalg.norm(err[3:]) < MAP_EXACT_M * 10


def test_ball_centres_touching_convex_edges_of_a_tessellation_fit(block):
    # a ball on a tessellated dome touches edges as often as faces: its centre lies off every
    # face's normal, and the residual is the distance to the edge, not to a face's plane
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
    index = MeshIndex(mesh)
    rng = np.random.default_rng(5)
    pick = rng.choice(len(mesh.face_adjacency), 300, replace=False)
    a, b = mesh.vertices[mesh.face_adjacency_edges[pick]].transpose(1, 0, 2)
    n0, n1 = mesh.face_normals[mesh.face_adjacency[pick]].transpose(1, 0, 2)
    q = a + rng.uniform(0.1, 0.9, (300, 1)) * (b - a)
    d = n0 + rng.uniform(0.2, 0.8, (300, 1)) * (n1 - n0)
    radius = 0.002
    C = q + radius * d / np.linalg.norm(d, axis=1, keepdims=True)
    T_true = T_NOMINAL @ exp_se3(XI_TRUE)
    res = localize_map(_world(C, T_true), index, T_NOMINAL, PRIOR, 1e-6, offset_m=radius)
    err = log_se3(inv_pose(T_true) @ res.T_world_workpiece)
    assert res.converged and res.inliers.all()
    assert np.linalg.norm(err[3:]) < MAP_EXACT_M * 10
    r = normalized_innovations(_world(C, T_true), np.zeros_like(C) + [0, 0, -1.0], index, T_true,
                               np.zeros((6, 6)), 1e-6, offset_m=radius)
    assert np.abs(r).max() < 1e-3


def test_points_near_sharp_edges_are_left_out(block):
    mesh, index = block
    edges = SharpEdges(mesh.vertices, mesh.faces)
    P = np.array([[0.0601, 0.04, 0.025], [0.06, 0.0401, 0.025], [0.1199, 0.04, 0.025], [0.06, 0.04, 0.0]])
    res = localize_map(_world(P, T_NOMINAL), index, T_NOMINAL, PRIOR, 2e-6, edges=edges, edge_band_m=0.0005)
    assert res.near_edge.tolist() == [False, False, True, False]
    assert edges.distance(P[2:3])[0] == pytest.approx(0.0001, abs=edges.step_m)


def test_innovations_tell_a_right_pose_from_a_wrong_one(block):
    mesh, index = block
    T_true = T_NOMINAL @ exp_se3(XI_TRUE)
    P, _ = _on_faces(mesh, 1000, 5)
    rng = np.random.default_rng(1)
    sigma = 2e-6
    Y = _world(P, T_true)
    beams = np.tile([0.0, 0.0, -1.0], (len(Y), 1))
    Y_noisy = Y + rng.normal(0, sigma, len(Y))[:, None] * beams
    C = np.diag([1e-12] * 6)
    right = normalized_innovations(Y_noisy, beams, index, T_true, C, sigma)
    wrong = normalized_innovations(Y_noisy, beams, index, T_true @ exp_se3([0, 0, 0, 0, 0, 5e-4]), C, sigma)
    assert np.sqrt(np.mean(right**2)) < INNOVATION_RMS_OK
    assert np.sqrt(np.mean(wrong**2)) > INNOVATION_RMS_WRONG


@pytest.mark.parametrize("kwargs, match", [
    (dict(sigma_m=0.0), "sigma_m"),
    (dict(prior_information=np.eye(6) * -1), "prior_information"),
    (dict(points=np.zeros((4, 2))), r"points must be \(N, 3\)"),
    (dict(bias_sigma_m=1e-6), "beams"),
    (dict(groups=np.array([0, -1, 0])), "groups"),
    (dict(offset_m=-1.0), "offset_m"),
])
def test_bad_input_is_refused(block, kwargs, match):
    _, index = block
    args = dict(points=np.zeros((3, 3)), index=index, T_prior=T_NOMINAL, prior_information=PRIOR, sigma_m=2e-6)
    args.update(kwargs)
    with pytest.raises(AlgorithmError, match=match):
        localize_map(**args)
