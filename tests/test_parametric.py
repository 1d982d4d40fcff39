"""Exact surfaces and document 000's Newton foot points: feet recovered on every surface kind,
the generated parts' exact surfaces against their meshes, Algorithm 1 as printed on them, and the
study keys that choose them."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.parametric import BezierRevolution, Cylinder, ParametricModel, Plane, Sphere, _bezier
from algorithms.geometry.se3 import exp_se3, transform_points, translation_error_m
from algorithms.registration import localize
from tests.helpers import ROOT
from twin.errors import TwinError
from twin.parts import bottle_profile_bezier, make_workpiece
from twin.parts.exact import exact_surfaces


def test_feet_of_plane_sphere_and_cylinder_are_exact():
    rng = np.random.default_rng(0)
    x = rng.normal(0, 0.05, (200, 3))
    f, n = Plane((0, 0, 0.01), (0, 0, 2.0)).feet(x)
    assert np.allclose(f[:, 2], 0.01) and np.allclose(f[:, :2], x[:, :2]) and np.allclose(n, [0, 0, 1])
    f, n = Sphere((0.01, 0, 0), 0.03).feet(x)
    assert np.allclose(np.linalg.norm(f - [0.01, 0, 0], axis=1), 0.03) and np.allclose(f + 0 * n, f)
    assert np.allclose(np.cross(x - [0.01, 0, 0], n), 0.0, atol=1e-15)
    f, n = Cylinder((0.02, -0.01), 0.006, (0.0, 0.01)).feet(x)
    assert np.allclose(np.linalg.norm(f[:, :2] - [0.02, -0.01], axis=1), 0.006) and np.allclose(f[:, 2], x[:, 2])


def test_newton_recovers_the_foot_on_the_bezier_bottle():
    """A point moved off the bottle's surface along its normal by s: the foot is the surface
    point, the distance |s| (the Newton of document 000's step (3))."""
    ctrl = bottle_profile_bezier()
    surface = BezierRevolution((0.0, 0.0, 0.015), (1.0, 0.0, 0.0), ctrl)
    rng = np.random.default_rng(1)
    seg, t, phi = rng.integers(0, len(ctrl), 300), rng.uniform(0.05, 0.95, 300), rng.uniform(0, np.pi, 300)
    p = np.array([_bezier(ctrl[k], np.array([tk]))[0][0] for k, tk in zip(seg, t, strict=True)])
    dp = np.array([_bezier(ctrl[k], np.array([tk]))[1][0] for k, tk in zip(seg, t, strict=True)])
    radial = np.column_stack([np.zeros(300), np.cos(phi), np.sin(phi)])
    on = np.array([0.0, 0.0, 0.015]) + p[:, :1] * [1, 0, 0] + p[:, 1:] * radial
    nm = np.column_stack([-dp[:, 1], dp[:, 0]])
    nm /= np.linalg.norm(nm, axis=1, keepdims=True)
    normal = nm[:, :1] * [1, 0, 0] + nm[:, 1:] * radial
    s = rng.uniform(-2e-4, 2e-4, 300)
    foot, n = surface.feet(on + s[:, None] * normal)
    assert np.max(np.linalg.norm(foot - on, axis=1)) < 1e-9
    assert np.allclose(np.einsum("ij,ij->i", n, normal), 1.0, atol=1e-9)


@pytest.mark.parametrize("name", ["hemisphere_punch", "bottle_punch"])
def test_exact_surfaces_lie_within_the_mesh_chord_tolerance(name):
    """Points on the mesh's measured faces are within its 10 um chord tolerance of the exact
    surfaces, and the exact normals agree with the mesh's within its faceting."""
    mesh = make_workpiece(name)
    index = MeshIndex(mesh)
    model = ParametricModel(exact_surfaces(name), index.extent)
    top = mesh.triangles_center[:, 2] > 0.001  # the bottom face is not modelled
    X, faces = trimesh.sample.sample_surface(mesh, 4000, seed=3)
    X = X[top[faces]]
    cp = model.query(X)
    assert np.max(cp.distance) <= 1.01e-5
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", cp.normal, index.query(X).normal), -1, 1)))
    assert np.percentile(angle, 99) < 3.0


def test_trims_give_a_dome_point_at_the_pins_height_to_the_sphere():
    model = ParametricModel(exact_surfaces("hemisphere_punch"), 0.15)
    # on the hemisphere (centre (0.01, 0, 0.02), radius 0.035) at the pins' top height z = 0.035
    z = 0.035
    r = np.sqrt(0.035**2 - (z - 0.02) ** 2)
    cp = model.query([[0.01 + r, 0.0, z]])
    assert cp.face[0] == 0 and cp.distance[0] < 1e-12


def test_algorithm_1_as_printed_with_newton_feet_recovers_an_exact_part():
    """On points of the exact surfaces the document's foot points fit exactly; the mesh's closest
    points carry its chord error as a bias of micrometres."""
    mesh = make_workpiece("hemisphere_punch")
    index = MeshIndex(mesh)
    model = ParametricModel(exact_surfaces("hemisphere_punch"), index.extent)
    rng = np.random.default_rng(4)
    X, faces = trimesh.sample.sample_surface(mesh, 6000, seed=5)
    dome = (X[:, 2] > 0.0201) & (np.linalg.norm(X[:, :2] - [0.01, 0.0], axis=1) < 0.034)
    side_x = np.column_stack([np.full(25, 0.06), rng.uniform(-0.03, 0.03, 25), rng.uniform(0.002, 0.018, 25)])
    side_y = np.column_stack([rng.uniform(-0.03, 0.03, 25), np.full(25, -0.05), rng.uniform(0.002, 0.018, 25)])
    X = np.vstack([model.query(X[dome][:100]).foot, side_x, side_y])
    T = exp_se3([0.01, 0.02, 0.05, 0.4, 0.1, 0.0])
    Y = transform_points(T, X)
    T0 = T @ exp_se3([0.01, -0.01, 0.01, 0.001, 0.0005, -0.0007])
    newton = localize(Y, index=model, method="hong_tan", init=T0, variant="printed")
    assert translation_error_m(newton.T_world_workpiece, T) < 1e-9
    on_mesh = localize(Y, index=index, method="hong_tan", init=T0, variant="printed")
    assert translation_error_m(on_mesh.T_world_workpiece, T) > 1e-6
    with pytest.raises(AlgorithmError, match="variant='printed'"):
        localize(Y, index=model, method="hong_tan", init=T0)


def test_study_keys_refuse_what_cannot_run(tmp_path):
    from twin.realize import realize
    from twin.scenario import load_scenario
    from twin.studies.spec import load_study
    from twin.studies.trials import exact_model

    study = tmp_path / "s.toml"
    study.write_text(f'name = "s"\nscenario = "{ROOT / "scenarios" / "hemisphere_punch.toml"}"\nkind = "points"\n'
                     'trials = 1\n[points]\ncount = 20\n[localize]\nmethod = "hong_tan"\nfoot_points = "newton"\n')
    with pytest.raises(TwinError, match="variant = 'printed'"):
        load_study(study)
    scenario = load_scenario(ROOT / "scenarios" / "s_surface.toml", machine="arm")
    with pytest.raises(TwinError, match="need a part with exact surfaces"):
        exact_model(scenario, realize(scenario).workpiece)
