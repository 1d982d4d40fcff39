"""twin/ActiveScan-v0: gymnasium's conventions (checker, seeding, vector modes, rendering), bad
input refused, and an episode that pins the part down to the tolerance with an honest
uncertainty."""

import os
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import twin.env  # noqa: F401  (registers the environments)
from tests.helpers import scenario
from tests.tolerances import ENV_CALIBRATION_SIGMAS
from twin.env.active_scan import ActiveScanEnv
from twin.env.arm import PART_CLEARANCE_M
from twin.env.observation import OBSERVATION_KEYS, flat
from twin.env.policies import GreedyInformationPolicy, RasterPolicy
from twin.robot import HOME_Q
from twin.trajectory import TABLE_CLEARANCE_M, TableCheck

ID = "twin/ActiveScan-v0"


@pytest.fixture(scope="module")
def env():
    e = gym.make(ID, max_steps=6)
    yield e
    e.close()


def _episode(env, seed, actions):
    obs, info = env.reset(seed=seed)
    out = [flat(obs)]
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out += [flat(obs), np.array([r, term, trunc, info["motion_time_s"], info["points"]])]
    return out


@pytest.mark.parametrize("actions", ["box", "views"])
def test_check_env_passes_without_a_warning(actions):
    e = gym.make(ID, max_steps=3, actions=actions)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(e.unwrapped, skip_render_check=True)
    e.close()
    gym_warnings = [str(w.message) for w in caught if "WARN" in str(w.message)]
    assert not gym_warnings, gym_warnings
    assert all(b.dtype == np.float32 for b in e.observation_space.spaces.values())
    assert e.action_space.dtype == (np.float32 if actions == "box" else np.int64)


def test_registration_sets_the_time_limit():
    e = gym.make(ID)
    assert e.spec.max_episode_steps == 30 and e.unwrapped.budget == 30
    e.close()
    e = gym.make(ID, max_steps=2, max_episode_steps=2)
    assert e.unwrapped.budget == 2
    obs, _ = e.reset(seed=0)
    miss = np.array([0.0, -1.0, 0.0, 0.0, 1.0, 1.0], dtype=np.float32)   # looks past the part: cheap
    assert not any(e.step(miss)[2:4])
    obs, _, term, trunc, _ = e.step(miss)
    assert trunc and not term and obs["progress"][0] == 0.0   # no step left
    e.close()


def test_same_seed_same_episode_bit_for_bit(env):
    actions = np.random.default_rng(7).uniform(-1, 1, (3, 6))
    actions[:, 4:] *= 0.3   # aim at the part so that the segments measure
    a = _episode(env, 11, actions)
    b = _episode(env, 11, actions)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert a[-1][4] > 0, "the episode measured no point: the test would not test the sensor's noise"
    c = _episode(env, 12, actions)
    assert not np.array_equal(a[0], c[0]) or not np.array_equal(a[-2], c[-2])


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_vector_envs_run(mode):
    envs = gym.make_vec(ID, num_envs=2, vectorization_mode=mode, max_steps=2)
    obs, _ = envs.reset(seed=[3, 4])
    assert obs["correlation"].shape == (2, 15)
    obs, reward, term, trunc, info = envs.step(np.zeros((2, 6), dtype=np.float32))
    assert obs["pose"].shape == (2, 6) and reward.shape == (2,) and np.all(np.isfinite(reward))
    envs.close()


RENDER_SCRIPT = """
import gymnasium as gym, numpy as np, twin
e = gym.make("twin/ActiveScan-v0", render_mode="rgb_array", width=160, height=120)
e.reset(seed=0)
e.step(np.array([0.25, -0.5, 0.0, 0.0, 0.0, 0.0], dtype=np.float32))   # a view from 37.5 deg: 100 points
np.save("frame.npy", e.render())
"""


def test_renders_a_frame_headless_without_mujoco_gl(tmp_path):
    """No display and no MUJOCO_GL (MuJoCo would pick GLFW and fail): the environment picks EGL."""
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY",
                                                              "PYOPENGL_PLATFORM")}
    run = subprocess.run([sys.executable, "-c", RENDER_SCRIPT], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    frame = np.load(tmp_path / "frame.npy")
    assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
    assert frame.std() > 5, "a blank frame"
    rgb = frame.astype(float)
    part = (rgb[..., 0] - rgb[..., 2] > 70).mean()   # the part's tan colour, not the grey table
    assert part > 0.02, f"the part fills {part:.1%} of the frame: hidden or out of view"


def test_import_twin_registers_without_importing_gymnasium():
    code = ("import sys, twin; assert 'gymnasium' not in sys.modules; import gymnasium; "
            "assert 'twin/ActiveProbe-v0' in gymnasium.registry")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]


