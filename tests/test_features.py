"""The feature library of document 000's Table 1 (algorithms/registration/symmetric/)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import exp_se3, transform_points
from algorithms.registration.symmetric import (
    FEATURE_TABLE,
    FEATURE_TYPES,
    Feature,
    check_feature_type,
    make_feature,
    symmetry_group,
)
from algorithms.registration.symmetric.groups import perp_basis
from tests.tolerances import CLOSED_FORM_M, FIT_AXIS_RAD, FIT_M, OFF_FEATURE_M, ON_FEATURE_M, ORTHOGONAL_TOL

TABLE_DIMS = {"circle2d": 2, "line2d": 2, "sphere": 3, "plane": 3, "line3d": 4, "cylinder": 4,
              "cone": 5, "extruded": 5, "freeform": 6}


# ------------------------------------------------------------------------ shared samplers
def bumpy_mesh(n: int = 40, size: float = 0.08) -> trimesh.Trimesh:
    """A free-form height field (no symmetry), workpiece frame [m]."""
    x = np.linspace(-size / 2, size / 2, n)
    X, Y = np.meshgrid(x, x)
    Z = (0.004 * np.sin(40 * X) * np.cos(30 * Y)
         + 0.003 * np.exp(-((X - 0.01) ** 2 + (Y + 0.01) ** 2) / 2e-4) + 20 * X**2 * Y)
    V = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    F = np.concatenate([np.column_stack([a, a + 1, a + n + 1]), np.column_stack([a, a + n + 1, a + n])])
    return trimesh.Trimesh(V, F, process=False)


def example_features() -> dict:
    """One feature of every type, in general position (workpiece frame)."""
    s = np.linspace(-0.04, 0.04, 401)
    profile = np.column_stack([s, 0.01 * np.sin(60 * s) + 4.0 * s * s])
    return {
        "circle2d": Feature.circle2d([0.01, 0.02], 0.03),
        "line2d": Feature.line2d([0.01, 0.02], [1.0, 0.5]),
        "sphere": Feature.sphere([0.01, 0.02, 0.03], 0.05),
        "plane": Feature.plane([0.01, 0.02, 0.03], [0.2, 0.1, 1.0]),
        "line3d": Feature.line3d([0.01, 0.02, 0.03], [1.0, 0.2, 0.1]),
        "cylinder": Feature.cylinder([0.01, 0.02, 0.03], [0.3, 0.1, 1.0], 0.04),
        "cone": Feature.cone([0.01, 0.02, 0.03], [0.1, 0.2, 1.0], 0.4),
        "extruded": Feature.extruded([0.1, -0.2, 1.0], profile=profile, origin=[0.01, 0.0, 0.02]),
        "freeform": Feature.freeform(bumpy_mesh()),
    }


def sample_feature(f: Feature, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) points exactly on the feature (z = 0 for the 2D ones), workpiece frame [m]."""
    c, a = f.origin, f.axis
    e1, e2 = perp_basis(a)
    k = f.kind
    if k == "circle2d":
        phi = rng.uniform(0, 2 * np.pi, n)
        return c + f.radius * np.column_stack([np.cos(phi), np.sin(phi), np.zeros(n)])
    if k == "line2d":
        return c + rng.uniform(-0.05, 0.05, n)[:, None] * a
    if k == "plane":
        u = rng.uniform(-0.05, 0.05, (n, 2))
        return c + u[:, :1] * e1 + u[:, 1:] * e2
    if k == "sphere":
        v = rng.normal(size=(n, 3))
        return c + f.radius * v / np.linalg.norm(v, axis=1, keepdims=True)
    if k == "line3d":
        return c + rng.uniform(-0.05, 0.05, n)[:, None] * a
    if k in ("cylinder", "cone"):
        phi = rng.uniform(0, 2 * np.pi, n)
        u = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
        if k == "cylinder":
            return c + rng.uniform(-0.05, 0.05, n)[:, None] * a + f.radius * u
        t = rng.uniform(0.02, 0.08, n)[:, None]
        return c + t * (np.cos(f.half_angle) * a + np.sin(f.half_angle) * u)
    if k == "extruded":
        P = f.profile
        seg = rng.integers(0, len(P) - 1, n)
        t = rng.uniform(0, 1, n)[:, None]
        q = P[seg] + t * (P[seg + 1] - P[seg])
        h = rng.uniform(-0.03, 0.03, n)[:, None]
        return c + h * a + q[:, :1] * e1 + q[:, 1:] * e2
    if k == "freeform":
        tri = f.index.vertices[f.index.faces]
        fi = rng.integers(0, len(tri), n)
        u, v = rng.random(n), rng.random(n)
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        return tri[fi, 0] + u[:, None] * (tri[fi, 1] - tri[fi, 0]) + v[:, None] * (tri[fi, 2] - tri[fi, 0])
    raise AssertionError(k)


