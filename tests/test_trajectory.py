"""Joint trajectories: mink IK along a path (continuity, singular and unreachable poses) and the time law."""

import numpy as np
import pytest

from algorithms.errors import AlgorithmError
from algorithms.geometry.kinematics import dh_forward
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.paths.timing import time_law
from algorithms.paths.toolpath import build_path, cad_raster, flange_poses, transform_path
from tests.helpers import scenario
from tests.tolerances import FEED_REL, LIMIT_RATIO
from twin.cell import build_cell
from twin.errors import TwinError
from twin.process_paths import tool_settings
from twin.realize import realize
from twin.robot import ACCELERATION_LIMIT_RAD_S2, HOME_Q, UR5E_DH, VELOCITY_LIMIT_RAD_S
from twin.trajectory import POSITION_TOL_M, PathError, plan_joint_trajectory, solve_path


@pytest.fixture(scope="module")
def setup():
    sc = scenario("s_surface")
    realized = realize(sc)
    mesh = realized.workpiece.mesh
    nominal = build_cell(realized, "nominal")
    lines, normals = cad_raster(mesh, line_spacing_m=0.02, point_spacing_m=0.001, margin_m=0.005,
                                normals=MeshIndex(mesh).smooth_normals)
    path_wp = build_path(lines[:2], normals[:2], tool_settings(sc))
    path = transform_path(sc.workpiece.T_world_workpiece_nominal, path_wp)  # base = world here
    ik, traj = plan_joint_trajectory(nominal, path, sc.path.T_flange_tool, sc.path.feed_m_s,
                                     sc.path.transit_speed_m_s, sc.path.acceleration_m_s2)
    return sc, nominal, path, ik, traj


def test_ik_follows_the_path_continuously(setup):
    sc, nominal, path, ik, traj = setup
    assert ik.problems == ()
    assert ik.position_error_m.max() < POSITION_TOL_M
    # no branch flip: neighbouring poses 1-2 mm apart need small joint steps
    assert np.abs(np.diff(ik.q, axis=0)).max() < 0.05
    # the nominal forward kinematics reproduce the flange targets
    T_bf = flange_poses(path.T_tool, sc.path.T_flange_tool)
    fk = dh_forward(ik.q, UR5E_DH)
    assert np.linalg.norm(fk[:, :3, 3] - T_bf[:, :3, 3], axis=1).max() < POSITION_TOL_M


def test_time_law_respects_the_limits_and_the_feed(setup):
    sc, nominal, path, ik, traj = setup
    assert traj.velocity_ratio <= LIMIT_RATIO and traj.acceleration_ratio <= LIMIT_RATIO
    assert np.all(np.abs(traj.qd) <= VELOCITY_LIMIT_RAD_S * LIMIT_RATIO)
    assert np.all(np.abs(traj.qdd) <= ACCELERATION_LIMIT_RAD_S2 * LIMIT_RATIO)
    # finite differences agree with the analytic velocities (the servo feed-forward)
    fd = np.gradient(traj.q, traj.dt, axis=0)
    assert np.abs(fd - traj.qd)[1:-1].max() < 0.01
    # the trajectory passes through the IK solutions at their times
    q_at = np.array([np.interp(traj.t_path, traj.t, traj.q[:, j]) for j in range(6)]).T
    assert np.abs(q_at - ik.q).max() < 1e-3
    # on a process line the TCP moves at the feed once accelerated
    a, b, kind, _ = path.segments[1]
    assert kind == "process"
    sel = traj.segment == 1
    assert np.max(traj.speed_m_s[sel]) == pytest.approx(sc.path.feed_m_s, rel=FEED_REL)
    length = np.linalg.norm(np.diff(path.T_tool[a:b + 1, :3, 3], axis=0), axis=1).sum()
    dur = traj.t_path[b] - traj.t_path[a]
    ramp = sc.path.feed_m_s / sc.path.acceleration_m_s2
    assert dur == pytest.approx(length / sc.path.feed_m_s + ramp, rel=0.02)


