"""Scan plans with several passes: explicit ``[[scan.passes]]``, the automatic planner on
through_hole (all six pose directions fixed), and the refusals of bad passes."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from algorithms.geometry.se3 import inv_pose
from algorithms.registration.local import localize
from algorithms.registration.uncertainty import pose_error_twist
from tests.helpers import SCENARIOS, raw_scenario, run_cli, scenario
from twin.cell import build_cell
from twin.errors import TwinError
from twin.plan import PLAN_STEP_M, SHARP_EDGE_DEG, STEP_JUMP_FACTOR, plan_scan
from twin.realize import realize
from twin.scenario import parse_scenario

BEAM_ALIGNED_RAD = 1e-9      # a fixed-beam pass: every sensor z on the beam
POSE_SIGMAS = 3.0            # bar: pose error in each determined direction within 3 sigma
COARSE_SPACING_M = 0.008     # through_hole scanned with every other line (keeps the test short)
HOUSING_CLEARANCE_M = 0.01   # the sensor housing's least distance from the part along a plan
ON_PLAN_M = 1e-5             # a spot between 1 mm planning points on a curved wall: the chord

TOP = {"name": "top", "beam": [0.0, 0.0, -1.0], "line_axis": "x"}
# Looking at the +x end face from 45 deg above, lines running up and down: every line crosses
# the top edge (a sharp edge) and the lines near the middle cross the hole (a step).
SIDE = {"name": "side", "beam": [-1.0, 0.0, -1.0], "line_axis": [0.0, 0.0, 1.0], "max_lines": 60}


def _nominal(sc):
    realized = realize(sc)
    return realized, build_cell(realized, "nominal")


def _explicit(passes):
    raw = raw_scenario("through_hole")
    raw["scan"]["passes"] = passes
    return parse_scenario(raw, name="through_hole", base_dir=SCENARIOS)


@pytest.fixture(scope="module")
def two_pass_plan():
    realized, cell = _nominal(_explicit([TOP, SIDE]))
    return realized, cell, plan_scan(cell)


def test_explicit_passes_look_along_their_beams(two_pass_plan):
    _, cell, plan = two_pass_plan
    assert [p.name for p in plan.passes] == ["top", "side"]
    R_wp = cell.T_world_workpiece[:3, :3]
    for i, beam in enumerate([np.array(TOP["beam"]), np.array(SIDE["beam"]) / math.sqrt(2.0)]):
        lines = np.flatnonzero(plan.line_pass == i)
        assert len(lines) == plan.passes[i].lines > 0
        on = np.isin(plan.line, lines)
        z_wp = plan.T_world_sensor[on, :3, 2] @ R_wp          # sensor z in the workpiece frame
        assert np.max(np.linalg.norm(z_wp - beam, axis=1)) < BEAM_ALIGNED_RAD
        assert np.allclose(plan.passes[i].beam_wp, beam)


def test_line_indices_are_unique_across_passes(two_pass_plan):
    _, _, plan = two_pass_plan
    ids = plan.line[plan.line >= 0]
    n = len(plan.line_pass)
    assert set(np.unique(ids)) == set(range(n))
    # Each line is one contiguous stretch of samples, lines in order, passes in order.
    starts = np.flatnonzero(np.diff(np.concatenate([[-1], plan.line])) != 0)
    runs = plan.line[starts]
    assert list(runs[runs >= 0]) == list(range(n))
    assert np.all(np.diff(plan.line_pass) >= 0)
    assert [p.first_line for p in plan.passes] == [0, plan.passes[0].lines]
    json.dumps([p.to_dict() for p in plan.passes])


def test_lines_split_at_edges_and_steps(two_pass_plan):
    realized, cell, plan = two_pass_plan
    index = realized.workpiece.index
    side = cell.scenario.scan.passes[1]
    T_wp_world = inv_pose(cell.T_world_workpiece)
    max_jump_m = STEP_JUMP_FACTOR * PLAN_STEP_M / math.cos(math.radians(cell.scenario.sensor.max_incidence_deg))
    rows = {}
    for line in np.flatnonzero(plan.line_pass == 1):
        T = plan.T_world_sensor[plan.line == line]
        spot_w = T[:, :3, 3] + side.standoff_m * T[:, :3, 2]
        spot_wp = spot_w @ T_wp_world[:3, :3].T + T_wp_world[:3, 3]
        cp = index.query(spot_wp)
        assert cp.distance.max() < ON_PLAN_M                # the planned spot lies on the CAD model
        n = np.asarray(realized.workpiece.mesh.face_normals)[cp.face]
        # No line crosses a sharp edge (a jump of the face normal) or a step.
        assert np.min(np.einsum("ij,ij->i", n[:-1], n[1:])) > math.cos(math.radians(SHARP_EDGE_DEG))
        assert np.max(np.linalg.norm(np.diff(spot_wp, axis=0), axis=1)) < max_jump_m
        rows.setdefault(round(float(plan.line_y_m[line]), 9), []).append(line)
    # The rows were split: a row crossing the top edge gives a line on the end face and one on
    # the top; one crossing the hole gives more.
    assert max(len(v) for v in rows.values()) >= 3
    assert all(len(v) >= 2 for v in rows.values())


def test_pass_change_climbs_above_the_part_and_the_sensor_stays_clear(two_pass_plan):
    realized, cell, plan = two_pass_plan
    # Between the passes the sensor climbs above the part's top plus the clearance.
    end0 = np.flatnonzero(plan.line == plan.passes[1].first_line - 1)[-1]
    start1 = np.flatnonzero(plan.line == plan.passes[1].first_line)[0]
    top_w = (realized.workpiece.mesh.vertices @ cell.T_world_workpiece[:3, :3].T + cell.T_world_workpiece[:3, 3])[:, 2]
    climb = plan.T_world_sensor[end0:start1, 2, 3].max()
    assert climb >= top_w.max() + cell.scenario.scan.transit_clearance_m - 1e-9
    # The sensor housing (a box on the sensor body) keeps clear of the part all along the plan.
    g = cell.model.geom("laser_housing")
    corners = g.pos + g.size * np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 0, 1)])
    T = plan.T_world_sensor[::10]
    pts_w = np.einsum("kij,nj->kni", T[:, :3, :3], corners) + T[:, None, :3, 3]
    T_wp_world = inv_pose(cell.T_world_workpiece)
    pts_wp = pts_w.reshape(-1, 3) @ T_wp_world[:3, :3].T + T_wp_world[:3, 3]
    assert realized.workpiece.index.query(pts_wp).distance.min() > HOUSING_CLEARANCE_M


@pytest.fixture(scope="module")
def auto_plan():
    sc = scenario("through_hole", scan={"line_spacing_m": COARSE_SPACING_M})
    realized, cell = _nominal(sc)
    return sc, realized, cell, plan_scan(cell)


def test_auto_planner_fixes_all_six_directions_on_through_hole(auto_plan):
    sc, _, _, plan = auto_plan
    assert sc.scan.auto is not None
    first, last = plan.passes[0], plan.passes[-1]
    assert first.name == "top view" and set(first.fixed) == {"z", "rx", "ry"}
    assert first.predicted_min_relative_eigenvalue < sc.scan.auto.min_relative_eigenvalue
    assert 2 <= len(plan.passes) <= sc.scan.auto.max_passes
    assert last.predicted_min_relative_eigenvalue >= sc.scan.auto.min_relative_eigenvalue
    assert set(last.fixed) == {"x", "y", "z", "rx", "ry", "rz"}
    for p in plan.passes[1:]:
        assert p.reason.startswith(p.name) and ("fixes" in p.reason or "raises" in p.reason)
        assert np.linalg.norm(p.beam_wp[:2]) > 0.1          # the added views are tilted
    assert sum(p.lines for p in plan.passes) == len(plan.line_pass)


def test_auto_scan_of_through_hole_localizes_in_six_directions(auto_plan):
    from twin.scan import run_scan
    from twin.scan_uncertainty import pose_covariance
    from twin.sensors.laser import sensor_sigma_m

    sc, realized, nominal, _ = auto_plan
    scan = run_scan(realized, nominal, build_cell(realized, "true"))
    loc = localize(scan.line_points_base, index=realized.workpiece.index, init=realized.T_base_workpiece_nominal,
                   sigma=sensor_sigma_m(sc))
    assert loc.observable and len(loc.free_directions) == 0
    # The error along each determined direction within 3 sigma of the reported covariance
    # (Cramer-Rao plus the sensor's linearity as a systematic error).
    C = pose_covariance(scan, loc, realized.workpiece.index)
    D = np.asarray(loc.determined_directions, dtype=np.float64).reshape(-1, 6)
    assert D.shape == (6, 6)
    xi = pose_error_twist(loc.T_world_workpiece, realized.T_base_workpiece_true)
    m = np.linalg.lstsq(D.T, xi, rcond=None)[0]
    assert np.all(np.abs(m) <= POSE_SIGMAS * np.sqrt(np.diag(C))), (m / np.sqrt(np.diag(C)))


def test_auto_planner_skips_views_the_arm_cannot_reach():
    far = {"xyz": [0.88, 0.10, 0.0]}                       # near the end of the UR5e's reach
    sc = scenario("through_hole", scan={"line_spacing_m": COARSE_SPACING_M},
                  workpiece={"true_pose": far, "nominal_pose": far})
    _, cell = _nominal(sc)
    plan = plan_scan(cell)
    assert any(n.startswith("top view: skipped, the arm cannot reach") for n in plan.notes)
    assert plan.passes[0].name != "top view" and "the first view the arm reaches" in plan.passes[0].reason
    assert plan.passes[-1].predicted_min_relative_eigenvalue >= sc.scan.auto.min_relative_eigenvalue


def test_an_unreachable_line_names_its_pass():
    from twin.scan import scan_scenario

    raw = raw_scenario("through_hole")
    raw["scan"]["passes"] = [{**TOP, "max_lines": 2}, {**SIDE, "max_lines": 2}]
    raw["workpiece"]["true_pose"] = raw["workpiece"]["nominal_pose"] = {"xyz": [0.9, 0.0, 0.0]}
    with pytest.raises(TwinError, match=r"scan line \d+ \(pass 'top'\) is unreachable"):
        scan_scenario(parse_scenario(raw))


@pytest.mark.parametrize("pass_table, message", [
    ({"beam": [0.0, 0.0, 0.0]}, "scan.passes[0].beam must be a non-zero vector"),
    ({"beam": [0.0, float("nan"), -1.0]}, "scan.passes[0].beam must be finite"),
    ({"beam": "down"}, 'scan.passes[0].beam must be "normal" or a direction'),
    ({"beam": "normal", "view": [0.0, 0.0, 0.0]}, "scan.passes[0].view must be a non-zero vector"),
    ({"bem": [0.0, 0.0, -1.0]}, "unknown key(s) scan.passes[0].bem"),
    ({"standoff_m": 0.2}, "scan.passes[0].standoff_m = 0.2 m is outside the sensor window"),
    ({"line_axis": [0.0, 0.0, 1.0]}, "scan.passes[0].line_axis [0.0, 0.0, 1.0] is within 10 deg of the view"),
    ({"region_m": [[0.01, 0.0], [0.0, 0.01]]}, "scan.passes[0].region_m must be"),
])
def test_bad_pass_is_refused_when_loaded(pass_table, message):
    with pytest.raises(TwinError) as exc:
        _explicit([pass_table])
    assert message in str(exc.value)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("over, message", [
    ({"passes": []}, 'scan.passes must be "auto" or a non-empty list'),
    ({"passes": "all"}, 'scan.passes must be "auto" or a non-empty list'),
    ({"passes": None, "auto_max_passes": 3}, 'scan.auto_max_passes applies to scan.passes = "auto" only'),
    ({"auto_tilts_deg": [0.0]}, "scan.auto_tilts_deg must be a non-empty list of tilts in (0, 80] deg"),
])
def test_bad_scan_pass_settings_are_refused(over, message):
    raw = raw_scenario("through_hole")
    for k, v in over.items():
        if v is None:
            raw["scan"].pop(k, None)
        else:
            raw["scan"][k] = v
    with pytest.raises(TwinError) as exc:
        parse_scenario(raw)
    assert message in str(exc.value) and "\n" not in str(exc.value)


@pytest.mark.parametrize("region, message", [
    ([[0.2, 0.2, 0.0], [0.3, 0.3, 0.1]], "region_m [[0.2, 0.2, 0.0], [0.3, 0.3, 0.1]] lies outside the part"),
    # Inside the block's material below the hole: every ray stops on the top face first.
    ([[-0.01, -0.01, 0.002], [0.01, 0.01, 0.006]], "no planning ray hits the part in its region"),
])
def test_bad_region_is_refused_when_planned(region, message):
    _, cell = _nominal(_explicit([{"name": "bad", "region_m": region}]))
    with pytest.raises(TwinError) as exc:
        plan_scan(cell)
    assert message in str(exc.value) and "scan pass 'bad'" in str(exc.value)
    assert "\n" not in str(exc.value)


def test_cli_refuses_a_bad_pass_with_exit_2(tmp_path):
    text = (SCENARIOS / "through_hole.toml").read_text().replace(
        '\npasses = "auto"\n', "\n\n[[scan.passes]]\nbeam = [0.0, 0.0, 0.0]\n")
    path = tmp_path / "bad_pass.toml"
    path.write_text(text)
    r = run_cli("scan", str(path), "--out", str(tmp_path / "out"))
    assert r.returncode == 2
    assert "scan.passes[0].beam must be a non-zero vector" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_single_pass_plans_carry_one_pass():
    _, cell = _nominal(scenario("s_surface", scan={"max_lines": 2}))
    plan = plan_scan(cell)
    assert len(plan.passes) == 1 and plan.passes[0].name == "scan"
    assert np.all(plan.line_pass == 0) and len(plan.line_pass) == len(plan.line_y_m)
