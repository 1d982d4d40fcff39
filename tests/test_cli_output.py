"""What the commands print: the result alone on stdout (JSON with --json, else a summary for a
reader), progress on stderr (plain lines off a terminal, bars on one, nothing with --quiet);
``twin view`` and ``twin export-mesh``."""

import io
import json
import os
import subprocess
import time

import numpy as np
import pytest

from tests.helpers import SCENARIOS, assert_pose_close, run_cli, sample_surface
from tests.tolerances import RECOVER_M, RECOVER_RAD
from twin.cli import COMMANDS, main
from twin.cli import view as view_cli
from twin.cli.common import EXIT_BAD_INPUT, Progress
from twin.io.output import PARTIAL_MARK


def short_scenario(folder):
    """The S-surface scenario cut to one scan line (a scan of a few seconds)."""
    p = folder / "short.toml"
    p.write_text((SCENARIOS / "s_surface.toml").read_text().replace('line_axis = "x"',
                                                                     'line_axis = "x"\nmax_lines = 1'))
    return p


def run_main(capsys, *argv):
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def one_line_refusal(rc, err):
    return rc == EXIT_BAD_INPUT and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def leftovers(folder):
    return [p.name for p in folder.rglob("*") if PARTIAL_MARK in p.name]


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    """One short scan with --json and a recording, one with --quiet and the summary."""
    d = tmp_path_factory.mktemp("out")
    scen = short_scenario(d)
    loud = run_cli("scan", str(scen), "--out", str(d / "loud"), "--rrd", str(d / "scan.rrd"), "--json")
    quiet = run_cli("scan", str(scen), "--out", str(d / "quiet"), "--quiet")
    return d, loud, quiet


# ------------------------------------------------------------------ stdout and stderr
def test_json_is_all_there_is_on_stdout(scans):
    d, loud, _ = scans
    assert loud.returncode == 0, loud.stderr
    summary = json.loads(loud.stdout)  # the whole of stdout, as `| python -m json.tool` reads it
    assert summary["out"] == str(d / "loud") and summary["recording"] == str(d / "scan.rrd")
    assert summary["samples"] == json.loads((d / "loud" / "scan.json").read_text())["n_samples"]
    assert 0 < summary["valid"] <= summary["samples"]


def test_progress_goes_to_stderr_as_plain_lines(scans):
    _, loud, _ = scans
    lines = loud.stderr.strip().splitlines()
    assert any(line.startswith("[scan] scanned ") for line in lines), loud.stderr
    assert all(line.startswith("[scan] ") for line in lines), loud.stderr
    assert "\r" not in loud.stderr and "\x1b" not in loud.stderr  # not a terminal: nothing animated


def test_without_json_a_summary_for_a_reader_and_quiet_stderr(scans):
    d, _, quiet = scans
    assert quiet.returncode == 0 and quiet.stderr == ""
    with pytest.raises(json.JSONDecodeError):
        json.loads(quiet.stdout)
    rows = dict(line.split(None, 1) for line in quiet.stdout.strip().splitlines() if not line.startswith("wall"))
    assert rows["scan"].startswith("complete: ") and "samples" in rows["scan"] and "valid" in rows["scan"]
    assert rows["files"].startswith(str(d / "quiet"))
    assert "wall time" in quiet.stdout and quiet.stdout.rstrip().endswith(" s")
    # the values stand in one column
    starts = {len(line) - len(line.split("  ", 1)[1].lstrip()) for line in quiet.stdout.strip().splitlines()}
    assert len(starts) == 1


def test_a_refused_scan_prints_its_error_line_only(tmp_path):
    """Stage lines of a scan that then refuses its input (an unreachable line) are not printed."""
    scen = short_scenario(tmp_path)
    scen.write_text(scen.read_text().replace("xyz = [0.450, 0.120, 0.0]", "xyz = [1.3, 0.120, 0.0]"))
    r = run_cli("scan", str(scen), "--out", str(tmp_path / "out"), "--json")
    assert one_line_refusal(r.returncode, r.stderr) and "unreachable" in r.stderr and r.stdout == ""
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ["scan", "run", "demo", "locate"])
def test_every_writing_command_has_json_and_quiet(command, capsys):
    assert main([command, "--help"]) == 0
    text = capsys.readouterr().out
    assert "--json" in text and "--quiet" in text


