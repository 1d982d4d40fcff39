"""Reach and base placement: the closed-form UR inverse kinematics, the reach test, the base
search on a scenario whose base stands out of reach, checked against the real mink IK."""

from __future__ import annotations

import time

import numpy as np
import pytest

from algorithms.errors import AlgorithmError
from algorithms.geometry.kinematics import DHTable, dh_forward, ur_inverse
from tests.helpers import SCENARIOS, scenario
from twin.errors import TwinError
from twin.robot import HOME_Q, UR5E_DH
from twin.scenario import load_scenario
from twin.workflows.placement import (
    HOME_BRANCH,
    MIN_MARGIN,
    describe_unreachable_fix,
    place_base,
    reach,
    reach_targets,
    suggest_base,
)

FK_IK_AGREEMENT = 1e-9


def _wrapped(a):
    return np.angle(np.exp(1j * a))


def test_ur_inverse_reproduces_random_reachable_poses():
    rng = np.random.default_rng(9)
    q = rng.uniform(-np.pi, np.pi, (3000, 6))
    T = dh_forward(q, UR5E_DH)
    sol = ur_inverse(T, UR5E_DH)
    assert sol.valid.any(axis=1).all()          # every FK pose has a solution
    for b in range(8):
        ok = sol.valid[:, b]
        assert np.abs(dh_forward(sol.q[ok, b], UR5E_DH) - T[ok]).max() < FK_IK_AGREEMENT
    # the joint vector the pose came from is one of the eight
    dq = np.where(sol.valid, np.abs(_wrapped(sol.q - q[:, None])).max(axis=2, initial=0.0), np.inf)
    assert (dq.min(axis=1) < 1e-6).all()


def test_ur_inverse_one_branch_and_the_home_branch():
    T = dh_forward(HOME_Q, UR5E_DH)
    sol = ur_inverse(T, UR5E_DH, branches=(HOME_BRANCH,))
    assert sol.valid[0].tolist() == [b == HOME_BRANCH for b in range(8)]
    np.testing.assert_allclose(_wrapped(sol.q[0, HOME_BRANCH] - HOME_Q), 0.0, atol=1e-12)


def test_ur_inverse_refuses_another_geometry_and_flags_poses_out_of_reach():
    other = DHTable(a=(0.1, -0.4, -0.4, 0, 0, 0), d=UR5E_DH.d, alpha=UR5E_DH.alpha)
    with pytest.raises(AlgorithmError, match="UR geometry"):
        ur_inverse(np.eye(4), other)
    far = np.eye(4)
    far[:3, 3] = [1.5, 0.0, 0.3]
    assert not ur_inverse(far, UR5E_DH).valid.any()


def test_the_shipped_base_reaches_s_surface_with_margin():
    sc = scenario("s_surface")
    targets = reach_targets(sc)
    assert {"scan", "path"} == set(targets.source.tolist())
    r = reach(sc.T_world_base, targets.T_world_flange)
    assert r.all_reachable and r.min_margin > MIN_MARGIN
    # the search keeps a base that already reaches everything comfortably
    s = suggest_base(sc, targets)
    assert s is not None and np.allclose(s.T_world_base, sc.T_world_base)
    assert describe_unreachable_fix(sc, targets) is None


def _moved_base(tmp_path, xyz_yaw=("-0.6", "0.0", "0.0"), short=True):
    text = (SCENARIOS / "s_surface.toml").read_text()
    x, y, yaw = xyz_yaw
    text = text.replace("base_pose = { xyz = [0.0, 0.0, 0.0], rpy_deg = [0.0, 0.0, 0.0] }",
                        f"base_pose = {{ xyz = [{x}, {y}, 0.0], rpy_deg = [0.0, 0.0, {yaw}] }}")
    if short:
        text = text.replace('line_axis = "x"', 'line_axis = "x"\nmax_lines = 3')
    path = tmp_path / "far_base.toml"
    path.write_text(text)
    return load_scenario(path)


@pytest.mark.parametrize("xyz_yaw", [("-0.6", "0.0", "0.0"),
                                     pytest.param(("1.5", "0.5", "30.0"), marks=pytest.mark.slow)])
def test_a_base_out_of_reach_is_placed_where_mink_reaches_every_scan_pose(tmp_path, xyz_yaw):
    from twin.cell import build_cell
    from twin.plan import plan_scan
    from twin.realize import realize
    from twin.scan import solve_joint_references

    sc = _moved_base(tmp_path, xyz_yaw)
    targets = reach_targets(sc)
    assert not reach(sc.T_world_base, targets.T_world_flange).all_reachable
    t0 = time.perf_counter()
    suggestion = suggest_base(sc, targets)
    assert time.perf_counter() - t0 < 5.0
    assert suggestion is not None and suggestion.margin >= MIN_MARGIN
    placed, info = place_base(sc, targets)
    np.testing.assert_allclose(placed.T_world_base, suggestion.T_world_base)
    assert info["moved"] and info["old_unreachable_poses"] > 0 and info["margin"] >= MIN_MARGIN
    assert placed.raw["robot"]["base_pose"]["matrix"] == info["T_world_base"]
    assert reach(placed.T_world_base, targets.T_world_flange).all_reachable
    # the real IK of the scan, on the placed scenario's nominal cell
    nominal = build_cell(realize(placed), "nominal")
    with pytest.raises(TwinError, match="unreachable"):
        solve_joint_references(build_cell(realize(sc), "nominal"), plan_scan(nominal))
    q_ref, _ = solve_joint_references(nominal, plan_scan(nominal))
    assert np.isfinite(q_ref).all()
    fix = describe_unreachable_fix(sc, targets)
    assert fix is not None and fix.endswith("run with --place-base") and "x = " in fix


def test_place_base_refuses_a_base_off_the_table(tmp_path):
    text = (SCENARIOS / "s_surface.toml").read_text().replace(
        "base_pose = { xyz = [0.0, 0.0, 0.0]", "base_pose = { xyz = [0.0, 0.0, 0.2]")
    path = tmp_path / "raised.toml"
    path.write_text(text)
    with pytest.raises(TwinError, match="table plane"):
        place_base(load_scenario(path))


def test_run_offers_place_base():
    from twin.cli import build_parser

    args = build_parser().parse_args(["run", str(SCENARIOS / "s_surface.toml"), "--out", "x", "--place-base"])
    assert args.place_base
