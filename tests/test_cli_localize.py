"""``twin localize``: one JSON object out, chained runs, units, the global search's verdicts,
clear errors."""

import json

import numpy as np
import pytest

from algorithms.geometry.se3 import rotation_error_rad, transform_points, translation_error_m
from tests.helpers import assert_pose_close, random_pose, run_cli, sample_surface
from tests.test_localization import part
from tests.tolerances import EXACT_FIT_M, RECOVER_M, RECOVER_RAD, SCAN_FIXED_M, SCAN_FIXED_RAD
from twin.cli.localize import EXIT_UNTRUSTED
from twin.io import write_points_ply

KEYS = {"T_world_workpiece", "rmse_m", "iterations", "converged", "method", "time_s", "status", "message",
        "covariance", "determined_directions", "observable", "free_dofs", "free_directions", "solutions"}
#: Noise of the cube's points [m] (the sensor's repeatability) and the sigma stated for them.
CUBE_NOISE_M = 2e-6


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
    part("s_surface")[0].export(d / "other_part.stl")
    return d, T


def localize_cli(*argv):
    r = run_cli("localize", *argv)
    return r.returncode, r.stdout, r.stderr


def test_json_output_recovers_the_pose(scene):
    d, T = scene
    rc, out, err = localize_cli("--model", d / "part.stl", "--points", d / "points.ply", "--json")
    assert rc == 0, err
    lines = out.strip().splitlines()
    assert len(lines) == 1
    res = json.loads(lines[0])
    assert KEYS <= set(res)
    Te = np.array(res["T_world_workpiece"])
    assert Te.shape == (4, 4)
    assert_pose_close(Te, T, RECOVER_M, RECOVER_RAD)
    # without --init the search covers every orientation (Algorithm 5), then hong_tan polishes
    assert res["converged"] and res["observable"] and res["method"] == "multistart"
    assert res["global"]["polish"] == "hong_tan"
    assert res["status"] == "ok" and res["trusted"] and res["free_dofs"] == 0 and res["free_directions"] == []
    assert np.array(res["covariance"]).shape == (6, 6) and np.array(res["determined_directions"]).shape == (6, 6)
    assert len(res["solutions"]) == 1 and np.array_equal(res["solutions"][0], res["T_world_workpiece"])
    (d / "out.json").write_text(out)


def test_output_seeds_the_next_run_and_bare_lists_work(scene):
    d, T = scene
    rc, out, _ = localize_cli("--model", d / "part.stl", "--points", d / "points.ply", "--json")
    (d / "prev.json").write_text(out)
    rc, out2, err = localize_cli("--model", d / "part.stl", "--points", d / "points.ply",
                            "--init", d / "prev.json", "--method", "tangent", "--sigma", "1e-6", "--json")
    assert rc == 0, err
    res = json.loads(out2)
    assert res["method"] == "tangent" and res["iterations"] <= 2
    assert translation_error_m(np.array(res["T_world_workpiece"]), T) < RECOVER_M
    (d / "bare.json").write_text(json.dumps(np.asarray(T).tolist()))
    rc, out3, err = localize_cli("--model", d / "part.stl", "--points", d / "points.ply",
                            "--init", d / "bare.json", "--json")
    assert rc == 0, err
    assert json.loads(out3)["rmse_m"] < EXACT_FIT_M


def test_millimetre_files(scene):
    d, T = scene
    rc, out, err = localize_cli("--model", d / "part_mm.stl", "--points", d / "points_mm.ply",
                           "--units", "mm", "--json")
    assert rc == 0, err
    Te = np.array(json.loads(out)["T_world_workpiece"])   # always metres
    assert translation_error_m(Te, T) < RECOVER_M


def test_human_readable_output(scene):
    d, _ = scene
    rc, out, _ = localize_cli("--model", d / "part.stl", "--points", d / "points.ply")
    assert rc == 0 and "T_world_workpiece" in out and "iterations" in out and "multistart: ok:" in out


# ------------------------------------------------------------------ --init global
def test_global_init_finds_the_pose_with_sigma(scene):
    d, T = scene
    rc, out, err = localize_cli("--model", d / "part.stl", "--points", d / "points.ply",
                           "--init", "global", "--sigma", "1e-6", "--json")
    assert rc == 0, err
    res = json.loads(out)
    assert res["method"] == "multistart" and res["status"] == "ok" and len(res["solutions"]) == 1
    assert res["global"]["n_starts"] >= 60 and res["candidates"][0]["rmse_m"] < EXACT_FIT_M
    # the diagnostics say how the answer was chosen, whether or not a start passed the coarse tests
    g = res["global"]
    assert f"{g['n_starts']}" in g["selection"] and "verified" in g["selection"]
    assert_pose_close(np.array(res["T_world_workpiece"]), T, RECOVER_M, RECOVER_RAD)


