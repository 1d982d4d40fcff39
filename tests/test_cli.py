"""The command line: help everywhere, files written, bad input is one line and a non-zero exit."""

import json
import subprocess
import sys

import pytest

from tests.helpers import SCENARIOS, run_cli
from tests.tolerances import RECORDING_FLOAT32_M
from twin.cli import COMMANDS, main


@pytest.mark.parametrize("command", COMMANDS)
def test_help_on_every_subcommand(command, capsys):
    assert main([command, "--help"]) == 0
    assert "usage: twin " + command in capsys.readouterr().out


def test_help_lists_every_command_without_loading_the_numerics():
    # `twin --help` (and a typo'd command) must answer at once: the command table comes from
    # twin.cli, and no command module, NumPy, SciPy, MuJoCo, trimesh or numba is imported
    code = ("import sys, contextlib, io; from twin.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()) as out: rc = main(['--help'])\n"
            "heavy = [m for m in ('numpy', 'scipy', 'mujoco', 'trimesh', 'numba', 'twin.cli.run')\n"
            "         if m in sys.modules]\n"
            "print(rc, heavy, out.getvalue())")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.stdout.startswith("0 []"), r.stdout + r.stderr
    for name, help_text in COMMANDS.items():
        assert name in r.stdout and help_text[:40] in " ".join(r.stdout.split())


def test_localize_loads_neither_trimesh_nor_scipy_spatial(tmp_path):
    # the start-up of `twin localize` (benchmarks/results_startup.md): a local fit with a stated
    # sigma reads the mesh with numpy and needs neither trimesh nor scipy.spatial
    from benchmarks.bench_startup import _problem

    argv = _problem(tmp_path)
    code = ("import sys, contextlib, io; from twin.cli import main\n"
            f"with contextlib.redirect_stdout(io.StringIO()) as out: rc = main({argv!r})\n"
            "print(rc, [m for m in ('trimesh', 'scipy.spatial') if m in sys.modules])")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.stdout.startswith("0 []"), r.stdout + r.stderr


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
    r = run_cli("scan", str(scen), "--out", str(out), "--rrd", str(rrd), "--json")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["valid"] > 1000
    meta = json.loads((out / "scan.json").read_text())
    assert meta["sample_period_s"] == 0.001 and meta["sensor"]["window_m"] == [0.055, 0.105]

    from rerun.chunk import RrdReader

    paths = {c.entity_path for c in RrdReader(str(rrd)).stream().to_chunks()}
    for expected in ("/world/robot/wrist_3_link/laser_sensor", "/world/scan/beam", "/plots/scan/d_mm",
                     "/world/workpiece/true/mesh"):
        assert expected in paths
    assert "/world/scan/points" in paths and not any(p.startswith("/world/scan/points/") for p in paths)


def test_scan_recording_shows_the_true_cell_that_scanned(tmp_path):
    """With kinematic errors on, ``twin scan --rrd`` records the arm of the cell that scanned:
    the recorded wrist pose equals the true cell's forward kinematics at the encoder readings
    (and not the nominal cell's)."""
    import mujoco
    import numpy as np
    import pyarrow.parquet as pq
    from rerun.chunk import RrdReader

    from twin.cell import build_cell
    from twin.realize import realize
    from twin.scenario import load_scenario

    text = (SCENARIOS / "s_surface.toml").read_text().replace('line_axis = "x"', 'line_axis = "x"\nmax_lines = 1')
    text = text.replace("[noise]", "[noise]\nkinematic_sigma_m = 0.0005\nkinematic_sigma_rad = 0.001")
    sc_file = tmp_path / "kin.toml"
    sc_file.write_text(text)
    assert main(["scan", str(sc_file), "--out", str(tmp_path / "scan"), "--rrd", str(tmp_path / "scan.rrd")]) == 0
    chunk = next(c for c in RrdReader(str(tmp_path / "scan.rrd")).stream().to_chunks()
                 if c.entity_path == "/world/robot/wrist_3_link")
    recorded = np.asarray(chunk.to_record_batch().column("Transform3D:translation")[0].as_py()[0])
    q0 = pq.read_table(tmp_path / "scan" / "samples.parquet").slice(0, 1).to_pylist()[0]
    q0 = np.array([q0[f"q{j}"] for j in range(1, 7)])  # encoder readings (no encoder noise here)
    realized = realize(load_scenario(sc_file))

    def wrist(which):
        cell = build_cell(realized, which)
        cell.set_q(q0)
        return cell.data.xpos[mujoco.mj_name2id(cell.model, mujoco.mjtObj.mjOBJ_BODY, "wrist_3_link")].copy()

    assert np.linalg.norm(recorded - wrist("true")) < RECORDING_FLOAT32_M
    assert np.linalg.norm(recorded - wrist("nominal")) > 100 * RECORDING_FLOAT32_M


def _closed_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("command", ["run", "demo"])
@pytest.mark.parametrize("live, message", [
    (["--connect", "http://127.0.0.1:9876"], "is not a Rerun viewer address"),
    (["--connect", "rerun+http://127.0.0.1:0/proxy"], "is not a Rerun viewer address"),
    (["--connect", "rerun+http://127.0.0.1:{port}/proxy"], "no Rerun viewer listens there"),
    (["--spawn", "--connect", "rerun+http://127.0.0.1:9876/proxy"], "not allowed with argument"),
    (["--spawn"], "--spawn needs a display"),
])
def test_a_live_viewer_that_cannot_be_reached_is_refused_before_any_work(tmp_path, monkeypatch, command, live,
                                                                         message):
    scen = SCENARIOS / "s_surface.toml"
    out = tmp_path / "out"
    args = [command, str(scen)] if command == "run" else [command, "--scenario", str(scen)]
    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    r = run_cli(*args, "--out", out, *[a.format(port=_closed_port()) for a in live])
    assert r.returncode == 2
    assert message in r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not out.exists()
