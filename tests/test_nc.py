"""NC programs (document 003's last step): G-code written and read back, refusals, a CAM program
relocated to a known pose, the drop-cutter raster against the surface, and ``twin localize --nc``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import exp_se3, transform_points
from algorithms.nc import (
    GCodeError,
    drop_cutter_raster,
    program_text,
    read_gcode,
    relocate_program,
    relocate_tool_tips,
    write_gcode,
)
from tests.helpers import run_cli
from tests.test_cli_localize import scene  # noqa: F401  (the fixture)
from twin.cli.localize import EXIT_UNTRUSTED

R_SPHERE_M, R_TOOL_M = 0.02, 0.003


@pytest.fixture(scope="module")
def sphere_program():
    """A drop-cutter raster over the top of a fine icosphere: (mesh, passes [m])."""
    mesh = trimesh.creation.icosphere(5, radius=R_SPHERE_M)
    passes = drop_cutter_raster(mesh.vertices, mesh.faces, tool_radius_m=R_TOOL_M, stepover_m=0.002, step_m=0.001,
                                xy_min_m=(-0.01, -0.01), xy_max_m=(0.01, 0.01), sample_m=2e-4)
    return mesh, passes


def test_written_program_reads_back_to_its_cutter_locations(sphere_program):
    _, passes = sphere_program
    tips_mm = [p * 1e3 for p in passes]
    text = write_gcode(tips_mm, safe_z_mm=60.0, decimals=3)
    moves = read_gcode(text)
    cut = np.array([m.xyz_mm for m in moves if not m.rapid])
    assert cut.shape == (sum(len(p) for p in passes), 3)
    assert np.max(np.abs(cut - np.concatenate(tips_mm))) <= 0.5e-3 + 1e-9  # 1 um grid: half a unit at most
    assert all(m.xyz_mm[2] == 60.0 for m in moves if m.rapid and m.complete)
    assert program_text(moves) == text  # the text is a fixed point


def test_inch_incremental_and_modal_words_are_read():
    moves = read_gcode("%\nO1000\nT1 M6\nG43 H1\nN10 G20 G91 G0 X1 Y1 Z1 (start)\nN20 G1 X1 F10 ; feed in inch/min\n"
                       "Y-1\nM30\n%\n")
    assert [m.xyz_mm for m in moves] == [(25.4, 25.4, 25.4), (50.8, 25.4, 25.4), (50.8, 0.0, 25.4)]
    assert moves[1].feed_mm_min == pytest.approx(254.0) and not moves[2].rapid


@pytest.mark.parametrize("text, message", [
    ("G21 G90\nG0 X0 Y0 Z5\nG2 X1 Y1 I1 J0 F100\n", "line 3: G2 is refused"),
    ("G0 X0 Y0 Z5 A30\n", "word A is refused"),
    ("G0 X0 Y0 Z5\nG1 X1\n", "line 2: a G1 move with no feed"),
    ("G0 X0 Y0 Z5 #1=2\n", "is not a G-code word"),
    ("G18\nG0 X1\n", "G18 is refused"),
    ("G54 G0 X1 Y1 Z1\n", "G54 is refused"),
])
def test_programs_it_cannot_execute_are_refused(text, message):
    with pytest.raises(GCodeError, match=message.replace("(", r"\(")):
        read_gcode(text)


def test_relocated_ball_keeps_its_contact_with_the_moved_part(sphere_program):
    """Moving the part by T and the program with it: every ball centre stays R + r from the
    sphere's moved centre, and the identity changes nothing."""
    _, passes = sphere_program
    tips_mm = np.concatenate(passes) * 1e3
    assert np.allclose(relocate_tool_tips(tips_mm, R_TOOL_M * 1e3, np.eye(4)), tips_mm)
    T = exp_se3([0.05, -0.03, 0.4, 0.2, -0.1, 0.05])
    moved = relocate_tool_tips(tips_mm, R_TOOL_M * 1e3, T)
    before = np.linalg.norm(tips_mm + [0, 0, R_TOOL_M * 1e3], axis=1)
    after = np.linalg.norm(moved + [0, 0, R_TOOL_M * 1e3] - T[:3, 3] * 1e3, axis=1)
    assert np.allclose(after, before, atol=1e-9)
    with pytest.raises(ValueError, match="tool_radius_mm"):
        relocate_tool_tips(tips_mm, 0.0, T)


def test_relocated_program_keeps_its_opening_retract_and_moves_the_rest(sphere_program):
    _, passes = sphere_program
    moves = read_gcode(write_gcode([p * 1e3 for p in passes], safe_z_mm=60.0))
    T = exp_se3([0.0, 0.0, 0.1, 0.005, -0.002, 0.0])
    moved = relocate_program(moves, R_TOOL_M * 1e3, T)
    assert moved[0] == moves[0] and moved[0].axes == "Z"  # G0 Z60 before X and Y are known
    done = [m for m in moves if m.complete]
    expect = relocate_tool_tips([m.xyz_mm for m in done], R_TOOL_M * 1e3, T)
    assert np.allclose([m.xyz_mm for m in moved if m.complete], expect)
    again = read_gcode(program_text(moved))
    assert np.max(np.abs(np.array([m.xyz_mm for m in again if m.complete]) - expect)) <= 0.5e-3 + 1e-9