def test_global_init_on_points_of_another_part_fails(scene):
    # the hemisphere punch's points against the S-surface part's model: no pose explains
    # them within the stated noise, so no confident pose is printed
    d, _ = scene
    sigma = 1e-6
    rc, out, err = localize_cli("--model", d / "other_part.stl", "--points", d / "points.ply",
                           "--init", "global", "--sigma", sigma, "--json")
    assert rc == EXIT_UNTRUSTED, err
    res = json.loads(out)
    assert res["status"] == "poor_fit" and not res["trusted"]
    assert res["message"].startswith("poor fit") and res["global"]["rms_verify_m"] > 100 * sigma


@pytest.fixture(scope="module")
def cube_scene(tmp_path_factory):
    """twin.parts' cube, [-a/2, a/2]^2 x [0, a], with points on three faces that meet at a
    corner: each of the cube's 24 rotations maps them onto three such faces."""
    from twin.parts import make_workpiece

    d = tmp_path_factory.mktemp("cube")
    a = 0.04
    mesh = make_workpiece("cube", side_m=a)
    mesh.export(d / "cube.ply")
    rng = np.random.default_rng(4)
    faces = []
    for axis in range(3):
        p = rng.uniform(-0.45 * a, 0.45 * a, (100, 3))
        p[:, axis] = a / 2
        faces.append(p)
    X = np.vstack(faces) + [0.0, 0.0, a / 2]
    T = random_pose(rng, X.mean(axis=0), a, max_deg=180)
    write_points_ply(d / "three_faces.ply", transform_points(T, X) + rng.normal(0, CUBE_NOISE_M, X.shape))
    return d, T


def test_global_init_prints_every_equally_good_pose_of_a_symmetric_part(cube_scene):
    d, T = cube_scene
    argv = ["--model", d / "cube.ply", "--points", d / "three_faces.ply", "--init", "global",
            "--sigma", CUBE_NOISE_M]
    rc, out, err = localize_cli(*argv, "--json")
    assert rc == EXIT_UNTRUSTED, err
    res = json.loads(out)
    assert res["status"] == "ambiguous" and "24 distinct poses" in res["message"]
    sols = np.array(res["solutions"])
    assert sols.shape == (24, 4, 4) and np.array_equal(sols[0], res["T_world_workpiece"])
    # one of them is the truth; the others are the cube's rotations, at least 90 degrees away
    err_rad = sorted(rotation_error_rad(S, T) for S in sols)
    assert err_rad[0] < SCAN_FIXED_RAD and err_rad[1] > np.radians(89.0)
    best = min(sols, key=lambda S: rotation_error_rad(S, T))
    assert translation_error_m(best, T) < SCAN_FIXED_M
    rc, out, err = localize_cli(*argv)
    assert rc == EXIT_UNTRUSTED, err
    assert "multistart: ambiguous:" in out and "equally good pose 24 of 24 [m]:" in out


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
        (["--model", "{d}/part.stl", "--points", "{d}/points_mm.ply", "--init", "global"], "units look wrong"),
    ],
)
def test_errors_are_one_line_and_exit_2(scene, argv, message):
    d, _ = scene
    (d / "garbage.json").write_text("{not json")
    scaled = np.eye(4)
    scaled[:3, :3] *= 1.1
    (d / "scaled.json").write_text(json.dumps(scaled.tolist()))
    rc, out, err = localize_cli(*[a.format(d=d) for a in argv])
    assert rc == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and message in err


def test_a_fit_with_free_directions_says_its_covariance_leaves_out_the_facets(tmp_path):
    """A tessellated cylinder's turn about its axis is free: the uncertainty's note says the
    facets along it are not in the covariance (as text and in the JSON); a box, whose points fix
    every direction, says nothing of the kind."""
    import trimesh

    mesh = trimesh.creation.cylinder(radius=0.02, height=0.05, sections=48)
    rng = np.random.default_rng(3)
    X, _ = sample_surface(mesh, 400, rng)
    side = X[np.abs(X[:, 2]) < 0.02]
    mesh.export(tmp_path / "cyl.stl")
    write_points_ply(tmp_path / "side.ply", side)
    (tmp_path / "identity.json").write_text(json.dumps(np.eye(4).tolist()))
    rc, out, err = localize_cli("--model", tmp_path / "cyl.stl", "--points", tmp_path / "side.ply",
                                "--init", tmp_path / "identity.json", "--json")
    res = json.loads(out)
    assert res["free_dofs"] >= 1, res["message"]
    assert "facets along the free directions" in res["uncertainty"]["note"]
    rc, out, err = localize_cli("--model", tmp_path / "cyl.stl", "--points", tmp_path / "side.ply",
                                "--init", tmp_path / "identity.json")
    assert "not in the covariance:" in out and "facets along the free directions" in out
    box = trimesh.creation.box(extents=[0.04, 0.03, 0.02])
    box.export(tmp_path / "box.stl")
    write_points_ply(tmp_path / "box.ply", sample_surface(box, 400, rng)[0])
    rc, out, err = localize_cli("--model", tmp_path / "box.stl", "--points", tmp_path / "box.ply",
                                "--init", tmp_path / "identity.json", "--json")
    res = json.loads(out)
    assert res["free_dofs"] == 0 and "facets" not in res["uncertainty"]["note"]
