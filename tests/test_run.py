"""The closed loop: scan -> localize -> path -> IK -> replay, its report, recording and bad input."""

import json

import numpy as np
import pytest

from algorithms.geometry.se3 import make_pose
from algorithms.paths.toolpath import transform_path
from tests.helpers import SCENARIOS, run_cli, scenario
from tests.tolerances import MAX_DEVIATION_MM, MAX_SURFACE_ERROR_MM, TRIANGULATION_RMS_DEG
from twin.cell import build_cell
from twin.cli.run import run_and_report
from twin.io.output import Staged
from twin.replay import replay
from twin.trajectory import plan_joint_trajectory

SHORT = {"scan": {"max_lines": 3}, "path": {"line_spacing_m": 0.02}}


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "out"
    sc = scenario("s_surface", **SHORT)
    with Staged(out) as stage:
        result, report = run_and_report(sc, stage, out / "run.rrd")
        stage.commit()
    return sc, out, report, result


def test_report_has_the_promised_fields_and_meets_the_bars(loop):
    sc, out, report, _ = loop
    assert json.loads((out / "report.json").read_text()) == json.loads(json.dumps(report))
    loc = report["localization"]
    assert loc["rotation_error_deg"] < 0.01 and loc["translation_error_mm"] < 0.02
    pv = report["path_verification"]
    assert pv["path"] == "scan_path"
    assert 0 < pv["max_deviation_mm"] < MAX_DEVIATION_MM and 0 < pv["rms_deviation_mm"] <= pv["max_deviation_mm"]
    assert pv["unintended_contacts"] == 0 and pv["joint_limit_hits"] == []
    assert all(c["intended"] for c in pv["contacts"])
    assert any(c["geom"] == "tool_tip" for c in pv["contacts"])  # the process does touch
    assert report["max_surface_error_mm"] < MAX_SURFACE_ERROR_MM
    # without the localization the same CAD path misses the part by about a millimetre
    assert report["cad_path"]["uncompensated_max_surface_error_mm"] > 10 * report["max_surface_error_mm"]
    sp = report["scan_path"]
    assert sp["lines"] == 3
    assert sp["contact_surface_error_max_um"] < sp["contact_surface_bound_um"]
    assert sp["normals_triangulation_rms_deg"] < TRIANGULATION_RMS_DEG
    assert sp["ik"]["problems"] == [] and sp["ik"]["max_joint_velocity_ratio"] <= 1.0
    for key in ("scan_s", "localize_s", "scan_path_ik_s", "scan_path_replay_s", "cad_path_replay_s", "recording_s"):
        assert report["timings_s"][key] >= 0.0
    v = sp["verification"]
    assert v["simulated_s"] > 0 and v["sim_speed_x_realtime"] > 1


def test_replay_log_is_consistent(loop):
    _, _, report, result = loop
    run = result.runs[0]
    log, path = run.log, run.path
    assert log.process.any()
    # the replayed TCP follows the commanded one to within the servo lag
    assert np.nanmax(log.deviation_m) <= log.tracking_error_m.max() + 1e-9
    # the ball end is on the part along the process lines, within the servo lag
    assert np.abs(log.tip_surface_m[log.process]).max() < MAX_DEVIATION_MM * 1e-3
    # and clear of it during the transits
    assert log.tip_surface_m[log.kind == "transit"].min() > 0.005
    assert len(log.t) == int(round(log.sim_s / 0.001))
    assert path.n_lines == 3


def test_recording_has_the_paths_frames_and_normals(loop):
    from rerun.chunk import RrdReader  # rerun 0.41: recordings are read back as chunks

    _, out, _, _ = loop
    entities = {c.entity_path for c in RrdReader(str(out / "run.rrd")).stream().to_chunks()}
    for name in ("scan_path", "cad_path"):
        for leaf in ("planned", "tool_frames", "normals", "tcp"):
            assert f"/world/path/{name}/{leaf}" in entities
    assert "/world/robot/wrist_3_link/tool" in entities and "/world/scan/beam" in entities


