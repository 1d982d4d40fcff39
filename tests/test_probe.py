"""The touch-trigger probe in the cell and document 001's hierarchy (``twin locate``).

The trigger model on exact geometry (a plane, a sphere), a probing move in the true cell
against the model, a miss reported as a miss, the qualification's effective radius, bad
input refused, a coarse pose too far off failing the fine stage with its misses, and the
hierarchy end to end on every locate scenario the project ships.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from algorithms.geometry.se3 import transform_points
from algorithms.probing.pretravel import PretravelModel
from tests.helpers import run_cli, tiered
from twin import evaluate
from twin.cell import build_cell
from twin.errors import TwinError
from twin.probing import (
    IK_KNOT_STEPS,
    ProbeTarget,
    ProbingProgram,
    ball_pose,
    build_probe_cell,
    line_profile,
    safe_height_world,
)
from twin.qualification import qualification_targets, qualify
from twin.realize import realize
from twin.scenario import load_scenario
from twin.sensors.touch_probe import find_trigger
from twin.workflows.locate import locate

ROOT = Path(__file__).resolve().parents[1]
LOCATE_SCENARIOS = sorted((ROOT / "scenarios").glob("locate_*.toml"))
EXACT_M = 1e-9
R_BALL = 0.001
MODEL = PretravelModel(stylus_m=0.020, repeatability_sigma_m=0.0)
DT = 1e-3


def _straight(c0, direction, speed=0.008, n=3000):
    t = np.arange(n) * DT
    return t, c0 + np.outer(speed * t, direction)


def test_trigger_on_a_plane_lands_where_the_model_says():
    # probe axis z = world -z (stylus down); the ball moves down and sideways onto z = 0
    R_world_probe = np.diag([1.0, -1.0, -1.0])
    u = np.array([0.3, 0.1, -1.0])
    u /= np.linalg.norm(u)
    t, c = _straight(np.array([0.01, 0.02, 0.006]), u)
    trig = find_trigger(t, c, lambda p: p[:, 2] - R_BALL, lambda d: float(MODEL.pretravel_m(d @ R_world_probe)))
    s_touch = (0.006 - R_BALL) / -u[2]
    touch = np.array([0.01, 0.02, 0.006]) + s_touch * u
    delta = float(MODEL.pretravel_m(u @ R_world_probe))
    assert np.linalg.norm(trig.centre_touch - touch) < EXACT_M
    assert np.linalg.norm(trig.centre_trigger - (touch + delta * u)) < EXACT_M
    assert abs(trig.trigger_t_s - (s_touch + delta) / 0.008) < 1e-9
    assert delta == pytest.approx(2 * (MODEL.axial_m * u[2] ** 2 + (1 - u[2] ** 2)
                                       * (MODEL.lateral_m + MODEL.lobe_m * np.cos(3 * np.arctan2(-u[1], u[0])))))


def test_trigger_on_a_sphere_lands_where_the_model_says():
    centre, radius = np.array([0.0, 0.0, 0.0]), 0.0125
    u = np.array([-1.0, 0.0, -0.2])
    u /= np.linalg.norm(u)
    c0 = np.array([0.03, 0.004, 0.008])
    t, c = _straight(c0, u)

    def gap(p):
        return np.linalg.norm(p - centre, axis=1) - radius - R_BALL

    trig = find_trigger(t, c, gap, lambda d: 5e-6)
    # |c0 + s u - centre| = R + r
    b = u @ (c0 - centre)
    s = -b - np.sqrt(b**2 - (np.sum((c0 - centre) ** 2) - (radius + R_BALL) ** 2))
    touch = c0 + s * u
    assert np.linalg.norm(trig.centre_touch - touch) < EXACT_M
    assert np.linalg.norm(trig.centre_trigger - (touch + 5e-6 * u)) < EXACT_M


def test_no_touch_within_the_samples_is_no_trigger():
    t, c = _straight(np.array([0.0, 0.0, 0.02]), np.array([0.0, 0.0, -1.0]), n=1000)   # stops 12 mm above
    assert find_trigger(t, c, lambda p: p[:, 2] - R_BALL, lambda d: 5e-6) is None


@pytest.fixture(scope="module")
def cube_probe():
    """The cube scenario with the probe, every error source off."""
    sc = load_scenario(ROOT / "scenarios" / "cube.toml", {
        "probe": {"repeatability_2sigma_m": 0.0},
        "noise": {"gaussian": False, "linearity": False, "quantization": False, "incidence": False,
                  "occlusion": False}})
    realized = realize(sc)
    return realized, build_cell(realized, "nominal"), build_probe_cell(realized)


def test_a_probing_move_in_the_cell_records_the_trigger_of_the_model(cube_probe):
    realized, nominal, cell = cube_probe
    mesh = realized.workpiece.mesh
    T = realized.T_base_workpiece_true
    top = mesh.bounds[1, 2]
    centre_wp = np.array([mesh.bounds[:, 0].mean(), mesh.bounds[:, 1].mean(), top])
    p_b = transform_points(T, centre_wp[None])[0]
    n_b = T[:3, 2]
    prog = ProbingProgram(realized, nominal, cell, np.random.default_rng(0))
    hit, = prog.run([ProbeTarget(p_b, n_b, "top")], safe_height_world(realized, realized.truth.T_world_workpiece))
    assert hit.hit
    tr = hit.truth
    # the recorded centre (latched encoders, nominal kinematics) is the true trigger position
    assert np.linalg.norm(hit.centre - tr.centre_trigger) < EXACT_M
    # along the normal: the touch at r from the face, then the model's pre-travel along the motion
    u_probe = tr.direction @ hit.R_base_probe
    delta = float(prog.touch_probe.pretravel.pretravel_m(np.r_[u_probe[:2], max(u_probe[2], 0.0)]
                                                         / np.linalg.norm(np.r_[u_probe[:2], max(u_probe[2], 0.0)])))
    assert tr.pretravel_m == pytest.approx(delta, abs=1e-15)
    height = (hit.centre - p_b) @ n_b
    assert height == pytest.approx(R_BALL + delta * (tr.direction @ n_b), abs=EXACT_M)
    assert np.linalg.norm(hit.centre - p_b - height * n_b) < 1e-6     # servo lag sideways: sub-micrometre


def test_a_miss_is_reported_as_a_miss(cube_probe):
    realized, nominal, cell = cube_probe
    mesh = realized.workpiece.mesh
    T = realized.T_base_workpiece_true
    p_wp = np.array([mesh.bounds[:, 0].mean(), mesh.bounds[:, 1].mean(), mesh.bounds[1, 2] + 0.010])  # 10 mm above
    prog = ProbingProgram(realized, nominal, cell, np.random.default_rng(0))
    hit, = prog.run([ProbeTarget(transform_points(T, p_wp[None])[0], T[:3, 2], "air")],
                    safe_height_world(realized, realized.truth.T_world_workpiece))
    assert not hit.hit and "no trigger" in hit.miss and np.all(np.isnan(hit.centre))
    assert prog.log((hit,)).contacts == ()


def test_the_closed_form_knots_are_what_mink_converges_to(cube_probe):
    # ProbingProgram solves a move's IK knots in closed form on the arm's branch where mink's
    # table avoidance does not act: the joints must be mink's, to its tolerances
    realized, nominal, cell = cube_probe
    prog = ProbingProgram(realized, nominal, cell, np.random.default_rng(0))
    prog.start()
    here = prog.ball_world()
    P = line_profile(here, here + np.array([0.06, -0.04, -0.05]), 0.25, 1.0, prog.dt)[::IK_KNOT_STEPS]
    T_world_ball = np.stack([ball_pose(p, prog.spin + 0.3 * i / len(P)) for i, p in enumerate(P)])
    q_start = prog.solver.q
    closed = prog._closed_form_knots(T_world_ball)
    prog.solver.set_q(q_start)
    mink = prog._mink_knots(T_world_ball)
    assert closed is not None
    assert np.abs(closed - mink).max() < 2e-6          # rad: mink stops at 1e-7 m / 1e-6 rad


def test_the_contact_gaps_are_exact_where_they_decide(cube_probe):
    # probe_contacts computes the gaps exactly only where a contact or the smallest clearance
    # could be, bounding the others: its contacts and clearance must be those of every sample
    # computed exactly, here on a real move lowered until the stylus and the body cut the cube
    realized, nominal, cell = cube_probe
    mesh = realized.workpiece.mesh
    T = realized.T_base_workpiece_true
    p_wp = np.array([mesh.bounds[:, 0].mean(), mesh.bounds[:, 1].mean(), mesh.bounds[1, 2]])
    prog = ProbingProgram(realized, nominal, cell, np.random.default_rng(0))
    prog.run([ProbeTarget(transform_points(T, p_wp[None])[0], T[:3, 2], "top")],
             safe_height_world(realized, realized.truth.T_world_workpiece))
    t = np.concatenate(prog.logs["t"])
    phase = np.concatenate(prog.logs["phase"])
    for drop_m in (0.0, 0.012, 0.03):
        ball = np.vstack(prog.logs["ball"]) - [0.0, 0.0, drop_m]
        module = np.vstack(prog.logs["module"]) - [0.0, 0.0, drop_m]
        got = prog.probe_contacts(t, ball, module, phase)
        expected = _every_sample_exactly(prog, t, ball, module, phase)
        assert got == expected
    assert len(expected[0]) >= 2                        # the deepest drop touches with stylus and body


def _every_sample_exactly(prog, t, ball_w, module_w, phase):
    """probe_contacts with every sample's gap computed (the reference)."""
    out, clearance = [], np.inf
    for name, samples, radius, check, _ in prog.probe_samples(ball_w, module_w, phase)[1]:
        pts = np.asarray(samples)
        k = pts.shape[1]
        d = prog.obstacles.distance(pts.reshape(-1, 3), reach_m=radius + 0.01).reshape(-1, k).min(axis=1) - radius
        if name != "probe_ball":
            clearance = min(clearance, float(d.min()))
        out += prog.contact_of(name, t, d, check, ball_w)
    return out, clearance


