"""The 1 ms rollout shared by the scan and the replay: servo references in, sensordata out."""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import mujoco.rollout
import numpy as np

from twin.cell import Cell

ROLLOUT_CHUNK_STEPS = 2000


def simulate(cell: Cell, q_ref: np.ndarray, qd_ref: np.ndarray,
             on_chunk: Callable[[int, np.ndarray, np.ndarray], None]) -> None:
    """Roll the cell out at its time step with the servo references ``q_ref``, ``qd_ref`` (K, 6).

    The arm starts at rest at ``q_ref[0]``. ``on_chunk(i0, sensordata, q_before)`` receives each
    chunk of steps: ``sensordata`` (n, nsensordata) and the joint positions (n, 6) the sensors
    of each step were evaluated at.
    """
    model, data = cell.model, cell.data
    mujoco.mj_resetData(model, data)
    data.qpos[cell.qpos_adr] = q_ref[0]
    mujoco.mj_forward(model, data)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state, spec)
    ctrl = np.concatenate([q_ref, qd_ref], axis=1)
    n = len(q_ref)
    qadr = cell.qpos_adr + 1  # FULLPHYSICS state starts with time
    for i0 in range(0, n, ROLLOUT_CHUNK_STEPS):
        i1 = min(n, i0 + ROLLOUT_CHUNK_STEPS)
        states, sens = mujoco.rollout.rollout(model, data, state, ctrl[None, i0:i1])
        # sensordata of step i is computed before step i integrates: it pairs with the state
        # at the start of the step, which is the previous output state (or the initial one).
        q_before = np.vstack([state[None, qadr], states[0, :-1][:, qadr]])
        on_chunk(i0, sens[0], q_before)
        state = states[0, -1].copy()
