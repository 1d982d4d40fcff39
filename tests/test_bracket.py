"""The user-mesh scenario: the bracket STL loads through the scenario's mesh key, is the closed
solid its script makes, and its scan localizes in all six directions."""

from __future__ import annotations

import importlib.util

import numpy as np

from algorithms.geometry.se3 import rotation_error_rad, translation_error_m
from tests.helpers import SCENARIOS, scenario
from twin.parts.loading import load_mesh
from twin.realize import load_workpiece_mesh

BRACKET_STL = SCENARIOS / "meshes" / "bracket.stl"


def _make_bracket():
    spec = importlib.util.spec_from_file_location("make_bracket", SCENARIOS / "meshes" / "make_bracket.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bracket_stl_is_a_small_closed_solid_in_millimetres():
    assert BRACKET_STL.stat().st_size < 300_000
    with BRACKET_STL.open("rb") as f:
        assert not f.read(5).startswith(b"solid")   # binary STL
    mesh = load_mesh(BRACKET_STL, "mm")
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert mesh.euler_number == -2                  # genus 2: the two through holes
    np.testing.assert_allclose(mesh.bounds, [[-0.06, -0.04, 0.0], [0.06, 0.04, 0.025]], atol=1e-12)


def test_bracket_scenario_loads_the_file_its_script_makes():
    sc = scenario("bracket")
    assert sc.workpiece.mesh.endswith("bracket.stl") and sc.workpiece.units == "mm"
    mesh = load_workpiece_mesh(sc)
    made = _make_bracket().build_mesh()
    assert len(made.faces) == len(mesh.faces)
    np.testing.assert_allclose(made.volume * 1e-9, mesh.volume, rtol=1e-6)
    T_nom, T_true = sc.workpiece.T_world_workpiece_nominal, sc.workpiece.T_world_workpiece_true
    assert 1e-3 < translation_error_m(T_nom, T_true) < 0.01
    assert np.radians(0.5) < rotation_error_rad(T_nom, T_true) < np.radians(3)


def test_bracket_scan_localizes_in_all_six_directions():
    from algorithms.registration.local import localize
    from twin.cell import build_cell
    from twin.realize import realize
    from twin.scan import run_scan
    from twin.sensors.laser import sensor_sigma_m

    sc = scenario("bracket")
    realized = realize(sc)
    scan = run_scan(realized, build_cell(realized, "nominal"), build_cell(realized, "true"))
    loc = localize(scan.line_points_base, index=realized.workpiece.index, init=realized.T_base_workpiece_nominal,
                   sigma=sensor_sigma_m(sc))
    assert loc.observable
    assert loc.rmse_m < 5e-6
    assert translation_error_m(loc.T_world_workpiece, realized.T_base_workpiece_true) < 20e-6
    assert rotation_error_rad(loc.T_world_workpiece, realized.T_base_workpiece_true) < np.radians(0.01)