def test_the_observation_is_bounded_and_says_which_directions_are_known(env):
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs) and set(obs) == set(OBSERVATION_KEYS)
    assert np.all(obs["pose"] == 0) and np.all(obs["std"] == 1) and np.all(obs["worst_std"] == 1)
    assert np.all(obs["coverage"] == 0) and obs["surface"].sum() == pytest.approx(1.0, abs=1e-6)
    assert obs["progress"].tolist() == [1.0, 0.0, 0.0]
    assert info["std_translation_m"] == pytest.approx(1e-3)   # the placement prior
    # straight down onto the bracket's top: z, and the tilts about x and y, become known; the
    # turn about z and the sideways shifts stay near the prior
    obs, *_ = env.step(np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0], dtype=np.float32))
    assert env.observation_space.contains(obs)
    std = dict(zip(["wx", "wy", "wz", "vx", "vy", "vz"], obs["std"], strict=True))
    assert std["vz"] < 0.5 and max(std["wz"], std["vx"], std["vy"]) > 0.8, std
    up = np.flatnonzero(obs["coverage"] > 0.5)
    assert up.tolist() == [2], obs["coverage"]   # the +z bin of the workpiece frame
    assert flat(obs).shape == (66,)


def test_views_actions_and_their_mask():
    e = gym.make(ID, actions="views", max_steps=3)
    obs, info = e.reset(seed=0)
    table, mask = e.unwrapped.view_table, info["action_mask"]
    assert e.action_space.n == len(table) == len(mask) == 200 and table.shape == (200, 6)
    assert mask.dtype == bool and 150 < mask.sum() < 200, mask.sum()   # most views reach the bracket
    assert np.array_equal(mask, e.unwrapped.action_masks())
    with pytest.raises(ValueError, match="one integer index of a view, 0 to 199"):
        e.step(200)
    with pytest.raises(ValueError, match="one integer index"):
        e.step(np.array([0.5, 0.0]))
    k = int(np.flatnonzero(mask)[0])
    *_, info = e.step(k)
    assert info["points"] > 0 and not info["clipped"]
    e.close()


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(tolerance_m=0.0), ValueError, "tolerance_m must be a finite number > 0"),
    (dict(tolerance_deg=-1.0), ValueError, "tolerance_deg"),
    (dict(max_steps=0), ValueError, "max_steps"),
    (dict(no_such_option=1), TypeError, "no_such_option"),
    (dict(render_mode="human"), ValueError, "render_mode"),
    (dict(actions="discrete"), ValueError, "actions must be one of 'box', 'views'"),
])
def test_bad_kwargs_are_refused(kwargs, error, match):
    with pytest.raises(error, match=match):
        ActiveScanEnv(**kwargs)


def test_a_part_out_of_reach_is_refused_at_construction():
    far = scenario("bracket", workpiece={"nominal_pose": {"xyz": [2.5, 0.0, 0.0]},
                                         "true_pose": {"xyz": [2.5, 0.0, 0.0]}})
    with pytest.raises(ValueError, match="reaches none of"):
        ActiveScanEnv(scenarios=[far])


def test_actions_outside_the_space(env):
    env.reset(seed=1)
    with pytest.raises(ValueError, match="6 finite numbers"):
        env.step(np.array([0, 0, 0, 0, 0, np.nan]))
    with pytest.raises(ValueError, match="6 finite numbers"):
        env.step(np.zeros(5))
    *_, info = env.step(np.array([3.0, 0, 0, 0, 0, 0]))
    assert info["clipped"]


def test_a_view_that_misses_the_part_costs_and_measures_nothing(env):
    env.reset(seed=2)
    _, reward, _, _, info = env.step(np.array([0.0, -1.0, 0.0, 0.0, 1.0, 1.0]))
    assert info["unreachable"] and info["points"] == 0
    assert reward == -env.unwrapped.unreachable_penalty


