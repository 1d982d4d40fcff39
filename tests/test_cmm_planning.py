"""Document 002's definitions, the swept probe check and the three GOTO planners (pure algorithms)."""

from pathlib import Path

import numpy as np
import pytest
import trimesh

from algorithms.errors import AlgorithmError
from algorithms.probing.cmm_planning import (
    PLANNERS,
    StylusReach,
    find_safe_path,
    plan,
    plan_full_check,
    program_moves,
    taught_path_collisions,
)
from algorithms.probing.program import Goto, MeasurePoint, ProbeSettings, Program, SelectStylus
from algorithms.probing.safety_plane import (
    SafetyPlane,
    Teach,
    TeachMove,
    TeachTouch,
    penetrations,
    safe_position,
    taught_path,
)
from algorithms.probing.sweep import MoveCheck, ProbeGeometry, ProbeSweep
from twin.errors import TwinError
from twin.formats.teach import load_teach, parse_teach
from twin.parts import make_workpiece

ROOT = Path(__file__).resolve().parents[1]
TEACH = ROOT / "scenarios" / "cmm" / "teach"
EXACT_M = 1e-12
CLEARANCE_M = 0.001
DIRS = {"S1": [0.0, 0.0, -1.0], "S2": [-1.0, 0.0, 0.0], "S3": [1.0, 0.0, 0.0]}


def _probes() -> dict[str, ProbeGeometry]:
    """A TP20 on a PH10-class head (the shipped CMM scenarios' sizes)."""
    return {k: ProbeGeometry(np.array(d), 0.001, 0.0005, 0.02, 0.0066, 0.05, 0.025, 0.04) for k, d in DIRS.items()}


def _planning(part: str):
    mesh = make_workpiece(part)
    probes = _probes()
    styli = {k: StylusReach(p.direction, p.reach_m, p.ball_radius_m) for k, p in probes.items()}
    sweep = ProbeSweep(mesh.vertices, mesh.faces, CLEARANCE_M)

    def check(a, b, s):
        return sweep.check_move(a, b, probes[s])
    return mesh, styli, check


def _stations(teach, styli):
    return taught_path(teach, {k: (v.direction, v.reach_m) for k, v in styli.items()},
                       {k: v.ball_radius_m for k, v in styli.items()})


# ----------------------------------------------------------------------------- definitions
def test_safety_plane_through_the_highest_point_and_safe_positions():
    box = trimesh.creation.box((0.1, 0.1, 0.04))
    plane = SafetyPlane.through_highest_point(box.vertices)
    assert plane.height(np.array([0.3, -0.2, 0.02])) == pytest.approx(0.0, abs=EXACT_M)
    p = np.array([0.01, 0.02, -0.005])
    s = safe_position(p, plane, 0.03)
    np.testing.assert_allclose(s, [0.01, 0.02, 0.05], atol=EXACT_M)
    # penetration: the tip-to-projection vector makes an acute angle with the normal below the plane
    assert plane.below(np.array([0.0, 0.0, 0.019]))
    assert not plane.below(np.array([0.0, 0.0, 0.021]))
    assert not plane.below(np.array([0.0, 0.0, 0.02]))  # on the plane is not below
    tilted = SafetyPlane(np.zeros(3), np.array([0.0, 1.0, 1.0]))
    np.testing.assert_allclose(tilted.normal, [0.0, 2**-0.5, 2**-0.5], atol=EXACT_M)
    with pytest.raises(AlgorithmError, match="safe distance must be positive"):
        safe_position(p, plane, 0.0)
    with pytest.raises(AlgorithmError, match="normal"):
        SafetyPlane(np.zeros(3), np.zeros(3))


