import numpy as np
import pytest

from tests.helpers import SCENARIOS, merge, raw_scenario, scenario
from twin.errors import TwinError
from twin.scenario import load_scenario, parse_scenario

SEED_SCENARIOS = ["s_surface", "hemisphere_punch", "bottle_punch", "inner_sphere", "through_hole"]


@pytest.mark.parametrize("name", SEED_SCENARIOS)
def test_every_seed_scenario_loads(name):
    sc = load_scenario(SCENARIOS / f"{name}.toml")
    assert sc.workpiece.T_world_workpiece_true.shape == (4, 4)
    assert sc.sensor.window_m == (0.055, 0.105)


def test_pose_forms_agree():
    a = scenario(workpiece={"true_pose": {"xyz": [0.4, 0.1, 0.0], "rpy_deg": [0, 0, 90]}})
    M = [[0, -1, 0, 0.4], [1, 0, 0, 0.1], [0, 0, 1, 0], [0, 0, 0, 1]]
    b = scenario(workpiece={"true_pose": {"matrix": M}})
    assert np.allclose(a.workpiece.T_world_workpiece_true, b.workpiece.T_world_workpiece_true, atol=1e-12)


@pytest.mark.parametrize("over, message", [
    ({"scan": {"line_spacing": 0.004}}, "unknown key(s) scan.line_spacing"),
    ({"sensr": {}}, "unknown key(s)"),
    ({"scan": {"speed_m_s": "fast"}}, "scan.speed_m_s must be a finite number"),
    ({"scan": {"speed_m_s": 0.0}}, "outside the allowed range"),
    ({"scan": {"standoff_m": 0.150}}, "outside the sensor window"),
    ({"noise": {"gaussian": 1}}, "noise.gaussian must be true or false"),
    ({"workpiece": {"true_pose": {"matrix": [[1, 0.1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}}},
     "not orthonormal"),
    ({"workpiece": {"true_pose": {"matrix": [[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}}},
     "reflection"),
    ({"workpiece": {"shape": "cube9"}}, "is not one of"),
    ({"sensor": {"kind": "area"}}, "sensor.kind = 'area' is not one of point, line"),
    ({"seed": -1}, "seed must be an integer"),
])
def test_bad_values_are_refused_with_one_line(over, message):
    with pytest.raises(TwinError) as exc:
        scenario(**over)
    assert message in str(exc.value)
    assert "\n" not in str(exc.value)


def test_shape_and_mesh_are_exclusive():
    raw = merge(raw_scenario("s_surface"), {"workpiece": {"mesh": "part.stl"}})
    with pytest.raises(TwinError, match="exactly one of"):
        parse_scenario(raw)


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(TwinError, match="not found"):
        load_scenario(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("seed = = 3")
    with pytest.raises(TwinError, match="not valid TOML"):
        load_scenario(bad)
