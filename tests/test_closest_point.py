"""Exact closest points on a mesh: exactness on and off the surface, scale invariance,
agreement of the two backends, bad input."""

import numpy as np
import pytest
import trimesh

from algorithms.errors import AlgorithmError
from algorithms.geometry.bvh_kernels import HAVE_NUMBA
from algorithms.geometry.mesh_index import MeshIndex, _corner_normals, closest_points_on_triangles
from tests.tolerances import (
    BACKEND_DISTANCE_M,
    BACKEND_FOOT_M,
    BRUTE_FORCE_REL,
    FACET_NORMAL_TOL,
    FOOT_DISTANCE_REL,
    ON_MESH_REL,
    SCALE_REL,
    SMOOTH_NORMAL_TOL,
)

BACKENDS = ["numpy"] + (["numba"] if HAVE_NUMBA else [])


def heightfield(n=40, size=0.2, amp=0.01, scale=1.0):
    """Open free-form sheet z = f(x, y) [m], no symmetry."""
    x = np.linspace(-size / 2, size / 2, n)
    y = np.linspace(-0.35 * size, 0.35 * size, int(0.7 * n))
    X, Y = np.meshgrid(x, y, indexing="ij")
    Z = (amp * np.sin(2 * np.pi * X / size * 1.3 + 0.4) * np.cos(np.pi * Y / size * 1.7)
         + 0.3 * amp * np.exp(-((X - 0.03) ** 2 + (Y + 0.02) ** 2) / 0.0008) + 0.05 * X)
    V = np.c_[X.ravel(), Y.ravel(), Z.ravel()] * scale
    nx, ny = X.shape
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return trimesh.Trimesh(V, np.r_[np.c_[a, b, c], np.c_[a, c, d]], process=False)


def sample_on_faces(mesh, n, rng):
    f = rng.integers(0, len(mesh.faces), n)
    u = rng.uniform(size=(n, 2))
    flip = u.sum(axis=1) > 1
    u[flip] = 1 - u[flip]
    t = mesh.triangles[f]
    return t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0]), f


def brute_force_d2(points, mesh):
    tri = mesh.triangles
    out = np.empty(len(points))
    for i, p in enumerate(points):
        _, d2 = closest_points_on_triangles(np.repeat(p[None], len(tri), axis=0), tri)
        out[i] = d2.min()
    return out


@pytest.mark.parametrize("backend", BACKENDS)
def test_points_on_the_mesh_are_their_own_feet(backend):
    # a metre-scale mesh with ~3 mm triangles: where trimesh 5.2 misplaces feet
    mesh = heightfield(n=70)
    rng = np.random.default_rng(0)
    pts, _ = sample_on_faces(mesh, 2000, rng)
    res = MeshIndex(mesh, backend=backend).query(pts)
    size = np.linalg.norm(mesh.extents)
    assert res.distance.max() <= ON_MESH_REL * size
    assert np.abs(res.foot - pts).max() <= ON_MESH_REL * size


@pytest.mark.parametrize("backend", BACKENDS)
def test_off_mesh_points_match_brute_force(backend):
    rng = np.random.default_rng(1)
    meshes = [heightfield(n=9), trimesh.creation.icosphere(subdivisions=1, radius=0.05),
              trimesh.creation.box(extents=[0.1, 0.04, 0.02])]
    for mesh in meshes:
        size = np.linalg.norm(mesh.extents)
        near, _ = sample_on_faces(mesh, 150, rng)
        pts = np.r_[near + rng.normal(size=near.shape) * 0.01 * size,
                    rng.uniform(-1.0, 1.0, size=(150, 3)) * size,   # far and inside
                    mesh.vertices[:20] + 1e-4 * size]                 # near vertices
        res = MeshIndex(mesh, backend=backend).query(pts)
        ref = np.sqrt(brute_force_d2(pts, mesh))
        assert np.abs(res.distance - ref).max() <= BRUTE_FORCE_REL * size
        # the foot is on the reported face and at the reported distance
        assert np.allclose(np.linalg.norm(pts - res.foot, axis=1), res.distance, rtol=0, atol=FOOT_DISTANCE_REL * size)
        _, d2_face = closest_points_on_triangles(res.foot, mesh.triangles[res.face])
        assert np.sqrt(d2_face).max() <= BRUTE_FORCE_REL * size
        assert np.allclose(np.linalg.norm(res.normal, axis=1), 1.0)
        assert np.allclose(res.normal, mesh.face_normals[res.face], atol=FACET_NORMAL_TOL)


@pytest.mark.parametrize("backend", BACKENDS)
def test_scale_invariance(backend):
    rng = np.random.default_rng(2)
    mesh = heightfield(n=30)
    pts = rng.uniform(-0.1, 0.1, size=(300, 3)) * [1, 1, 0.2]
    a = MeshIndex(mesh, backend=backend).query(pts)
    for s in (1e-3, 1e3):
        b = MeshIndex(heightfield(n=30, scale=s), backend=backend).query(pts * s)
        assert np.abs(b.distance / s - a.distance).max() <= SCALE_REL * np.linalg.norm(mesh.extents)
        assert np.abs(b.foot / s - a.foot).max() <= SCALE_REL * np.linalg.norm(mesh.extents)