def test_a_slower_feed_takes_longer(setup):
    sc, nominal, path, ik, traj = setup
    slow = time_law(path, ik.q, sc.path.feed_m_s / 2, sc.path.transit_speed_m_s, sc.path.acceleration_m_s2,
                    VELOCITY_LIMIT_RAD_S, ACCELERATION_LIMIT_RAD_S2)
    a, b, _, _ = path.segments[1]
    assert (slow.t_path[b] - slow.t_path[a]) > 1.9 * (traj.t_path[b] - traj.t_path[a]) - 0.2


@pytest.mark.parametrize("feed", [0.0, -0.01, float("nan")])
def test_feed_rate_must_be_positive(setup, feed):
    sc, nominal, path, ik, traj = setup
    with pytest.raises(AlgorithmError, match="feed rate must be a positive number"):
        time_law(path, ik.q, feed, 0.05, 0.25, VELOCITY_LIMIT_RAD_S, ACCELERATION_LIMIT_RAD_S2)
    with pytest.raises(TwinError, match="feed rate must be a positive number"):
        plan_joint_trajectory(nominal, path, sc.path.T_flange_tool, feed, 0.05, 0.25)


def test_non_rigid_tool_is_refused(setup):
    sc, nominal, path, ik, traj = setup
    T = sc.path.T_flange_tool.copy()
    T[:3, :3] *= 1.01
    with pytest.raises(TwinError, match="tool transform T_flange_tool rotation is not orthonormal"):
        plan_joint_trajectory(nominal, path, T, 0.03, 0.05, 0.25)


def test_unreachable_poses_are_reported_with_index_and_position(setup):
    sc, nominal, path, ik, traj = setup
    T = flange_poses(path.T_tool[:40], sc.path.T_flange_tool)
    far = T.copy()
    far[20:, 0, 3] += np.linspace(0.0, 1.0, 20)  # walks out of the arm's reach
    with pytest.raises(PathError, match=r"unreachable pose\(s\) of 40 .* first: pose \d+ at \(") as exc:
        solve_path(nominal, far, q_start=ik.q[0])
    probs = exc.value.problems
    unreachable = [p for p in probs if p.kind == "unreachable"]
    first = unreachable[0].index
    # out of reach (about 0.9 m from the shoulder) and from there on, none in reach
    assert 20 < first < 40 and [p.index for p in unreachable] == list(range(first, 40))
    assert np.allclose(unreachable[0].position_m, far[first, :3, 3])
    assert all(p.kind in ("unreachable", "discontinuous") for p in probs)
    # nothing is skipped: reporting mode returns every pose with the same problems
    rep = solve_path(nominal, far, q_start=ik.q[0], on_problem="report")
    assert len(rep.q) == 40 and [p.index for p in rep.problems] == [p.index for p in probs]


def test_singular_poses_are_reported():
    sc = scenario("s_surface")
    nominal = build_cell(realize(sc), "nominal")
    q = np.tile(HOME_Q, (41, 1))
    q[:, 4] = np.linspace(0.2, -0.2, 41)  # the wrist passes its singularity (q5 = 0)
    T = dh_forward(q, UR5E_DH)
    rep = solve_path(nominal, T, q_start=q[0], on_problem="report")
    sing = [p for p in rep.problems if p.kind == "singular"]
    assert sing and all(abs(q[p.index, 4]) < 0.05 for p in sing)
    assert any(p.index == 20 for p in sing)
    with pytest.raises(PathError, match="singular"):
        solve_path(nominal, T, q_start=q[0])


def test_bad_pose_arrays():
    nominal = build_cell(realize(scenario("s_surface")), "nominal")
    with pytest.raises(TwinError, match=r"\(K, 4, 4\)"):
        solve_path(nominal, np.eye(4))
    T = np.repeat(np.eye(4)[None], 3, axis=0)
    T[1, 0, 3] = np.nan
    with pytest.raises(TwinError, match="flange pose 1 contains NaN"):
        solve_path(nominal, T)
