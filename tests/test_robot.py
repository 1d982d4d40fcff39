import mujoco
import numpy as np

from algorithms.geometry.kinematics import dh_forward
from tests.tolerances import FK_AGREEMENT_M
from twin.robot import FLANGE_SITE, SCENE_XML, UR5E_DH


def test_mujoco_forward_kinematics_equals_dh_table():
    model = mujoco.MjModel.from_xml_path(str(SCENE_XML))
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    site = model.site(FLANGE_SITE).id
    for _ in range(20):
        q = rng.uniform(-np.pi, np.pi, 6)
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        T = dh_forward(q, UR5E_DH)
        assert np.max(np.abs(data.site_xpos[site] - T[:3, 3])) < FK_AGREEMENT_M
        assert np.max(np.abs(data.site_xmat[site].reshape(3, 3) - T[:3, :3])) < FK_AGREEMENT_M


def test_dh_zero_configuration_matches_published_reach():
    # UR5e at q = 0: flange at x = a2 + a3, y = -(d4 + d6), z = d1 - d5.
    T = dh_forward(np.zeros(6), UR5E_DH)
    assert np.allclose(T[:3, 3], [-0.8172, -0.2329, 0.0628], atol=1e-12)