@pytest.mark.slow
def test_run_prints_its_headline_as_json_only(tmp_path):
    """A two-line run (some 15 s): stdout is the report's headline, nothing else; --quiet: no stderr."""
    scen = short_scenario(tmp_path)
    scen.write_text(scen.read_text().replace("max_lines = 1", "max_lines = 2") + "\n[path]\nline_spacing_m = 0.03\n")
    out = tmp_path / "out"
    r = run_cli("run", str(scen), "--out", str(out), "--json", "--quiet")
    assert r.returncode in (0, 3), r.stderr
    assert r.stderr == ""
    h = json.loads(r.stdout)
    report = json.loads((out / "report.json").read_text())
    assert h["complete"] is report["complete"] is True and h["trusted"] == report["trusted"]
    assert h["report"] == str(out / "report.json") and "localization" in h and "path_verification" in h


HEADLINE = {
    "complete": True, "trusted": True,
    "localization": {"status": "ok", "observable": True, "max_error_sigmas": 1.582,
                     "rotation_error_deg": 0.0019349515419149251, "translation_error_mm": 0.0024397427974560755},
    "path_verification": {"path": "scan_path", "max_deviation_mm": 0.10068681113481275,
                          "rms_deviation_mm": 0.03325085413680578, "contacts": [], "unintended_contacts": 0,
                          "joint_limit_hits": []},
    "max_surface_error_mm": 0.0013371586350909791, "report": "out/report.json", "recording": "out/run.rrd",
    "wall_s": 13.74,
}


def test_run_summary_states_the_verdict_and_the_errors_with_units():
    from twin.cli.run import summary_rows

    rows = dict(summary_rows(HEADLINE))
    assert rows["complete"] == "yes" and rows["trusted"] == "yes"
    assert "rotation error 0.001935 deg, translation error 0.00244 mm" in rows["localization"]
    assert "max deviation 0.1007 mm" in rows["path replay"] and "0 unintended" in rows["path replay"]
    assert rows["surface error"].startswith("max 0.001337 mm")
    assert rows["report"] == "out/report.json" and rows["recording"] == "out/run.rrd" and rows["wall time"] == "13.7 s"
    failed = {"complete": False, "failed_stage": "scan_path", "failure": "too few lines", "trusted": False,
              "localization": {**HEADLINE["localization"], "status": "unobservable", "observable": False,
                               "rotation_error_deg": "free", "translation_error_mm": "free"},
              "report": "out/report.json"}
    rows = dict(summary_rows(failed))
    assert rows["complete"] == "no: stopped at scan_path: too few lines"
    assert rows["trusted"] == "no (localization unobservable)" and "free direction" in rows["localization"]


def test_locate_summary_states_each_stage():
    from twin.cli.locate import summary_rows

    h = {"complete": True, "trusted": False,
         "coarse": {"method": "multistart", "rotation_error_deg": 0.5, "translation_error_mm": 2.5,
                    "within_1mm_1deg": False},
         "effective_radius_error_um": 0.12, "probing": {"points": 12, "hits": 11, "unintended_contacts": 0},
         "fine": {"status": "ok", "rotation_error_deg": 0.001, "translation_error_mm": 0.002,
                  "max_error_sigmas": 2.1},
         "report": "out/report.json", "wall_s": 40.0}
    rows = dict(summary_rows(h))
    assert rows["trusted"] == "no" and "outside 1 mm / 1 deg" in rows["coarse pose"]
    assert rows["probing"] == "11 of 12 points hit, 0 unintended contact(s)"
    assert "0.12 um" in rows["qualification"] and "translation error 0.002 mm" in rows["fine pose"]