def test_normals_point_outward_on_a_closed_mesh():
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(500, 3)) * 0.05
    res = MeshIndex(mesh).query(pts)
    assert np.all(np.einsum("ij,ij->i", res.normal, res.foot) > 0)


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed")
def test_backends_agree_and_hints_do_not_change_answers():
    mesh = heightfield(n=60)
    rng = np.random.default_rng(4)
    pts = np.r_[sample_on_faces(mesh, 3000, rng)[0] + rng.normal(size=(3000, 3)) * 1e-3,
                rng.uniform(-0.2, 0.2, size=(5000, 3))]   # enough to use the parallel kernel
    a = MeshIndex(mesh, backend="numpy").query(pts)
    idx = MeshIndex(mesh, backend="numba")
    b = idx.query(pts)
    assert np.abs(a.distance - b.distance).max() <= BACKEND_DISTANCE_M
    assert np.abs(a.foot - b.foot).max() <= BACKEND_FOOT_M
    hint = rng.integers(0, len(mesh.faces), len(pts))
    c = idx.query(pts, hint=hint)
    assert np.array_equal(c.distance, b.distance)


@pytest.mark.skipif(not HAVE_NUMBA, reason="the approximate search is the compiled one's")
def test_approximate_queries_stay_within_their_relative_error():
    mesh = heightfield(n=60)
    rng = np.random.default_rng(8)
    on, _ = sample_on_faces(mesh, 2000, rng)
    pts = on + rng.normal(size=on.shape) * np.array([[2e-3], [1e-2], [3e-2], [1e-4]]).repeat(500, 0)
    idx = MeshIndex(mesh, backend="numba")
    exact = idx.query(pts)
    assert exact.rel_error == 0.0
    for rel in (0.05, 0.3):
        approx = idx.query(pts, rel_error=rel)
        assert approx.rel_error == rel
        assert np.all(approx.distance >= exact.distance - 1e-15)
        assert np.all(approx.distance <= (1.0 + rel) * exact.distance + 1e-15)
        # the answer is a real foot on the face named, at the distance reported
        assert np.allclose(np.linalg.norm(pts - approx.foot, axis=1), approx.distance, rtol=0, atol=1e-15)
        d_face = np.sqrt(closest_points_on_triangles(pts, mesh.triangles[approx.face])[1])
        assert np.allclose(d_face, approx.distance, rtol=0, atol=1e-12)
    # far points are where it saves work: some answers differ from the exact ones there
    assert np.any(idx.query(pts, rel_error=0.3).face[500:1500] != exact.face[500:1500])
    with pytest.raises(AlgorithmError, match="rel_error"):
        idx.query(pts, rel_error=-0.1)


def test_smooth_normals_are_radial_on_a_tessellated_cylinder():
    mesh = trimesh.creation.cylinder(radius=0.02, height=0.05, sections=24)
    idx = MeshIndex(mesh)
    rng = np.random.default_rng(5)
    side = np.nonzero(np.abs(mesh.face_normals[:, 2]) < 0.5)[0]
    f = rng.choice(side, 200)
    u = rng.uniform(size=(200, 2))
    u[u.sum(1) > 1] = 1 - u[u.sum(1) > 1]
    t = mesh.triangles[f]
    foot = t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0])
    n = idx.smooth_normals(f, foot)
    radial = foot[:, :2] / np.linalg.norm(foot[:, :2], axis=1, keepdims=True)
    assert np.abs(n[:, 2]).max() < SMOOTH_NORMAL_TOL
    assert np.abs(radial[:, 0] * n[:, 1] - radial[:, 1] * n[:, 0]).max() < SMOOTH_NORMAL_TOL  # parallel
    # sharp edges stay sharp: the cap keeps its flat normal
    cap = np.nonzero(mesh.face_normals[:, 2] > 0.99)[0][:5]
    nc = idx.smooth_normals(cap, mesh.triangles[cap].mean(axis=1))
    assert np.allclose(nc, [0, 0, 1])


def test_smooth_normals_of_a_few_faces_are_those_of_the_whole_mesh():
    # the index fills its per-corner normals face by face, as the queries need them: the
    # values must be exactly those computed for every face at once, whatever the order asked
    mesh = heightfield(n=30)
    rng = np.random.default_rng(8)
    idx = MeshIndex(mesh)
    whole = _corner_normals(idx.vertices, idx.faces, idx.face_normals)
    for _ in range(3):
        f = rng.choice(len(mesh.faces), 40)
        u = rng.uniform(0.0, 0.5, size=(40, 2))
        t = mesh.triangles[f]
        foot = t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0])
        n = idx.smooth_normals(f, foot)
        assert np.array_equal(idx._smooth[f], whole[f])
        ref = MeshIndex(mesh)
        ref._smooth, ref._smooth_done = whole, np.ones(len(whole), dtype=bool)
        assert np.array_equal(n, ref.smooth_normals(f, foot))
    assert not idx._smooth_done.all()  # only what was asked was computed


