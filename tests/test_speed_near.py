"""The certified local closest-point query (MeshIndex.query_near) and the kernels' one-time
compilation: the near-face lists give the tree's answers exactly, whatever the motion, and
compiling again is a no-op. (Speed is measured by benchmarks/, never asserted here.)"""

import numpy as np
import pytest
import trimesh

from algorithms.geometry.bvh_kernels import HAVE_NUMBA, compile_kernels, kernels_cached
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import exp_se3
from tests.test_closest_point import brute_force_d2, heightfield, sample_on_faces
from tests.tolerances import BRUTE_FORCE_REL

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="the near-face lists need the numba backend")


def _moved(points, center, xi):
    T = exp_se3(xi)
    return (points - center) @ T[:3, :3].T + T[:3, 3] + center


@pytest.mark.parametrize("n", [300, 9000])  # one thread, and chunks on threads
def test_near_query_equals_tree_query_along_a_sequence_of_motions(n):
    mesh = heightfield(n=60)
    index = MeshIndex(mesh)
    rng = np.random.default_rng(3)
    size = np.linalg.norm(mesh.extents)
    p0, _ = sample_on_faces(mesh, n, rng)
    p0 = p0 + rng.normal(size=p0.shape) * 1e-3 * size
    c = p0.mean(axis=0)
    near = None
    rebuilt = []
    # from large to tiny steps (the course of a registration), and one large jump back
    p = p0
    for scale in [3e-2, 1e-2, 1e-3, 1e-4, 1e-5, None, 3e-2]:
        if scale is not None:  # None: the same points again
            xi = rng.normal(size=6) * scale * np.r_[np.full(3, 1.0), np.full(3, size)]
            p = _moved(p0, c, xi)
        cp, near = index.query_near(p, near)
        ref = index.query(p)
        assert np.array_equal(cp.distance, ref.distance) or np.abs(cp.distance - ref.distance).max() == 0.0
        assert np.allclose(np.linalg.norm(p - cp.foot, axis=1), cp.distance, atol=1e-15 * size)
        assert np.array_equal(cp.normal, mesh.face_normals[cp.face]) or np.allclose(
            cp.normal, index.face_normals[cp.face])
        rebuilt.append(near.n_rebuilt)
    assert rebuilt[0] == n          # the first query finds every list
    assert rebuilt[5] == 0          # the same points again: every certificate holds
    assert rebuilt[-1] > rebuilt[-2]  # a large jump invalidates lists


def test_near_query_far_and_inside_points_match_brute_force():
    rng = np.random.default_rng(4)
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    index = MeshIndex(mesh)
    size = np.linalg.norm(mesh.extents)
    p = rng.uniform(-1.0, 1.0, size=(200, 3)) * size
    cp, near = index.query_near(p)
    cp2, _ = index.query_near(p + 1e-6 * size, near)
    ref = np.sqrt(brute_force_d2(p + 1e-6 * size, mesh))
    assert np.abs(cp2.distance - ref).max() <= BRUTE_FORCE_REL * size


def test_mesh_with_fewer_faces_than_a_list():
    tri = trimesh.Trimesh(vertices=[[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0]], faces=[[0, 1, 2]], process=False)
    index = MeshIndex(tri)
    p = np.array([[0.002, 0.002, 0.003], [0.05, 0.0, 0.0]])
    cp, near = index.query_near(p)
    cp2, near = index.query_near(p * 1.5, near)
    assert near.n_rebuilt == 0  # the list holds every face: always certified
    assert np.allclose(cp2.distance, index.query(p * 1.5).distance, rtol=0, atol=1e-18)


def test_near_lists_must_match_the_points():
    index = MeshIndex(heightfield(n=9))
    _, near = index.query_near(np.zeros((5, 3)))
    with pytest.raises(Exception, match="near lists were made for 5 points"):
        index.query_near(np.zeros((6, 3)), near)


def test_kernels_compile_once():
    compile_kernels(announce=False)
    assert compile_kernels() == 0.0     # a second call does nothing
    assert kernels_cached() in (True, None)


def test_twin_warmup_says_what_it_did(capsys):
    from twin.cli import main

    assert main(["warmup", "--json"]) == 0
    out = capsys.readouterr().out
    assert '"kernels"' in out and '"seconds"' in out