def test_qualification_finds_the_effective_radius():
    sc = load_scenario(LOCATE_SCENARIOS[0])
    realized = realize(sc)
    prog = ProbingProgram(realized, build_cell(realized, "nominal"), build_probe_cell(realized),
                          realized.streams.generator("probe"))
    hits = prog.run(qualification_targets(realized), safe_height_world(realized, realized.truth.T_world_workpiece))
    q = qualify(hits, realized)
    assert abs(q.effective_radius_m - evaluate.true_effective_radius_m(sc.probe)) < 0.1e-6
    # the pole's axial excess goes into the offset along the stylus (probe z)
    s = sc.probe.stylus_length_m / sc.probe.reference_stylus_m
    excess = s * (sc.probe.axial_pretravel_m - sc.probe.lateral_pretravel_m)
    assert abs(abs(q.offset_probe_m[2]) - excess) < 0.5e-6


@pytest.mark.parametrize("table, needle", [
    ({"stylus_length_m": 0.0005}, "must be longer than probe.ball_radius_m"),
    ({"probing_speed_m_s": 0.0}, "probing_speed_m_s = 0.0 is outside"),
    ({"search_m": -0.001}, "search_m = -0.001 is outside"),
    ({"points": 5}, "at least 6 points"),
    ({"stylus": 0.02}, "unknown key"),
])
def test_bad_probe_tables_are_refused(table, needle):
    with pytest.raises(TwinError, match=needle):
        load_scenario(LOCATE_SCENARIOS[0], {"probe": table})


