"""The command line: help everywhere, files written, bad input is one line and a non-zero exit."""

import json
import subprocess
import sys

import pytest

from tests.helpers import SCENARIOS
from twin.cli import COMMANDS, main


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "twin.cli", *args], capture_output=True, text=True)


@pytest.mark.parametrize("command", COMMANDS)
def test_help_on_every_subcommand(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    assert "usage: twin " + command in capsys.readouterr().out


def write_scenario(tmp_path, text, name="bad.toml"):
    p = tmp_path / name
    base = (SCENARIOS / "s_surface.toml").read_text()
    p.write_text(text(base) if callable(text) else text)
    return p


def short(base):
    return base.replace('line_axis = "x"', 'line_axis = "x"\nmax_lines = 1')


@pytest.mark.parametrize("edit, message", [
    (lambda b: b.replace("speed_m_s", "sped_m_s"), "unknown key(s) scan.sped_m_s"),
    (lambda b: b.replace('shape = "s_surface"', 'mesh = "missing.stl"\nunits = "mm"'), "missing.stl"),
    (lambda b: b.replace('beam = "normal"', 'beam = "normal"\nstandoff_m = 0.040'), "outside the sensor window"),
    (lambda b: b.replace("rpy_deg = [0.0, 0.0, 3.0] }", "rpy_deg = [0.0, 0.0, 3.0, 1.0] }"), "list of 3 numbers"),
    (lambda b: b.replace("xyz = [0.452, 0.118, 0.0], rpy_deg = [0.0, 0.0, 3.0]",
                         "matrix = [[1, 0.2, 0, 0.45], [0, 1, 0, 0.1], [0, 0, 1, 0], [0, 0, 0, 1]]"),
     "not orthonormal"),
    (lambda b: b.replace("xyz = [0.450, 0.120, 0.0]", "xyz = [1.3, 0.120, 0.0]"), "is unreachable"),
])
def test_bad_scenarios_fail_cleanly(tmp_path, edit, message):
    scen = write_scenario(tmp_path, lambda b: edit(short(b)))
    out = tmp_path / "out"
    r = run_cli("scan", str(scen), "--out", str(out))
    assert r.returncode == 2
    assert message in r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_mesh_with_no_faces_is_refused(tmp_path):
    (tmp_path / "empty.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 0\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n")
    scen = write_scenario(tmp_path, lambda b: short(b).replace(
        'shape = "s_surface"', 'mesh = "empty.ply"\nunits = "m"'))
    r = run_cli("scan", str(scen), "--out", str(tmp_path / "out"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "face" in r.stderr.lower()


def test_user_mesh_scan_and_recording(tmp_path):
    from twin.parts import make_workpiece

    mesh = make_workpiece("through_hole")
    mesh.apply_scale(1000.0)
    mesh.export(tmp_path / "block_mm.stl")
    scen = write_scenario(tmp_path, lambda b: short(b).replace(
        'shape = "s_surface"', 'mesh = "block_mm.stl"\nunits = "mm"'), name="user.toml")
    out, rrd = tmp_path / "out", tmp_path / "scan.rrd"
    r = run_cli("scan", str(scen), "--out", str(out), "--rrd", str(rrd))
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["valid"] > 1000
    meta = json.loads((out / "scan.json").read_text())
    assert meta["sample_period_s"] == 0.001 and meta["sensor"]["window_m"] == [0.055, 0.105]

    from rerun.chunk import RrdReader

    paths = {c.entity_path for c in RrdReader(str(rrd)).stream().to_chunks()}
    for expected in ("/world/robot/laser_sensor", "/world/scan/beam", "/plots/d_mm", "/world/workpiece/true/mesh"):
        assert expected in paths
    assert any(p.startswith("/world/scan/points/") for p in paths)
