"""Every shipped scenario and model loads, compiles and steps without a MuJoCo warning.

New files are picked up by the globs: a new scenario or model is tested without editing a
test (as MuJoCo Menagerie tests its models).
"""

from pathlib import Path

import mujoco
import numpy as np
import pytest

from tests.helpers import MODELS, SCENARIOS
from twin.cell import build_cell
from twin.probing import build_probe_cell
from twin.realize import realize
from twin.replay import build_replay_cell
from twin.robot import HOME_Q
from twin.scenario import load_scenario

STEP_S = 0.1
SCENARIO_FILES = sorted(SCENARIOS.glob("*.toml"))
SCENE_FILES = sorted(MODELS.glob("**/scene*.xml"))


def _step_without_warnings(model: mujoco.MjModel, data: mujoco.MjData, what: str) -> None:
    for _ in range(int(round(STEP_S / model.opt.timestep))):
        mujoco.mj_step(model, data)
    warned = {mujoco.mjtWarning(i).name: int(data.warning[i].number) for i in range(len(data.warning))
              if data.warning[i].number > 0}
    assert not warned, f"{what}: MuJoCo warnings {warned}"
    assert np.all(np.isfinite(data.qpos)), f"{what}: non-finite state after {STEP_S} s"


def test_there_is_something_to_sweep():
    assert SCENARIO_FILES and SCENE_FILES


@pytest.mark.parametrize("path", SCENE_FILES, ids=lambda p: str(p.relative_to(MODELS)))
def test_model_scene_compiles_and_steps(path: Path):
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0) if model.nkey else mujoco.mj_resetData(model, data)
    _step_without_warnings(model, data, str(path))


@pytest.mark.parametrize("path", SCENARIO_FILES, ids=lambda p: p.stem)
def test_scenario_cells_compile_and_step(path: Path):
    realized = realize(load_scenario(path))
    cells = [("nominal", build_cell(realized, "nominal")), ("true", build_cell(realized, "true")),
             ("replay", build_replay_cell(realized))]
    if realized.scenario.probe is not None:
        cells.append(("probe", build_probe_cell(realized)))
    for which, cell in cells:
        cell.set_q(HOME_Q)
        # hold the home posture with the servos (position and velocity references)
        cell.data.ctrl[:] = np.concatenate([HOME_Q, np.zeros(6)])
        _step_without_warnings(cell.model, cell.data, f"{path.name} ({which} cell)")