@pytest.mark.slow
def test_too_few_plannable_points_fail_the_plan_stage_and_say_why(tmp_path):
    src = LOCATE_SCENARIOS[-1].read_text().replace("[probe]", "[probe]\ncandidate_spacing_m = 0.09")
    scen = tmp_path / "sparse.toml"
    scen.write_text(src)
    r = run_cli("locate", str(scen), "--out", str(tmp_path / "out"))
    assert r.returncode == 4, r.stderr
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    assert not rep["complete"] and rep["failed_stage"] == "plan"
    assert "candidate probe points are plannable, 12 are needed (rejected:" in rep["failure"]


def test_points_below_six_is_bad_input(tmp_path):
    r = run_cli("locate", str(LOCATE_SCENARIOS[0]), "--out", str(tmp_path / "out"), "--points", "5")
    assert r.returncode == 2 and "at least 6" in r.stderr and not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_coarse_pose_far_off_fails_the_fine_stage_with_its_misses(monkeypatch):
    import twin.workflows.locate as loc

    real = loc.coarse_pose

    def lifted(points, realized, method):
        T, r = real(points, realized, method)
        T = T.copy()
        T[2, 3] -= 0.012     # 12 mm too low: every planned point lies below the search end
        return T, r

    monkeypatch.setattr(loc, "coarse_pose", lifted)
    res = locate(realize(load_scenario(LOCATE_SCENARIOS[-1])))
    assert res.failure is not None and res.failure[0] == "fine"
    assert "were hit" in res.failure[1] and res.T_final is None
    assert sum(not h.hit for h in res.hits) > len(res.hits) - 6
    assert all(h.miss and np.all(np.isnan(h.centre)) for h in res.hits if not h.hit)