def test_a_tool_driven_into_the_part_is_an_unintended_contact(loop):
    sc, _, _, result = loop
    cell = result.replay_cell
    cad = result.run("cad_path").path
    a = cad.segments[0][0]
    b = cad.segments[3][1]  # approach, first line, retract: one line only
    one = type(cad)(cad.T_tool[a:b + 1], cad.contact[a:b + 1], cad.normal[a:b + 1], cad.segment[a:b + 1],
                    cad.segments[:3], cad.s[a:b + 1], cad.tip_radius_m)
    sunk = transform_path(make_pose(p=[0.0, 0.0, -0.009]), one)  # 9 mm into the part
    nominal = build_cell(result.realized, "nominal")
    p = sc.path
    _, traj = plan_joint_trajectory(nominal, sunk, p.T_flange_tool, p.feed_m_s, p.transit_speed_m_s,
                                    p.acceleration_m_s2, touchdown_acceleration_m_s2=p.touchdown_acceleration_m_s2)
    log = replay(cell, traj, sunk, result.realized.workpiece.index)
    bad = [c for c in log.contacts if not c.intended]
    assert any(c.geom == "tool_shank" and c.other == "workpiece_collision" for c in bad)
    shank = next(c for c in bad if c.geom == "tool_shank")
    # a physical contact: the servos push the shank into the height field, which pushes back
    assert shank.steps > 0 and shank.max_penetration_m > 0.0
    assert np.nanmax(log.deviation_m) > 0.001
    tip = next(c for c in log.contacts if c.geom == "tool_tip" and c.intended)
    # the ball end is buried until the shank, 4 mm above the contact point, hits the part
    assert 0.003 < tip.max_penetration_m < 0.009



def write(tmp_path, edit):
    text = (SCENARIOS / "s_surface.toml").read_text().replace('line_axis = "x"', 'line_axis = "x"\nmax_lines = 2')
    p = tmp_path / "s.toml"
    p.write_text(edit(text))
    return p


@pytest.mark.parametrize("edit, message", [
    (lambda t: t + "\n[path]\nfeed_m_s = 0.0\n", "path.feed_m_s = 0.0 is outside the allowed range (0, 1]"),
    (lambda t: t + "\n[path]\nfeed_m_s = -0.02\n", "path.feed_m_s = -0.02 is outside"),
    (lambda t: t + "\n[path]\ntool = { matrix = [[1, 0.1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.1], [0, 0, 0, 1]] }\n",
     "path.tool.matrix rotation is not orthonormal"),
    (lambda t: t + "\n[path]\nfeed = 0.03\n", "unknown key(s) path.feed"),
])
def test_bad_input_is_one_clear_line_and_no_report(tmp_path, edit, message):
    out = tmp_path / "out"
    r = run_cli("run", str(write(tmp_path, edit)), "--out", str(out))
    assert r.returncode == 2, r.stdout + r.stderr
    errors = [line for line in r.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and message in errors[0], r.stderr
    assert "Traceback" not in r.stderr
    assert not (out / "report.json").exists()


@pytest.mark.parametrize("edit, stage, message", [
    (lambda t: t.replace("max_lines = 2", "max_lines = 1"), "scan_path",
     "needs at least 2 lines with valid points, got 1 (scan line 0)"),
    pytest.param(lambda t: t + "\n[path]\ntool = { xyz = [0.0, 0.0, 2.0], rpy_deg = [180.0, 0.0, 0.0] }\n",
                 "scan_path", "unreachable", marks=pytest.mark.slow),
])
def test_a_stage_that_fails_leaves_a_partial_report(tmp_path, edit, stage, message):
    out = tmp_path / "out"
    r = run_cli("run", str(write(tmp_path, edit)), "--out", str(out))
    assert r.returncode == 4, r.stdout + r.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["complete"] is False and report["failed_stage"] == stage
    assert message in report["failure"] and "Traceback" not in r.stderr
    assert "scan" in report and "localization" in report and "cad_path" not in report


def test_the_run_writes_its_figures_and_a_report_page(loop):
    _, out, report, _ = loop
    assert set(report["figures"]) >= {"scan_residuals.png", "scan_deviation_map.png", "path_deviation.png",
                                      "tracking_error.png"}
    for name in report["figures"]:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    page = (out / "report.html").read_text()
    assert all(f'src="{name}"' in page for name in report["figures"]) and "pass" in page