# ------------------------------------------------------------------------------- the table
def test_table_has_the_nine_features_with_their_quotient_dimensions():
    assert FEATURE_TYPES == tuple(TABLE_DIMS)
    for name, dim in TABLE_DIMS.items():
        info = FEATURE_TABLE[name]
        assert info.quotient_dim == dim
        g = symmetry_group(name)
        assert g.quotient_dim == dim
        assert g.dim == (3 if info.planar else 6) - dim
        assert g.name == info.group
    assert [FEATURE_TABLE[n].group for n in FEATURE_TYPES] == [
        "SO(2)", "T(1)", "SO(3)", "SE(2)", "SO(2)xT(1)", "SO(2)xT(1)", "SO(2)", "T(1)", "{1}"]


@pytest.mark.parametrize("kind", FEATURE_TYPES)
def test_g0_leaves_the_feature_unchanged_and_m0_moves_it(kind):
    f = example_features()[kind]
    g = f.group
    X = sample_feature(f, 200, np.random.default_rng(1))
    assert np.max(np.abs(f.closest(X).distance)) < ON_FEATURE_M
    # g_0 and m_0 together span the ambient algebra (se(2) for planar features)
    ambient = 3 if g.planar else 6
    assert np.linalg.matrix_rank(np.vstack([g.g0, g.m0]), tol=1e-9) == ambient
    for eta in g.g0:
        for t in (0.3, -1.1):
            moved = transform_points(exp_se3(t * eta), X)
            assert np.max(np.abs(f.closest(moved).distance)) < ON_FEATURE_M * 1e3
            assert g.contains(exp_se3(t * eta))
    for eta in g.m0:
        moved = transform_points(exp_se3(0.05 * eta), X)
        assert np.max(np.abs(f.closest(moved).distance)) > OFF_FEATURE_M
        assert not g.contains(exp_se3(0.01 * eta))
    # unit bases: |omega| = 1 for rotations, |v| = 1 for translations
    for eta in np.vstack([g.g0, g.m0]):
        nw = np.linalg.norm(eta[:3])
        assert nw == pytest.approx(1.0) or (nw < ORTHOGONAL_TOL and np.linalg.norm(eta[3:]) == pytest.approx(1.0))


def test_complement_is_orthogonal_about_the_reference_point():
    g = symmetry_group("cylinder", [0.1, -0.2, 0.3], [1.0, 2.0, 3.0])

    def about_c(x):  # [omega, velocity of the reference point]
        return np.concatenate([x[:3], x[3:] + np.cross(x[:3], g.origin)])

    G = np.array([about_c(x) for x in g.g0])
    M = np.array([about_c(x) for x in g.m0])
    assert np.max(np.abs(G @ M.T)) < ORTHOGONAL_TOL


def test_unknown_feature_type_lists_the_valid_ones():
    with pytest.raises(AlgorithmError, match="unknown feature type 'torus'.*circle2d.*freeform"):
        check_feature_type("torus")
    with pytest.raises(AlgorithmError, match="valid types are"):
        make_feature("ellipsoid", center=[0, 0, 0])
    with pytest.raises(AlgorithmError, match="valid types are"):
        symmetry_group("helix")


@pytest.mark.parametrize("call, message", [
    (lambda: Feature.sphere([0, 0, 0], -1.0), "radius must be a positive length"),
    (lambda: Feature.cone([0, 0, 0], [0, 0, 1], 2.0), r"half_angle must be in \(0, pi/2\)"),
    (lambda: Feature.plane([0, 0, 0], [0, 0, 0]), "normal|axis must be a non-zero vector"),
    (lambda: Feature.line2d([0, 0], [0, 0, 1]), "direction must lie in the xy plane"),
    (lambda: Feature.circle2d([0, 0, 0.1], 0.01), "lies in the plane z = 0"),
    (lambda: Feature.extruded([0, 0, 1]), "exactly one of profile or mesh"),
    (lambda: make_feature("cylinder", point=[0, 0, 0], axis=[0, 0, 1]), "bad parameters for a cylinder"),
])
def test_bad_feature_parameters_are_one_line_errors(call, message):
    with pytest.raises(AlgorithmError, match=message):
        call()


