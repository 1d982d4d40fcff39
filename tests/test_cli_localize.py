"""``twin localize``: one JSON object out, chained runs, units, clear errors."""

import json

import numpy as np
import pytest

from algorithms.geometry.se3 import rotation_error_rad, transform_points, translation_error_m
from tests.test_localization import part, random_pose, sample_surface
from twin import cli
from twin.io import write_points_ply

RECOVER_M = 1e-6
RECOVER_RAD = 1e-6
KEYS = {"T_world_workpiece", "rmse_m", "iterations", "converged", "method", "time_s",
        "covariance", "observable", "status"}


@pytest.fixture(autouse=True)
def _dispatcher_knows_localize(monkeypatch):
    # the dispatcher lists its subcommands; make sure this one is among them
    if "localize" not in cli.COMMANDS:
        monkeypatch.setattr(cli, "COMMANDS", [*cli.COMMANDS, "localize"])


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("loc")
    mesh, _ = part("hemisphere_punch")
    rng = np.random.default_rng(21)
    X, _ = sample_surface(mesh, 300, rng)
    T = random_pose(rng, X.mean(axis=0), 0.12, max_deg=25)
    Y = transform_points(T, X)
    mesh.export(d / "part.stl")
    write_points_ply(d / "points.ply", Y)
    mm = mesh.copy()
    mm.apply_scale(1000.0)
    mm.export(d / "part_mm.stl")
    write_points_ply(d / "points_mm.ply", Y * 1000.0)
    return d, T


def run_cli(capsys, *argv):
    rc = cli.main(["localize", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


def test_json_output_recovers_the_pose(scene, capsys):
    d, T = scene
    rc, out, err = run_cli(capsys, "--model", d / "part.stl", "--points", d / "points.ply", "--json")
    assert rc == 0, err
    lines = out.strip().splitlines()
    assert len(lines) == 1
    res = json.loads(lines[0])
    assert KEYS <= set(res)
    Te = np.array(res["T_world_workpiece"])
    assert Te.shape == (4, 4)
    assert rotation_error_rad(Te, T) < RECOVER_RAD and translation_error_m(Te, T) < RECOVER_M
    assert res["converged"] and res["observable"] and res["method"] == "hong_tan"
    assert np.array(res["covariance"]).shape == (6, 6)
    (d / "out.json").write_text(out)


def test_output_seeds_the_next_run_and_bare_lists_work(scene, capsys):
    d, T = scene
    rc, out, _ = run_cli(capsys, "--model", d / "part.stl", "--points", d / "points.ply", "--json")
    (d / "prev.json").write_text(out)
    rc, out2, err = run_cli(capsys, "--model", d / "part.stl", "--points", d / "points.ply",
                            "--init", d / "prev.json", "--method", "tangent", "--sigma", "1e-6", "--json")
    assert rc == 0, err
    res = json.loads(out2)
    assert res["method"] == "tangent" and res["iterations"] <= 2
    assert translation_error_m(np.array(res["T_world_workpiece"]), T) < RECOVER_M
    (d / "bare.json").write_text(json.dumps(np.asarray(T).tolist()))
    rc, out3, err = run_cli(capsys, "--model", d / "part.stl", "--points", d / "points.ply",
                            "--init", d / "bare.json", "--json")
    assert rc == 0, err
    assert json.loads(out3)["rmse_m"] < 1e-9


def test_millimetre_files(scene, capsys):
    d, T = scene
    rc, out, err = run_cli(capsys, "--model", d / "part_mm.stl", "--points", d / "points_mm.ply",
                           "--units", "mm", "--json")
    assert rc == 0, err
    Te = np.array(json.loads(out)["T_world_workpiece"])   # always metres
    assert translation_error_m(Te, T) < RECOVER_M


def test_human_readable_output(scene, capsys):
    d, _ = scene
    rc, out, _ = run_cli(capsys, "--model", d / "part.stl", "--points", d / "points.ply")
    assert rc == 0 and "T_world_workpiece" in out and "converged" in out


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--model", "{d}/missing.stl", "--points", "{d}/points.ply"], "not found"),
        (["--model", "{d}/part.stl", "--points", "{d}/missing.ply"], "not found"),
        (["--model", "{d}/part.stl", "--points", "{d}/points_mm.ply"], "units look wrong"),
        (["--model", "{d}/part.stl", "--points", "{d}/points.ply", "--init", "{d}/nope.json"], "not found"),
        (["--model", "{d}/part.stl", "--points", "{d}/points.ply", "--init", "{d}/garbage.json"], "not valid JSON"),
        (["--model", "{d}/part.stl", "--points", "{d}/points.ply", "--init", "{d}/scaled.json"], "orthonormal"),
        (["--model", "{d}/part.stl", "--points", "{d}/points.ply", "--sigma", "-1"], "sigma"),
    ],
)
def test_errors_are_one_line_and_exit_2(scene, capsys, argv, message):
    d, _ = scene
    (d / "garbage.json").write_text("{not json")
    scaled = np.eye(4)
    scaled[:3, :3] *= 1.1
    (d / "scaled.json").write_text(json.dumps(scaled.tolist()))
    rc, out, err = run_cli(capsys, *[a.format(d=d) for a in argv])
    assert rc == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and message in err