def test_rotation_vector_is_scipys():
    # se3.rotation_vector replaces scipy's Rotation.from_matrix(R).as_rotvec() on the pose code's
    # path: the same vectors, also at 0, across the series' switch at 1e-3 rad and at pi
    from scipy.spatial.transform import Rotation

    from algorithms.geometry.se3 import rotation_vector

    rng = np.random.default_rng(3)
    axes = rng.normal(size=(12, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = [0.0, 1e-12, 1e-6, 0.999e-3, 1.001e-3, 0.5, 3.0, np.pi - 1e-6, np.pi]
    rotations = [*Rotation.random(200, random_state=4).as_matrix(),
                 *(Rotation.from_rotvec(a * ax).as_matrix() for a in angles for ax in axes)]
    for R in rotations:
        expected = Rotation.from_matrix(R).as_rotvec()
        got = rotation_vector(R)
        if np.linalg.norm(expected) > np.pi - 1e-9:  # at pi, w and -w are the same rotation
            got = got if got @ expected > 0 else -got
        assert np.allclose(got, expected, rtol=0.0, atol=1e-14)


def test_bad_input_is_refused():
    with pytest.raises(AlgorithmError, match="at least one triangle"):
        MeshIndex(trimesh.Trimesh(vertices=np.zeros((3, 3)), faces=np.zeros((0, 3), dtype=int)))
    v = np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0.0]])
    with pytest.raises(AlgorithmError, match="NaN"):
        MeshIndex(trimesh.Trimesh(v, [[0, 1, 2]], process=False))
    with pytest.raises(AlgorithmError, match="backend"):
        MeshIndex(heightfield(n=5), backend="cuda")
    idx = MeshIndex(heightfield(n=5))
    with pytest.raises(AlgorithmError, match=r"\(N, 3\)"):
        idx.query(np.zeros((4, 2)))
    with pytest.raises(AlgorithmError, match="NaN"):
        idx.query(np.array([[0.0, np.inf, 0.0]]))
    assert idx.query(np.zeros((0, 3))).foot.shape == (0, 3)


@pytest.mark.parametrize("make", [lambda: trimesh.creation.box((0.1, 0.08, 0.05)),
                                  lambda: trimesh.creation.icosphere(3, 0.05),
                                  lambda: trimesh.creation.annulus(0.02, 0.05, 0.03)])
def test_signed_distance_is_negative_exactly_inside(make):
    mesh = make()
    index = MeshIndex(mesh)
    P = np.random.default_rng(3).uniform(-0.12, 0.12, (5000, 3))
    # near the corners and edges too: vertices pushed out along random directions
    V = np.asarray(mesh.vertices)
    P = np.vstack([P, V[np.arange(2000) % len(V)] + np.random.default_rng(4).normal(0, 0.004, (2000, 3))])
    sd = index.signed_distance(P)
    assert np.array_equal(sd < 0, mesh.contains(P))
    assert np.allclose(np.abs(sd), index.query(P).distance)


@pytest.mark.skipif(not HAVE_NUMBA, reason="the compiled tree needs numba")
def test_the_trees_single_precision_boxes_still_bound_their_faces():
    """The compiled tree keeps its boxes in float32, rounded outwards: far from the origin
    (where float32 steps are 60 um) the answers stay exact to double precision. (Rounded to
    nearest, some points near the surface get a neighbouring face 20 um too far.)"""
    mesh = heightfield(n=70)
    mesh = trimesh.Trimesh(mesh.vertices + [1000.1234567, -2000.7654321, 500.5], mesh.faces, process=False)
    rng = np.random.default_rng(3)
    pts, _ = sample_on_faces(mesh, 3000, rng)
    pts = pts + rng.normal(size=pts.shape) * 5e-6
    res = MeshIndex(mesh, backend="numba").query(pts)
    assert np.abs(res.distance - np.sqrt(brute_force_d2(pts, mesh))).max() <= 1e-12


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_pickled_index_answers_the_same(backend):
    """Worker processes get the index pickled: the same answers, bit for bit."""
    import pickle

    mesh = heightfield(n=30)
    index = MeshIndex(mesh, backend=backend)
    copy = pickle.loads(pickle.dumps(index))
    pts = np.random.default_rng(4).uniform(-0.1, 0.1, size=(500, 3)) * [1, 1, 0.2]
    a, b = index.query(pts), copy.query(pts)
    assert np.array_equal(a.distance, b.distance) and np.array_equal(a.face, b.face)
    assert np.array_equal(a.foot, b.foot)