def test_cone_closest_points_are_exact():
    f = Feature.cone([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], np.radians(30.0))
    # a point off the cone: distance along the outward normal in its axial half-plane
    p = np.array([[0.05, 0.0, 0.02]])
    pr = f.closest(p)
    n = np.array([np.cos(np.radians(30.0)), 0.0, -np.sin(np.radians(30.0))])
    gen = np.array([np.sin(np.radians(30.0)), 0.0, np.cos(np.radians(30.0))])
    assert pr.distance[0] == pytest.approx(p[0] @ n, abs=CLOSED_FORM_M)
    assert np.allclose(pr.foot[0], (p[0] @ gen) * gen, atol=CLOSED_FORM_M)


# ---------------------------------------------------------------------------- mesh faces
def _cylinder_side():
    m = trimesh.creation.cylinder(radius=0.02, height=0.06, sections=64)
    T = exp_se3([0.3, -0.2, 0.1, 0.01, 0.02, 0.03])
    m.apply_transform(T)
    side = np.nonzero(np.abs(m.face_normals @ T[:3, 2]) < 1e-6)[0]
    return m, side, T


@pytest.mark.parametrize("kind", [None, "cylinder"])
def test_cylinder_is_fitted_and_classified_from_mesh_faces(kind):
    m, side, T = _cylinder_side()
    f = Feature.from_mesh(m, side, kind=kind)
    assert f.kind == "cylinder" and f.source == "mesh faces"
    assert f.radius == pytest.approx(0.02, abs=FIT_M)
    assert abs(abs(f.axis @ T[:3, 2]) - 1.0) < FIT_AXIS_RAD
    d = np.cross(f.origin - T[:3, 3], T[:3, 2])
    assert np.linalg.norm(d) < FIT_M


def test_classification_of_mesh_faces():
    box = trimesh.creation.box([0.04, 0.05, 0.06])
    top = np.nonzero(box.face_normals[:, 2] > 0.99)[0]
    assert Feature.from_mesh(box, top).kind == "plane"
    ball = trimesh.creation.icosphere(3, 0.03)
    assert Feature.from_mesh(ball).kind == "sphere"
    assert Feature.from_mesh(ball).radius == pytest.approx(0.03, abs=FIT_M)
    cone = trimesh.creation.cone(0.03, 0.05, sections=64)
    lateral = np.nonzero(cone.face_normals[:, 2] > 0.01)[0]
    fc = Feature.from_mesh(cone, lateral)
    assert fc.kind == "cone"
    assert fc.half_angle == pytest.approx(np.arctan2(0.03, 0.05), abs=FIT_AXIS_RAD)
    # the walls of a prism over a sine profile: only translation along z leaves them unchanged
    s = np.linspace(-0.04, 0.04, 81)
    xy = np.column_stack([s, 0.01 * np.sin(60 * s)])
    V = np.vstack([np.column_stack([xy, np.zeros(81)]), np.column_stack([xy, np.full(81, 0.02)])])
    i = np.arange(80)
    F = np.vstack([np.column_stack([i, i + 1, i + 82]), np.column_stack([i, i + 82, i + 81])])
    walls = trimesh.Trimesh(V, F, process=False)
    fe = Feature.from_mesh(walls)
    assert fe.kind == "extruded" and abs(abs(fe.axis[2]) - 1.0) < FIT_AXIS_RAD
    assert Feature.from_mesh(bumpy_mesh()).kind == "freeform"


def test_mesh_faces_that_are_not_the_requested_kind_are_refused():
    box = trimesh.creation.box([0.04, 0.05, 0.06])
    with pytest.raises(AlgorithmError, match="the faces are not a cylinder: fit RMS"):
        Feature.from_mesh(box, kind="cylinder")
    with pytest.raises(AlgorithmError, match="is a curve, not a surface"):
        Feature.from_mesh(box, kind="line3d")
    with pytest.raises(AlgorithmError, match="valid types are"):
        Feature.from_mesh(box, kind="blob")