def test_effective_and_ineffective_penetrations_with_their_points():
    plane = SafetyPlane(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    touch = TeachTouch("P1", "F", (0.01, 0.0, -0.02), (0.0, 0.0, 1.0))
    steps = (TeachMove((0.0, 0.0, 0.01)), TeachMove((0.0, 0.0, -0.01)), TeachMove((0.0, 0.0, 0.01)),  # ineffective
             TeachMove((0.01, 0.0, 0.02)), touch, TeachMove((0.01, 0.0, 0.03)))                         # effective
    teach = Teach("t", "S1", steps, 0.03, ProbeSettings(approach_m=0.002))
    st = taught_path(teach, {"S1": (np.array([0, 0, -1.0]), 0.07)}, {"S1": 0.001})
    np.testing.assert_allclose(st[4].position_m, [0.01, 0.0, -0.017], atol=EXACT_M)  # approach centre
    pens = penetrations(st, plane)
    assert [p.effective for p in pens] == [False, True]
    np.testing.assert_allclose(pens[0].entry_m, [0.0, 0.0, 0.0], atol=EXACT_M)
    # the second: from (0.01, 0, 0.02) down to the approach centre at z = -0.017
    np.testing.assert_allclose(pens[1].entry_m, [0.01, 0.0, 0.0], atol=EXACT_M)
    np.testing.assert_allclose(pens[1].exit_m, [0.01, 0.0, 0.0], atol=EXACT_M)
    assert pens[1].touches == (4,)


def test_a_teach_starting_below_the_plane_is_refused():
    plane = SafetyPlane(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    teach = Teach("t", "S1", (TeachMove((0.0, 0.0, -0.01)), TeachTouch("P", "F", (0, 0, -0.02), (0, 0, 1))), 0.03)
    st = taught_path(teach, {"S1": (np.array([0, 0, -1.0]), 0.07)}, {"S1": 0.001})
    with pytest.raises(AlgorithmError, match="starts below the safety plane"):
        penetrations(st, plane)


# ----------------------------------------------------------------------------- swept check
def test_sweep_finds_the_first_contact_and_never_tunnels():
    plate = trimesh.creation.box((0.1, 0.1, 0.002))  # 2 mm thick: a long move could step over it
    probe = _probes()["S1"]
    sweep = ProbeSweep(plate.vertices, plate.faces, CLEARANCE_M)
    res = sweep.check_move([0.0, 0.0, 0.5], [0.0, 0.0, -0.05], probe)
    assert not res.clear and res.part == "ball"
    # first closer than the clearance where the ball is the clearance + r above the plate
    z_first = 0.5 - res.fraction * 0.55
    assert z_first == pytest.approx(0.001 + 0.001 + CLEARANCE_M, abs=2e-5)
    assert sweep.check_move([0.0, 0.0, 0.2], [0.3, 0.0, 0.2], probe).clear
    # grazing: the ball passes 0.5 mm from the plate's edge, inside the clearance
    res = sweep.check_move([0.0515, -0.2, 0.0], [0.0515, 0.2, 0.0], probe)
    assert not res.clear
    assert sweep.check_move([0.0525, -0.2, 0.0], [0.0525, 0.2, 0.0], probe).clear


def test_sweep_sees_a_probe_inside_the_material():
    block = trimesh.creation.box((0.4, 0.4, 0.4))
    sweep = ProbeSweep(block.vertices, block.faces, CLEARANCE_M)
    res = sweep.check_position([0.0, 0.0, 0.0], _probes()["S1"])
    assert not res.clear and res.part == "ball"


def test_find_safe_path_bisects_to_a_clear_point_below_the_safe_position():
    calls = []

    def check(a, b, s):  # clear from below 30 mm only
        calls.append(a[2])
        return MoveCheck(bool(a[2] < 0.030))
    m = find_safe_path(np.array([0.05, 0.0, 0.0]), np.array([0.0, 0.0, 0.04]), np.array([0.0, 0.0, 0.07]),
                       np.array([0.0, 0.0, 1.0]), "S1", check)
    assert m is not None and 0.030 - 2e-4 <= m[2] < 0.030
    np.testing.assert_allclose(m[:2], [0.0, 0.0], atol=EXACT_M)
    assert find_safe_path(np.array([0.05, 0.0, 0.0]), np.zeros(3), np.array([0.0, 0.0, 0.07]),
                          np.array([0.0, 0.0, 1.0]), "S1", lambda a, b, s: MoveCheck(False)) is None


# ----------------------------------------------------------------------------- planners
def test_program_moves_measure_from_the_approach_centre():
    prog = Program("p", ProbeSettings(approach_m=0.002, retract_m=0.003), (
        SelectStylus("S1"), Goto((0.0, 0.0, 0.1)), MeasurePoint("P1", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))))
    styli = {"S1": StylusReach(np.array([0.0, 0.0, -1.0]), 0.07, 0.001)}
    moves = program_moves(prog, styli)
    assert [m.kind for m in moves] == ["approach", "probe", "retract"]
    np.testing.assert_allclose(moves[0].end_m, [0, 0, 0.003], atol=EXACT_M)
    np.testing.assert_allclose(moves[1].end_m, [0, 0, 0.001], atol=EXACT_M)
    np.testing.assert_allclose(moves[2].end_m, [0, 0, 0.004], atol=EXACT_M)
    with pytest.raises(AlgorithmError, match="before the first GOTO"):
        program_moves(Program("q", ProbeSettings(), (SelectStylus("S1"), prog.statements[2])), styli)


@pytest.mark.parametrize("part, teach", [("inner_sphere", "inner_sphere"), ("through_hole", "through_hole")])
def test_the_documents_experiments_baseline_collides_document_planner_does_not(part, teach):
    mesh, styli, check = _planning(part)
    t = load_teach(TEACH / f"{teach}.toml")
    st = _stations(t, styli)
    assert taught_path_collisions(st, check) == []
    plans = {m: plan(m, t, st, mesh.vertices, styli, check) for m in PLANNERS}
    assert len(plans["baseline"].collisions) >= 1
    assert plans["document"].collisions == () and plans["document"].unresolved == ()
    assert plans["full_check"].collisions == () and plans["full_check"].unresolved == ()
    for p in plans.values():  # every planner measures the operator's points in the operator's order
        assert [m.label for m in p.program.measurements] == [x.label for x in t.touches]


def test_through_hole_uses_find_safe_path():
    mesh, styli, check = _planning("through_hole")
    t = load_teach(TEACH / "through_hole.toml")
    p = plan("document", t, _stations(t, styli), mesh.vertices, styli, check)
    assert sum("find-safe-path" in r for r in p.reasons) >= 2


def test_below_the_plane_document_planner_collides_and_full_check_does_not():
    mesh, styli, check = _planning("inner_sphere")
    t = load_teach(TEACH / "inner_sphere_below_plane.toml")
    st = _stations(t, styli)
    doc = plan("document", t, st, mesh.vertices, styli, check)
    full = plan("full_check", t, st, mesh.vertices, styli, check)
    assert len(doc.collisions) >= 1  # the detour around the post is lost (the document's stated limit)
    assert full.collisions == () and full.unresolved == ()
    assert any("via point on the taught path" in r for r in full.reasons)


def test_full_check_reports_a_move_it_cannot_clear():
    mesh, styli, check = _planning("inner_sphere")
    t = load_teach(TEACH / "inner_sphere_below_plane.toml")
    st = _stations(t, styli)

    def blocked(a, b, s):  # nothing may reach the second point
        target = st[7].position_m
        if np.allclose(b, target, atol=1e-9) and not np.allclose(a, b):
            return MoveCheck(False, 0.5, 0.5 * (a + b), "body", 0.0)
        return check(a, b, s)
    full = plan_full_check(t, st, mesh.vertices, styli, blocked)
    assert len(full.unresolved) == 1 and "no chain of taught stations clears it" in full.unresolved[0]


# ----------------------------------------------------------------------------- teach files
@pytest.mark.parametrize("raw, message", [
    ({"stylus": "S1", "safe_distance_m": 0.03, "step": [{"move": [0, 0, 0.1]}], "colour": 1}, "unknown key"),
    ({"stylus": "S1", "safe_distance_m": 0.0, "step": [{"move": [0, 0, 0.1]}]}, "safe_distance_m must be a positive"),
    ({"stylus": "S1", "safe_distance_m": -1, "step": [{"move": [0, 0, 0.1]}]}, "safe_distance_m must be a positive"),
    ({"stylus": "S1", "safe_distance_m": 0.03, "step": [{"move": [0, 0, 0.1], "stylus": "S2"}]}, "exactly one of"),
    ({"stylus": "S1", "safe_distance_m": 0.03, "step": [{"move": [0, 0]}]}, "three numbers"),
    ({"stylus": "S1", "safe_distance_m": 0.03, "step": [{"move": [0, 0, 0.1]}, {"touch": "P1", "point": [0, 0, 0],
                                                                                "normal": [0, 0, 1]}]}, "'feature'"),
    ({"stylus": "S1", "safe_distance_m": 0.03, "step": [{"move": [0, 0, 0.1]}]}, "at least one touch"),
    ({"stylus": "S1", "safe_distance_m": 0.03, "step": [{"touch": "P1", "feature": "F", "point": [0, 0, 0],
                                                         "normal": [0, 0, 1]}]}, "starts with a move"),
    ({"stylus": "1S", "safe_distance_m": 0.03, "step": [{"move": [0, 0, 0.1]}]}, "not a DMIS label"),
    ({"stylus": "S1", "safe_distance_m": 0.03, "settings": {"approach_m": 0}, "step": [{"move": [0, 0, 0.1]}]},
     "approach_m must be a positive"),
])
def test_bad_teach_files_are_refused_in_one_line(raw, message):
    with pytest.raises(TwinError, match=message) as exc:
        parse_teach(raw, "t.toml")
    assert "\n" not in str(exc.value)


def test_sweep_keeps_probes_apart_however_they_were_made():
    """Solids are cached by the probe's geometry, not its id (a dropped probe's id is reused)."""
    plate = trimesh.creation.box((0.1, 0.1, 0.002))  # top face at z = 1 mm
    sweep = ProbeSweep(plate.vertices, plate.faces, CLEARANCE_M)
    above = [0.0, 0.0, 0.05]  # ball 50 mm over the plate's centre
    for _ in range(50):
        down = ProbeGeometry(np.array([0.0, 0.0, -1.0]), 0.001, 0.0005, 0.02, 0.0066, 0.05, 0.025, 0.04)
        assert sweep.solid_distances(above, down)["ball"] == pytest.approx(0.05 - 0.001 - 0.001, abs=1e-9)
        del down
        side = ProbeGeometry(np.array([1.0, 0.0, 0.0]), 0.001, 0.0005, 0.02, 0.0066, 0.05, 0.025, 0.04)
        d = sweep.solid_distances(above, side)
        assert d["body"] == pytest.approx(0.05 - 0.0066 - 0.001, abs=1e-9)  # as low as the ball, wider
        assert d["head"] == pytest.approx(0.05 - 0.025 - 0.001, abs=1e-9)
        del side