# ------------------------------------------------------------------ the progress reporter
def test_plain_lines_off_a_terminal():
    err = io.StringIO()
    with Progress("locate", stream=err) as say:
        say("coarse pass: 100 samples")
        for i in range(1, 4):
            say(f"probe point {i}/3 (p{i}): hit")
    assert err.getvalue().splitlines() == ["[locate] coarse pass: 100 samples", "[locate] probe point 1/3 (p1): hit",
                                           "[locate] probe point 2/3 (p2): hit", "[locate] probe point 3/3 (p3): hit"]


def test_counted_lines_drive_a_bar_on_a_terminal():
    err = io.StringIO()
    with Progress("locate", stream=err, animate=True) as say:
        say("planned 3 probe points")
        for i in range(1, 4):
            say(f"probe point {i}/3 (p{i}): hit")
        say("fine stage: ok")
    text = err.getvalue()
    assert "[locate] planned 3 probe points\n" in text and "[locate] fine stage: ok\n" in text
    bar = [s for s in text.replace("\n", "\r").split("\r") if "probe point" in s]
    assert bar and "3/3" in bar[-1] and "step/s" in bar[-1] and "100%" in bar[-1], text
    assert "probe point 2/3 (p2): hit\n" not in text  # the count moves the bar, it is not a line each


def test_quiet_and_deferred_lines():
    err = io.StringIO()
    with Progress("scan", stream=err, quiet=True) as say:
        say("scanned")
    assert err.getvalue() == ""
    with Progress("scan", stream=err, defer=True) as say:
        say("scanned")
        assert err.getvalue() == ""
    assert err.getvalue() == "[scan] scanned\n"
    err = io.StringIO()
    with pytest.raises(RuntimeError), Progress("scan", stream=err, defer=True) as say:
        say("scanned")
        raise RuntimeError("refused")
    assert err.getvalue() == ""
    # released: the held lines at once, and every later one as it comes
    err = io.StringIO()
    with Progress("scan", stream=err, defer=True) as say:
        say("planned")
        say.release()
        assert err.getvalue() == "[scan] planned\n"
        say("simulated")
        assert err.getvalue() == "[scan] planned\n[scan] simulated\n"


# ------------------------------------------------------------------ twin view
def test_new_commands_are_registered():
    assert "view" in COMMANDS and "export-mesh" in COMMANDS


@pytest.mark.parametrize("name, content, message", [
    ("missing.rrd", None, "not found"),
    ("scan.txt", b"RRF2\x00\x00", "not a .rrd file"),
    ("fake.rrd", b"hello, not a recording", "not a Rerun recording"),
    ("empty.rrd", b"", "not a Rerun recording"),
])
def test_view_refuses_what_is_not_a_recording(tmp_path, capsys, monkeypatch, name, content, message):
    monkeypatch.setattr(view_cli, "launch", lambda argv: pytest.fail(f"a viewer was started: {argv}"))
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    rc, out, err = run_main(capsys, "view", path)
    assert one_line_refusal(rc, err) and message in err and out == ""


