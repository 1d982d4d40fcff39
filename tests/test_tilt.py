"""Tool axes tilted within a cone so that the shank and holder clear the part
(``algorithms.paths.tilt``), and the ball-end path built on them."""

import numpy as np
import pytest

from algorithms.paths.tilt import clear_axes, clearance_m, foot_gap_m, profile_gaps_m, steer_axes, tool_profile
from algorithms.paths.toolpath import ToolSettings, build_path
from tests.tolerances import ORTHONORMAL

TIP_M, SHANK_M, HOLDER_M, HOLDER_LEN_M, REACH_M = 0.004, 0.004, 0.015, 0.05, 0.13
WALL_X_M = 0.02          # a wall 0.2 m high stands on the floor z = 0 from x = 20 mm on
MIN_GAP_M = 0.003
PROFILE = tool_profile(REACH_M, TIP_M, SHANK_M, HOLDER_M, HOLDER_LEN_M, 0.002)


def _box_sdf(p, lo, hi):
    centre, half = (np.asarray(lo) + hi) / 2, (np.asarray(hi) - lo) / 2
    q = np.abs(p - centre) - half
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(np.max(q, axis=1), 0.0)


def floor_and_wall(p):
    """Signed distance [m] to a floor slab (z < 0) with a wall on it (x > 20 mm)."""
    p = np.asarray(p, dtype=np.float64)
    return np.minimum(_box_sdf(p, (-0.5, -0.5, -0.05), (0.5, 0.5, 0.0)),
                      _box_sdf(p, (WALL_X_M, -0.5, -0.05), (0.06, 0.5, 0.2)))


def _floor_line(x_m):
    contacts = np.column_stack([x_m, np.zeros_like(x_m), np.zeros_like(x_m)])
    return contacts, np.tile([0.0, 0.0, 1.0], (len(x_m), 1))


def test_gaps_under_a_limit_are_exact_and_the_others_bounded_by_it():
    # profile_gaps_m with a limit computes every PROFILE_STRIDE-th sample up the tool and only
    # the samples their Lipschitz bound cannot clear: under the limit the gaps (and so each
    # row's minimum) are the exact ones, elsewhere at least the limit
    rng = np.random.default_rng(2)
    centres = np.column_stack([rng.uniform(-0.05, 0.05, 400), rng.uniform(-0.05, 0.05, 400),
                               rng.uniform(0.002, 0.05, 400)])
    axes = rng.normal(size=(400, 3)) + [0.0, 0.0, 2.0]
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    exact = profile_gaps_m(centres, axes, PROFILE, floor_and_wall)
    for limit in (MIN_GAP_M, 0.02):
        got = profile_gaps_m(centres, axes, PROFILE, floor_and_wall, limit)
        under = exact < limit
        assert 0 < under.sum() < under.size
        assert np.array_equal(got[under], exact[under])
        assert np.all(got[~under] >= limit) and np.all(got <= exact)
        assert np.array_equal(clearance_m(centres, axes, PROFILE, floor_and_wall, limit) < limit,
                              exact.min(axis=1) < limit)


def test_the_holder_clears_a_wall_by_tilting_away_from_it():
    x = np.arange(-0.04, 0.0121, 0.002)
    contacts, normals = _floor_line(x)
    centres = contacts + TIP_M * normals
    upright = clearance_m(centres, normals, PROFILE, floor_and_wall)
    assert np.any(upright < MIN_GAP_M)                   # the holder meets the wall near it
    max_tilt = np.radians(30.0)
    axes = clear_axes(contacts, normals, TIP_M, PROFILE, floor_and_wall, max_tilt, MIN_GAP_M)
    assert np.allclose(np.linalg.norm(axes, axis=1), 1.0, atol=ORTHONORMAL)
    tilt = np.arccos(np.clip(axes[:, 2], -1.0, 1.0))
    assert np.all(tilt <= max_tilt + 1e-12)
    assert np.all(clearance_m(centres, axes, PROFILE, floor_and_wall) >= MIN_GAP_M)
    tilted = tilt > 1e-9
    assert np.all(axes[tilted, 0] < 0)                   # away from the wall
    assert np.all(tilt[x < -0.015] == 0.0)               # far from it the axis is the normal
    assert np.all(np.diff(tilt) >= -1e-12)               # ramps in towards the wall, no jumps back