def test_greedy_episode_reaches_the_tolerance_with_an_honest_uncertainty():
    e = ActiveScanEnv(max_steps=12)
    policy = GreedyInformationPolicy(e)
    obs, info = e.reset(seed=0)
    for _ in range(12):
        obs, reward, term, trunc, info = e.step(policy(obs))
        if term or trunc:
            break
    assert info["is_success"], info
    assert info["std_translation_m"] <= 10e-6 and info["std_rotation_deg"] <= 0.01
    # the claim is honest: the true error is within a few of the reported sigmas
    assert info["translation_error_m"] <= ENV_CALIBRATION_SIGMAS * info["std_translation_m"] + 1e-6
    assert info["rotation_error_deg"] <= ENV_CALIBRATION_SIGMAS * info["std_rotation_deg"]


def test_raster_policy_replays_the_scenarios_scan_plan():
    e = ActiveScanEnv(max_steps=3)
    policy = RasterPolicy(e)
    obs, _ = e.reset(seed=0)
    policy.reset()
    for _ in range(3):
        obs, _, term, trunc, info = e.step(policy(obs))
        assert "unreachable" not in info and info["segment_points"] > 0
        if term or trunc:
            break


def test_a_motion_near_the_part_is_refused_before_it_moves(env):
    # the sensor 2 mm over the part's top, beam down: its housing would come within the part's
    # clearance; the table check alone would let it pass; at the sensor's stand-off it plans
    env.reset(seed=0)
    ep = env.unwrapped.episode
    arm, es = ep["arm"], ep["es"]
    lo, hi = es.workpiece.mesh.bounds
    T_wp = es.scenario.workpiece.T_world_workpiece_nominal
    top = T_wp[:3, :3] @ np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2]]) + T_wp[:3, 3]
    plans = {}
    for standoff_m in (0.002, es.scenario.sensor.reference_m):
        T_start = np.eye(4)
        T_start[:3, :3] = np.diag([1.0, -1.0, -1.0])
        T_start[:3, 3] = top + [0.0, 0.0, standoff_m]
        T_end = T_start.copy()
        T_end[0, 3] += 0.01
        arm.solver.set_q(HOME_Q)
        arm.solver.solve(T_start, 0.05, 300, velocity_limited=False)
        q = arm.solver.q.copy()
        checks = (arm.clearance.nearest(q), TableCheck(es.nominal, TABLE_CLEARANCE_M).nearest(q))
        plans[standoff_m] = (arm.plan(T_start, T_end), *checks)
    refused, near, table_only = plans[0.002]
    assert isinstance(refused, str) and "laser_housing" in refused
    assert near is not None and near[1] < PART_CLEARANCE_M and table_only is None
    planned, near, _ = plans[es.scenario.sensor.reference_m]
    assert not isinstance(planned, str) and near is None


def test_greedy_does_not_choose_again_what_measured_nothing(env):
    obs, _ = env.reset(seed=2)
    policy = GreedyInformationPolicy(env)
    policy.reset()
    first = policy(obs)
    env.unwrapped.episode["arm"].plan = lambda *args: "refused by the test"
    obs, _, _, _, info = env.step(first)
    assert info["unreachable"] == "refused by the test"
    assert not np.array_equal(policy(obs), first)


def test_placement_ranges_draw_each_episodes_prior():
    e = ActiveScanEnv(placement_sigma_m=(1e-4, 1e-2), placement_sigma_deg=(0.1, 1.0), max_steps=2)
    sigmas = []
    for seed in range(6):
        obs, info = e.reset(seed=seed)
        sigmas.append(info["std_translation_m"])   # the prior's, nothing measured yet
        assert 1e-4 <= info["std_translation_m"] <= 1e-2 and 0.1 <= info["std_rotation_deg"] <= 1.0
        assert np.all(obs["std"] == 1)   # the observation is scaled by the episode's own prior
    assert len(set(sigmas)) == 6
    assert e.reset(seed=3)[1]["std_translation_m"] == sigmas[3]
    with pytest.raises(ValueError, match=r"placement_sigma_m must be .* low <= high, got \(0.01, 0.001\)"):
        ActiveScanEnv(placement_sigma_m=(1e-2, 1e-3))


def test_each_episode_masks_the_views_of_its_own_part():
    e = ActiveScanEnv(scenarios=["bracket.toml", "cube.toml"], actions="views", max_steps=2)
    masks = {es.scenario.name: m for es, m in zip(e.scenarios, e._view_masks, strict=True)}
    assert not np.array_equal(*masks.values())   # the two parts' reachable views differ
    seen = set()
    for seed in range(8):
        _, info = e.reset(seed=seed)
        seen.add(info["scenario"])
        assert np.array_equal(info["action_mask"], masks[info["scenario"]])
    assert seen == set(masks)