@pytest.mark.parametrize("scenario", tiered(LOCATE_SCENARIOS, ("locate_bottle_punch",), ids=lambda p: p.stem))
def test_every_locate_scenario_meets_the_bar(tmp_path, scenario):
    out = tmp_path / "out"
    r = run_cli("locate", str(scenario), "--out", str(out), "--rrd", str(tmp_path / "locate.rrd"))
    assert r.returncode == 0, r.stderr
    rep = json.loads((out / "report.json").read_text())
    assert rep["complete"] and rep["trusted"]
    assert rep["coarse"]["within_1mm_1deg"]
    assert rep["coarse"]["nominal_translation_error_mm"] > 20 or rep["coarse"]["nominal_rotation_error_deg"] > 10
    assert abs(rep["qualification"]["effective_radius_error_um"]) < 0.1
    assert rep["probing"]["unintended_contacts"] == 0 and not rep["probing"]["misses"]
    assert rep["fine"]["max_error_sigmas"] <= 3.0
    assert rep["fine"]["translation_error_mm"] < 0.01
    hits = (out / "probe_hits.csv").read_text().splitlines()
    assert len(hits) == 1 + rep["probing"]["points"] and (out / "coarse_points.ply").stat().st_size > 0
    assert (tmp_path / "locate.rrd").stat().st_size > 0
    assert "pose_error.png" in rep["figures"] and (out / "pose_error.png").exists()
    assert "FAIL" not in (out / "report.html").read_text()


def test_every_coarse_method_returns_a_pose():
    """The coarse methods on points of the part at its true pose: the multistart within 1 mm and
    1 deg; the document's single genetic run returns its own pose, whatever its quality."""
    from algorithms.geometry.se3 import rotation_error_rad, translation_error_m
    from twin.workflows.locate import coarse_pose

    realized = realize(load_scenario(LOCATE_SCENARIOS[-1]))
    pts_wp, _ = realized.workpiece.mesh.sample(3000, return_index=True, seed=3)
    pts = transform_points(realized.T_base_workpiece_true, pts_wp)
    pts = pts[transform_points(realized.scenario.T_world_base, pts)[:, 2] > 0.002]    # the table hides the bottom
    T, r = coarse_pose(pts, realized, "multistart")
    assert np.degrees(rotation_error_rad(T, realized.T_base_workpiece_true)) < 1.0
    assert translation_error_m(T, realized.T_base_workpiece_true) < 1e-3
    T_ga, r_ga = coarse_pose(pts, realized, "ga")
    assert np.allclose(T_ga[:3, :3] @ T_ga[:3, :3].T, np.eye(3), atol=1e-9)
    assert np.array_equal(T_ga, r_ga.diagnostics.genetic.T_coarse)
