"""The 1 ms rollout shared by the scan and the replay: servo references in, sensordata out."""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import mujoco.rollout
import numpy as np

from twin.cell import Cell

ROLLOUT_CHUNK_STEPS = 2000


def simulate(cell: Cell, q_ref: np.ndarray, qd_ref: np.ndarray,
             on_chunk: Callable[[int, np.ndarray, np.ndarray], None] | None = None,
             state: np.ndarray | None = None, chunk_steps: int = ROLLOUT_CHUNK_STEPS,
             states_out: list | None = None) -> np.ndarray:
    """Roll the cell out at its time step with the servo references ``q_ref``, ``qd_ref`` (K, 6).

    The arm starts at rest at ``q_ref[0]``, or from ``state`` (a full physics state, see
    :func:`full_state`) to continue an earlier rollout. ``on_chunk(i0, sensordata, q_before)``
    receives each chunk of steps: ``sensordata`` (n, nsensordata) and the joint positions
    (n, 6) the sensors of each step were evaluated at; returning True stops the rollout after
    that chunk. With ``states_out`` (a list), the full state after every step of each chunk
    is appended to it, chunk by chunk ((n, state size) arrays). Returns the final state.
    """
    model, data = cell.model, cell.data
    if state is None:
        mujoco.mj_resetData(model, data)
        data.qpos[cell.qpos_adr] = q_ref[0]
        mujoco.mj_forward(model, data)
        state = full_state(cell)
    state = np.array(state, dtype=np.float64)
    ctrl = np.concatenate([q_ref, qd_ref], axis=1)
    n = len(q_ref)
    qadr = cell.qpos_adr + 1  # FULLPHYSICS state starts with time
    for i0 in range(0, n, chunk_steps):
        i1 = min(n, i0 + chunk_steps)
        states, sens = mujoco.rollout.rollout(model, data, state, ctrl[None, i0:i1])
        # sensordata of step i is computed before step i integrates: it pairs with the state
        # at the start of the step, which is the previous output state (or the initial one).
        q_before = np.vstack([state[None, qadr], states[0, :-1][:, qadr]])
        if states_out is not None:
            states_out.append(states[0])
        state = states[0, -1].copy()
        if on_chunk is not None and on_chunk(i0, sens[0], q_before):
            break
    return state


def full_state(cell: Cell) -> np.ndarray:
    """The cell's full physics state (time first), as :func:`simulate` takes and returns it."""
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(cell.model, spec))
    mujoco.mj_getState(cell.model, cell.data, state, spec)
    return state
