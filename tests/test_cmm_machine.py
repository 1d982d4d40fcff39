"""The bridge CMM model (models/cmm): the conventions the twin relies on, and its servos."""

from pathlib import Path

import mujoco
import numpy as np
import pytest

SCENE = Path(__file__).resolve().parents[1] / "models" / "cmm" / "scene.xml"
JOINTS = ("axis_x", "axis_y", "axis_z", "head_a", "head_b")
EXACT_M = 1e-12


@pytest.fixture(scope="module")
def model():
    return mujoco.MjModel.from_xml_path(str(SCENE))


def _set(model, data, q):
    for j, v in zip(JOINTS, q, strict=True):
        data.qpos[model.jnt_qposadr[model.joint(j).id]] = v
    mujoco.mj_forward(model, data)


def test_axes_read_the_head_centre_and_the_mount_points_along_d(model):
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    mount = model.body("probe_mount").id
    for _ in range(20):
        q = [rng.uniform(0, 0.7), rng.uniform(0, 1.0), rng.uniform(0.1, 0.76), rng.uniform(0, 1.8), rng.uniform(-3, 3)]
        _set(model, data, q)
        np.testing.assert_allclose(data.site("head_centre").xpos, q[:3], atol=EXACT_M)
        np.testing.assert_allclose(data.xpos[mount], q[:3], atol=EXACT_M)
        a, b = q[3], q[4]
        d = [np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), -np.cos(a)]
        np.testing.assert_allclose(data.xmat[mount].reshape(3, 3)[:, 2], d, atol=EXACT_M)


def test_joint_ranges_are_the_published_numerics(model):
    for axis, key in zip(("axis_x", "axis_y", "axis_z"), ("x", "y", "z"), strict=True):
        lo, hi = model.jnt_range[model.joint(axis).id]
        assert hi - lo == pytest.approx(float(model.numeric(f"cmm_range_{key}_m").data[0]), abs=EXACT_M)


def test_a_straight_move_stays_on_its_line_and_settles():
    """A 100 mm diagonal move with the class's acceleration: the head leaves its line by less
    than 1 um (every axis has the same dynamics) and settles within 5 um in 50 ms."""
    model = mujoco.MjModel.from_xml_path(str(SCENE))
    data = mujoco.MjData(model)
    start, end = np.array([0.2, 0.3, 0.4]), np.array([0.26, 0.38, 0.4])
    _set(model, data, [*start, 0.0, 0.0])
    u = (end - start) / np.linalg.norm(end - start)
    a, dist = 1.0, float(np.linalg.norm(end - start))
    t_acc = np.sqrt(dist / a)
    n = int(2 * t_acc / 1e-3)
    off_line = 0.0
    for k in range(n + 50):
        t = min((k + 1) * 1e-3, 2 * t_acc)
        s = 0.5 * a * t**2 if t < t_acc else dist - 0.5 * a * (2 * t_acc - t) ** 2
        v = a * t if t < t_acc else a * (2 * t_acc - t)
        ref = start + s * u
        for i, ax in enumerate(("axis_x", "axis_y", "axis_z")):
            data.ctrl[model.actuator(f"{ax}_pos").id] = ref[i]
            data.ctrl[model.actuator(f"{ax}_vel").id] = v * u[i]
        mujoco.mj_step(model, data)
        h = data.site("head_centre").xpos - start
        off_line = max(off_line, float(np.linalg.norm(h - (h @ u) * u)))
    assert off_line < 1e-6
    assert np.linalg.norm(data.site("head_centre").xpos - end) < 5e-6
    assert not any(data.warning[i].number for i in range(len(data.warning)))


def test_the_head_indexes_to_a_horizontal_probe():
    model = mujoco.MjModel.from_xml_path(str(SCENE))
    data = mujoco.MjData(model)
    _set(model, data, [0.3, 0.5, 0.4, 0.0, 0.0])
    data.ctrl[model.actuator("head_a_pos").id] = np.pi / 2
    for ax, v in zip(("axis_x", "axis_y", "axis_z"), (0.3, 0.5, 0.4), strict=True):
        data.ctrl[model.actuator(f"{ax}_pos").id] = v
    for _ in range(1500):
        mujoco.mj_step(model, data)
    assert data.qpos[model.jnt_qposadr[model.joint("head_a").id]] == pytest.approx(np.pi / 2, abs=1e-3)
