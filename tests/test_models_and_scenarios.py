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


def test_a_height_field_is_cast_once_per_mesh_and_again_when_the_mesh_changes():
    """The part's collision height field (its own frame) is cast once per mesh: a second cell of
    the same part reuses it; a mesh moved since is cast again, and its field moves with it."""
    import trimesh

    from twin.replay import height_field

    mesh = trimesh.creation.box(extents=[0.04, 0.03, 0.02])
    first = height_field(mesh)
    assert height_field(mesh) is first
    assert first.heights_m.max() == pytest.approx(0.02, abs=1e-9)
    mesh.apply_translation([0.005, 0.0, 0.0])
    moved = height_field(mesh)
    assert moved is not first and moved.x_m[0] == pytest.approx(first.x_m[0] + 0.005, abs=1e-12)