def test_view_refuses_a_folder_and_a_port_without_web(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(view_cli, "launch", lambda argv: pytest.fail(f"a viewer was started: {argv}"))
    (tmp_path / "dir.rrd").mkdir()
    rc, _, err = run_main(capsys, "view", tmp_path / "dir.rrd")
    assert one_line_refusal(rc, err) and "not a file" in err
    (tmp_path / "ok.rrd").write_bytes(b"RRF2" + bytes(20))
    rc, _, err = run_main(capsys, "view", tmp_path / "ok.rrd", "--port", "9000")
    assert one_line_refusal(rc, err) and "--port applies with --web" in err
    rc, _, err = run_main(capsys, "view", tmp_path / "ok.rrd", "--web", "--port", "70000")
    assert one_line_refusal(rc, err) and "--port" in err


def test_view_starts_the_rerun_viewer_on_a_recording(scans, capsys, monkeypatch):
    d, _, _ = scans
    started = []
    monkeypatch.setattr(view_cli, "launch", lambda argv: started.append(argv) or (0, ""))
    rc, out, err = run_main(capsys, "view", d / "scan.rrd")
    assert rc == 0 and out == "" and err == ""
    assert started[-1] == [*view_cli.rerun_command(), str(d / "scan.rrd")]
    assert started[-1][0].endswith("rerun") or started[-1][-2:] == ["rerun_cli", str(d / "scan.rrd")]


def test_view_web_serves_on_localhost_and_prints_the_address(tmp_path, capsys, monkeypatch):
    rrd = tmp_path / "old.rrd"
    rrd.write_bytes(b"RRF1" + bytes(20))  # an older release's recording is a recording too
    started = []
    monkeypatch.setattr(view_cli, "launch", lambda argv: started.append(argv) or (0, ""))
    rc, out, _ = run_main(capsys, "view", rrd, "--web", "--port", "0")
    assert rc == 0
    argv = started[-1]
    port = int(argv[argv.index("--web-viewer-port") + 1])
    grpc = int(argv[argv.index("--port") + 1])
    assert argv[argv.index("--serve-web") + 1] == str(rrd) and argv[argv.index("--bind") + 1] == "127.0.0.1"
    assert port > 0 and grpc > 0 and port != grpc
    assert f"http://127.0.0.1:{port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy" in out


def test_view_reports_a_viewer_that_failed(tmp_path, capsys, monkeypatch):
    rrd = tmp_path / "a.rrd"
    rrd.write_bytes(b"RRF2" + bytes(20))
    monkeypatch.setattr(view_cli, "launch", lambda argv: (1, "Error: no display"))
    rc, _, err = run_main(capsys, "view", rrd)
    assert one_line_refusal(rc, err) and "exit status 1: Error: no display" in err


def test_launch_reports_the_viewers_last_log_line_and_leaves_nothing_running(tmp_path):
    """A viewer that logs several (coloured) lines and fails: its last line, plain; a viewer
    whose own child outlives it: the child is ended with the command."""
    script = tmp_path / "viewer.sh"
    script.write_text("#!/bin/sh\nprintf 'starting\\n\\033[31mError:\\033[0m no display\\n' >&2\n"
                      "sleep 300 &\necho $! > \"$1\"\nexit 1\n")
    script.chmod(0o755)
    pid_file = tmp_path / "child.pid"
    code, last = view_cli.launch([str(script), str(pid_file)])
    assert (code, last) == (1, "Error: no display")
    child = int(pid_file.read_text())
    for _ in range(50):
        try:
            os.kill(child, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        raise AssertionError("the viewer's child outlived the command")


# ------------------------------------------------------------------ twin export-mesh
@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    from twin.realize import load_workpiece_mesh
    from twin.scenario import load_scenario

    d = tmp_path_factory.mktemp("mesh")
    scen = SCENARIOS / "s_surface.toml"
    r = run_cli("export-mesh", str(scen), str(d / "part.stl"))
    return d, r, load_workpiece_mesh(load_scenario(scen))


def test_export_mesh_writes_the_scenarios_mesh(exported):
    from twin.parts import load_mesh

    d, r, mesh = exported
    assert r.returncode == 0, r.stderr
    assert r.stderr == "" and leftovers(d) == []
    back = load_mesh(d / "part.stl", "m")
    # binary STL stores float32: the same triangles to float32's resolution at the part's size
    float32_m = np.finfo(np.float32).eps * np.abs(mesh.vertices).max()
    assert back.triangles.shape == mesh.triangles.shape
    assert np.abs(back.triangles - mesh.triangles).max() <= float32_m
    assert f"{len(mesh.faces)}" in r.stdout and str(d / "part.stl") in r.stdout and "bounds" in r.stdout


def test_export_mesh_refuses_an_existing_file_and_force_replaces_it(exported, capsys):
    d, _, mesh = exported
    before = (d / "part.stl").stat().st_mtime_ns
    rc, out, err = run_main(capsys, "export-mesh", SCENARIOS / "s_surface.toml", d / "part.stl")
    assert one_line_refusal(rc, err) and "--force" in err and out == ""
    assert (d / "part.stl").stat().st_mtime_ns == before
    rc, out, err = run_main(capsys, "export-mesh", SCENARIOS / "s_surface.toml", d / "part.stl", "--force", "--json")
    assert rc == 0 and err == ""
    res = json.loads(out)
    assert res["triangles"] == len(mesh.faces) and res["path"] == str(d / "part.stl")
    assert np.allclose(res["bounds_m"], mesh.bounds)
    assert res["features"] == {name: len(f) for name, f in mesh.metadata["features"].items()}
    assert sum(res["features"].values()) == len(mesh.faces) and "s_surface" in res["features"]
    assert leftovers(d) == []


@pytest.mark.parametrize("name", ["part.step", "part", "part.stl.tmp"])
def test_export_mesh_refuses_a_suffix_no_format_has(tmp_path, capsys, name):
    rc, out, err = run_main(capsys, "export-mesh", SCENARIOS / "s_surface.toml", tmp_path / name)
    assert one_line_refusal(rc, err) and ".stl" in err and out == ""
    assert list(tmp_path.iterdir()) == []


def test_export_mesh_obj_and_ply_by_suffix(tmp_path, capsys, exported):
    from twin.parts import load_mesh

    _, _, mesh = exported
    for name, tol in (("part.obj", 1e-15), ("part.ply", np.finfo(np.float32).eps * np.abs(mesh.vertices).max())):
        rc, _, err = run_main(capsys, "export-mesh", SCENARIOS / "s_surface.toml", tmp_path / name)
        assert rc == 0, err
        back = load_mesh(tmp_path / name, "m")
        assert np.abs(back.triangles - mesh.triangles).max() <= tol


def test_localize_takes_the_exported_mesh(exported, tmp_path):
    """Points of the part at a known pose: ``twin localize --model OUT.stl`` finds that pose."""
    from scipy.spatial.transform import Rotation

    from algorithms.geometry.se3 import make_pose
    from twin.io import write_points_ply

    d, _, mesh = exported
    rng = np.random.default_rng(3)
    pts, _ = sample_surface(mesh, 800, rng)
    T = make_pose(Rotation.from_euler("z", 3.0, degrees=True).as_matrix(), np.array([0.45, 0.12, 0.0]))
    write_points_ply(tmp_path / "points.ply", pts @ T[:3, :3].T + T[:3, 3])
    (tmp_path / "init.json").write_text(json.dumps(T.tolist()))
    r = run_cli("localize", "--model", str(d / "part.stl"), "--points", str(tmp_path / "points.ply"),
                "--init", str(tmp_path / "init.json"), "--json")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["status"] == "ok"
    assert_pose_close(np.asarray(res["T_world_workpiece"]), T, RECOVER_M, RECOVER_RAD)


@pytest.mark.slow
def test_a_terminated_web_viewer_stops_serving(tmp_path):
    """SIGTERM of ``twin view --web`` ends the real viewer too (the ``rerun`` script's child
    used to keep serving, so the next call found the port busy)."""
    import re
    import signal
    import socket
    import sys

    rrd = tmp_path / "scan.rrd"
    assert run_cli("scan", short_scenario(tmp_path), "--out", tmp_path / "scan", "--rrd", rrd).returncode == 0
    proc = subprocess.Popen([sys.executable, "-m", "twin", "view", "--web", "--port", "0", str(rrd)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    port = int(re.search(r"127\.0\.0\.1:(\d+)/", proc.stdout.readline()).group(1))

    def serving() -> bool:
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", port)) == 0

    for _ in range(100):
        if serving():
            break
        time.sleep(0.1)
    assert serving()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 143 and len(err.strip().splitlines()) == 1, err
    time.sleep(0.5)
    assert not serving()