def test_the_foot_of_a_tilted_shank_drops_towards_the_surface():
    centre = np.array([[-0.2, 0.0, TIP_M]])          # the ball on the floor, far from the wall
    for tilt_deg in (0.0, 30.0):
        a = np.radians(tilt_deg)
        axis = np.array([[np.sin(a), 0.0, np.cos(a)]])
        # the lowest point of the shank's rim at the ball's equator: r (1 - sin tilt) above the floor
        assert foot_gap_m(centre, axis, PROFILE, floor_and_wall)[0] == pytest.approx(TIP_M * (1 - np.sin(a)), abs=1e-12)
    # 0.5 mm beside the wall: leaning 30 deg away clears the shank above the ball, not its foot
    near = np.array([[WALL_X_M - TIP_M - 0.0005, 0.0, TIP_M]])
    up, away = np.array([[0.0, 0.0, 1.0]]), np.array([[-0.5, 0.0, np.sqrt(0.75)]])
    assert clearance_m(near, up, PROFILE, floor_and_wall)[0] < MIN_GAP_M
    assert clearance_m(near, away, PROFILE, floor_and_wall)[0] >= MIN_GAP_M
    assert foot_gap_m(near, away, PROFILE, floor_and_wall)[0] < 0.0015


def test_tilts_keep_the_foot_of_the_shank_clear():
    x = np.arange(-0.04, 0.0121, 0.002)
    contacts, normals = _floor_line(x)
    centres = contacts + TIP_M * normals
    axes = clear_axes(contacts, normals, TIP_M, PROFILE, floor_and_wall, np.radians(30.0), MIN_GAP_M, 0.0015)
    assert np.all(clearance_m(centres, axes, PROFILE, floor_and_wall) >= MIN_GAP_M)
    assert np.all(foot_gap_m(centres, axes, PROFILE, floor_and_wall) >= 0.0015)


def test_no_tilt_allowed_or_nothing_in_the_way_leaves_the_normals():
    contacts, normals = _floor_line(np.arange(-0.04, 0.0121, 0.002))
    assert np.array_equal(clear_axes(contacts, normals, TIP_M, PROFILE, floor_and_wall, 0.0, MIN_GAP_M), normals)
    far, n_far = _floor_line(np.arange(-0.2, -0.1, 0.002))
    assert np.array_equal(clear_axes(far, n_far, TIP_M, PROFILE, floor_and_wall, np.radians(30), MIN_GAP_M), n_far)


def test_a_point_no_axis_in_the_cone_clears_keeps_its_normal():
    # 3.5 mm from the wall the 4 mm shank touches it right above the ball, at any tilt up to 30 deg
    contacts, normals = _floor_line(np.array([WALL_X_M - 0.0035]))
    axes = clear_axes(contacts, normals, TIP_M, PROFILE, floor_and_wall, np.radians(30), MIN_GAP_M)
    assert np.array_equal(axes, normals)
    assert clearance_m(contacts + TIP_M * normals, axes, PROFILE, floor_and_wall)[0] < MIN_GAP_M


@pytest.mark.parametrize("zigzag", [False, True])
def test_a_tilted_ball_end_touches_the_same_point(zigzag):
    x = np.arange(-0.04, 0.0121, 0.002)
    contacts, normals = _floor_line(x)
    axes = clear_axes(contacts, normals, TIP_M, PROFILE, floor_and_wall, np.radians(30), MIN_GAP_M)
    lines = [contacts, contacts + [0.0, 0.004, 0.0]]
    path = build_path(lines, [normals, normals], ToolSettings(tip_radius_m=TIP_M, zigzag=zigzag),
                      lines_axis=[axes, axes])
    on = path.process_mask()
    T = path.T_tool[on]
    # the ball's centre (tip + r axis) is the contact's centre (c + r n), and the axis is the planned one
    assert np.allclose(T[:, :3, 3] + TIP_M * T[:, :3, 2], path.contact[on] + TIP_M * path.normal[on], atol=1e-12)
    planned = np.concatenate([axes, axes[::-1] if zigzag else axes])
    assert np.allclose(T[:, :3, 2], planned, atol=1e-12)
    assert np.abs(T[:, :3, 2] @ [1.0, 0.0, 0.0]).max() > 0.1     # some poses do tilt


def test_tool_axes_must_match_the_lines():
    contacts, normals = _floor_line(np.arange(0.0, 0.01, 0.002))
    with pytest.raises(Exception, match="lines_axis"):
        build_path([contacts], [normals], ToolSettings(), lines_axis=[normals, normals])
    with pytest.raises(Exception, match="lines_axis"):
        build_path([contacts], [normals], ToolSettings(), lines_axis=[normals[:2]])


def _leaning(direction):
    """A made-up cost for the arm: lower the more the axes lean towards ``direction``."""
    return lambda centres, axes: -float(np.mean(axes @ np.asarray(direction, dtype=float)))