def test_drop_cutter_touches_the_surface_without_gouging(sphere_program):
    """Each ball centre is the tool radius from the mesh, to the edge sampling bound sample^2 / (8 r)."""
    mesh, passes = sphere_program
    centres = np.concatenate(passes) + [0.0, 0.0, R_TOOL_M]
    d = MeshIndex(mesh).query(centres).distance
    bound = (2e-4) ** 2 / (8 * R_TOOL_M)
    assert d.min() >= R_TOOL_M - bound - 1e-9
    assert d.max() <= R_TOOL_M + 1e-9


def test_drop_cutter_on_a_plane_is_exact():
    box = trimesh.creation.box([0.1, 0.1, 0.02])  # top face z = 0.01
    passes = drop_cutter_raster(box.vertices, box.faces, tool_radius_m=0.005, stepover_m=0.01, step_m=0.01,
                                xy_min_m=(-0.03, -0.03), xy_max_m=(0.03, 0.03))
    assert np.allclose(np.concatenate(passes)[:, 2], 0.01)
    with pytest.raises(ValueError, match="must be > 0"):
        drop_cutter_raster(box.vertices, box.faces, tool_radius_m=0.0, stepover_m=0.01, step_m=0.01,
                           xy_min_m=(0, 0), xy_max_m=(1, 1))


def test_localize_writes_the_relocated_program_only_from_a_trusted_pose(scene, tmp_path):  # noqa: F811
    d, T = scene
    tips_cad_mm = np.array([[0.0, 0.0, 40.0], [10.0, 0.0, 41.0], [20.0, 5.0, 42.0]])
    (tmp_path / "cam.nc").write_text(write_gcode([tips_cad_mm], safe_z_mm=80.0), encoding="utf-8")
    out_nc = tmp_path / "located.nc"
    r = run_cli("localize", "--model", d / "part.stl", "--points", d / "points.ply", "--json", "--nc",
                tmp_path / "cam.nc", "--nc-out", out_nc, "--tool-radius", "0.003")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["nc_program"]["written"] and out_nc.is_file()
    T_found = np.array(res["T_world_workpiece"])
    cut = np.array([m.xyz_mm for m in read_gcode(out_nc.read_text()) if not m.rapid])
    expect = relocate_tool_tips(tips_cad_mm, 3.0, T_found)
    assert np.max(np.abs(cut - expect)) <= 0.5e-3 + 1e-9
    # against the truth: the ball centres where the true part puts them, to the pose's accuracy (um)
    true_centres = transform_points(T, (tips_cad_mm + [0, 0, 3.0]) * 1e-3)
    assert np.max(np.linalg.norm((cut + [0, 0, 3.0]) * 1e-3 - true_centres, axis=1)) < 5e-5
    # another part's model: the pose is not trusted, nothing is written, the exit status says so
    out_bad = tmp_path / "bad.nc"
    r = run_cli("localize", "--model", d / "other_part.stl", "--points", d / "points.ply", "--init", "global",
                "--nc", tmp_path / "cam.nc", "--nc-out", out_bad, "--tool-radius", "0.003")
    assert r.returncode == EXIT_UNTRUSTED and not out_bad.exists()
    assert "NC program NOT written" in r.stdout


@pytest.mark.parametrize("extra, message", [
    (["--nc", "{t}/cam.nc"], "go together"),
    (["--nc", "{t}/missing.nc", "--nc-out", "{t}/o.nc", "--tool-radius", "0.003"], "cannot read it"),
    (["--nc", "{t}/arc.nc", "--nc-out", "{t}/o.nc", "--tool-radius", "0.003"], "G3 is refused"),
    (["--nc", "{t}/cam.nc", "--nc-out", "{t}/no/such/o.nc", "--tool-radius", "0.003"], "does not exist"),
])
def test_nc_input_errors_are_one_line_and_exit_2(scene, tmp_path, extra, message):  # noqa: F811
    d, _ = scene
    (tmp_path / "cam.nc").write_text("G0 X0 Y0 Z50\n")
    (tmp_path / "arc.nc").write_text("G0 X0 Y0 Z50\nG3 X1 Y1 R1 F100\n")
    r = run_cli("localize", "--model", d / "part.stl", "--points", d / "points.ply",
                *[a.format(t=tmp_path) for a in extra])
    assert r.returncode == 2 and r.stdout == ""
    assert len(r.stderr.strip().splitlines()) == 1 and message in r.stderr
    assert not (tmp_path / "o.nc").exists()