def _far_floor(p):
    return np.asarray(p)[:, 2] + 1.0     # nothing within a metre below: every axis is clear


def test_the_arm_gets_the_tilt_it_asks_for_on_the_stretch_with_ramps():
    contacts, normals = _floor_line(np.arange(-0.2, -0.1, 0.002))
    max_tilt = np.radians(30.0)
    out = steer_axes(contacts, normals, normals, 20, 30, _leaning([1, 0, 0]), TIP_M, PROFILE, floor_and_wall,
                     max_tilt, MIN_GAP_M, 0.0015, ramp=3)
    tilt = np.degrees(np.arccos(np.clip(out[:, 2], -1.0, 1.0)))
    assert np.allclose(tilt[20:30], 30.0) and np.allclose(out[20:30, 0], 0.5)     # all the cone allows, +x
    assert np.array_equal(out[:17], normals[:17]) and np.array_equal(out[33:], normals[33:])
    assert np.all(np.diff(tilt[16:21]) > 0) and np.all(np.diff(tilt[29:34]) < 0)   # ramps in and out
    assert np.allclose(np.linalg.norm(out, axis=1), 1.0, atol=ORTHONORMAL)
    # an arm that wants the axis on the normal gets nothing new
    assert steer_axes(contacts, normals, normals, 20, 30, _leaning([0, 0, 1]), TIP_M, PROFILE, floor_and_wall,
                      max_tilt, MIN_GAP_M, 0.0015) is None


def test_a_fast_turning_normal_is_followed_slower_within_the_cones():
    # a bend: the normal turns 24 deg from one point to the next; the arm's cost is the largest
    # turn of the axis between neighbours (the wrist's step)
    n_pts = 41
    x = np.arange(n_pts) * 0.001
    angle = np.where(np.arange(n_pts) < 20, 0.0, np.radians(24.0))
    normals = np.column_stack([np.sin(angle), np.zeros(n_pts), np.cos(angle)])
    contacts = np.column_stack([x, np.zeros(n_pts), np.zeros(n_pts)])

    def largest_turn(centres, axes):
        return float(np.max(np.arccos(np.clip(np.sum(axes[1:] * axes[:-1], axis=1), -1.0, 1.0))))

    max_tilt = np.radians(20.0)
    out = steer_axes(contacts, normals, normals, 17, 23, largest_turn, TIP_M, PROFILE, _far_floor, max_tilt,
                     MIN_GAP_M)
    assert out is not None
    assert largest_turn(None, out) < 0.5 * largest_turn(None, normals)
    assert np.all(np.sum(out * normals, axis=1) >= np.cos(max_tilt) - 1e-12)       # every axis in its cone
    assert np.allclose(np.linalg.norm(out, axis=1), 1.0, atol=ORTHONORMAL)


def test_the_arm_never_gets_a_tilt_that_brings_the_tool_into_the_part():
    # next to the wall (+x) the arm would like the axis leaning along it (+y): a tilt towards
    # +y alone keeps the holder as near the wall as upright (not clear), so it gets the best
    # clear one, leaning along the wall and away from it
    x = np.arange(-0.03, 0.0121, 0.002)
    contacts, normals = _floor_line(x)
    centres = contacts + TIP_M * normals
    max_tilt = np.radians(30.0)
    axes = clear_axes(contacts, normals, TIP_M, PROFILE, floor_and_wall, max_tilt, MIN_GAP_M, 0.0015)
    lo, hi = len(x) - 6, len(x)
    out = steer_axes(contacts, normals, axes, lo, hi, _leaning([0, 1, 0]), TIP_M, PROFILE, floor_and_wall,
                     max_tilt, MIN_GAP_M, 0.0015)
    assert out is not None
    assert np.all(out[lo:hi, 1] > 0.1) and np.all(out[lo:hi, 0] < -0.1)
    assert np.all(clearance_m(centres, out, PROFILE, floor_and_wall) >= MIN_GAP_M)
    tilted = out[:, 2] < np.cos(1e-6)
    assert np.all(foot_gap_m(centres[tilted], out[tilted], PROFILE, floor_and_wall) >= 0.0015)
    assert np.all(np.degrees(np.arccos(np.clip(out[:, 2], -1.0, 1.0))) <= 30.0 + 1e-9)
    # an arm that wants the axis leaning into the wall gets at most what keeps the tool clear
    towards = steer_axes(contacts, normals, axes, lo, hi, _leaning([1, 0, 0]), TIP_M, PROFILE, floor_and_wall,
                         max_tilt, MIN_GAP_M, 0.0015)
    assert towards is not None
    assert np.all(clearance_m(centres, towards, PROFILE, floor_and_wall) >= MIN_GAP_M)
