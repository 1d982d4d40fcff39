"""The probing move of a touch-trigger probe, for any machine that carries one.

One engine (:func:`probing_move`) owns the move both the arm (:mod:`twin.probing`) and the
bridge CMM (:mod:`twin.cmm_machine`) make on every probe point:

1. advance along the probing line, one chunk of 1 ms steps at a time;
2. watch the true ball centres for the touch (the gap to the exact surface at or below zero),
   then for the trigger (:func:`twin.sensors.touch_probe.find_trigger`: the touch plus one
   pre-travel draw per touch, in the probe frame);
3. on the trigger: latch the measuring system (joint encoders or scales, with their noise) at
   the trigger time, brake at the stop deceleration, retract; at the end of the line without a
   trigger: retract and report a miss.

The machine is what moves: :class:`ProbingMachine` says what the engine asks of it. How it
follows its references (IK and a servo rollout, axis set-points) and what its latch reads are
its own.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

import numpy as np

from algorithms.arraytypes import FloatArray
from algorithms.probing.pretravel import PretravelModel
from twin.sensors.touch_probe import Trigger, find_trigger

ReadingT = TypeVar("ReadingT")
ReadingT_co = TypeVar("ReadingT_co", covariant=True)

#: signed distance [m] of ball-centre positions (k, 3), machine world frame, to the exact
#: surface minus the ball radius: positive in the air, zero at the touch
GapFn = Callable[[FloatArray], FloatArray]


class ProbingMachine(Protocol[ReadingT_co]):
    """A machine making one probing move along a line it was set up with (world frame, SI).

    Attributes:
        chunk_steps: how many 1 ms steps the engine asks for between two trigger checks.
    """

    chunk_steps: int

    def lead_in(self) -> tuple[FloatArray, FloatArray]:
        """Samples recorded before the move's first step that the trigger search also sees:
        ball centres (k, 3) [m] and times (k,) [s], k may be 0."""
        ...

    def advance(self, n_steps: int) -> tuple[FloatArray, FloatArray]:
        """Move the reference on along the line by up to ``n_steps`` steps: the true ball
        centres (m, 3) [m] and times (m,) [s] of the steps taken; m = 0 at the line's end."""
        ...

    def R_world_probe(self) -> FloatArray:
        """(3, 3) the probe frame (z along the stylus) in the world now: where the pre-travel
        direction is read."""
        ...

    def latch(self, t_s: float) -> ReadingT_co:
        """The measuring system's reading latched at ``t_s`` [s], noise included."""
        ...

    def brake(self, trigger_t_s: float) -> FloatArray:
        """React to the trigger at ``trigger_t_s`` [s] and brake to rest at the stop
        deceleration; returns the true ball centre (3,) [m] at rest."""
        ...

    def retract(self) -> None:
        """Move back off the surface to where the probing move began (or the machine's
        retract point)."""
        ...


@dataclass(frozen=True)
class ProbingOutcome(Generic[ReadingT]):
    """What one probing move gives.

    Attributes:
        trigger: the true touch and trigger (world frame), or None for a miss.
        reading: the latched measuring system at the trigger, or None for a miss.
        stop_centre: (3,) the true ball centre at rest after braking [m], or None for a miss.
    """

    trigger: Trigger | None
    reading: ReadingT | None
    stop_centre: FloatArray | None


class _PretravelDraw:
    """The pre-travel for the touch's motion direction: drawn once per touch (however many
    trigger checks it takes to reach the trigger), in the machine's probe frame."""

    def __init__(self, pretravel: PretravelModel, rng: np.random.Generator,
                 R_world_probe: Callable[[], FloatArray]):
        self.pretravel = pretravel
        self.rng = rng
        self.R_world_probe = R_world_probe
        self.delta_m: float | None = None

    def __call__(self, direction_world: FloatArray) -> float:
        if self.delta_m is None:
            u = direction_world @ self.R_world_probe()
            # A touch with the motion slightly away from the body (an equator touch while the
            # servo rises by micrometres) triggers sideways: the model's lateral law.
            u[2] = max(u[2], 0.0)
            self.delta_m = float(self.pretravel.draw_m(u / np.linalg.norm(u), self.rng))
        return self.delta_m


def _watch_for_trigger(machine: ProbingMachine[ReadingT], gap: GapFn, draw: _PretravelDraw) -> Trigger | None:
    """Advance chunk by chunk until the trigger or the line's end. The gap of each new chunk
    screens for the touch; from the touch on, the trigger is sought over the whole move."""
    lead_c, lead_t = machine.lead_in()
    centres: list[FloatArray] = [lead_c]
    times: list[FloatArray] = [lead_t]
    touched = False
    while True:
        c, t = machine.advance(machine.chunk_steps)
        if len(t) == 0:
            return None
        centres.append(c)
        times.append(t)
        if not touched:
            touched = bool(np.any(gap(c) <= 0))
        if touched:
            trigger = find_trigger(np.concatenate(times), np.vstack(centres), gap, draw)
            if trigger is not None:
                return trigger


def probing_move(machine: ProbingMachine[ReadingT], gap: GapFn, pretravel: PretravelModel,
                 rng: np.random.Generator) -> ProbingOutcome[ReadingT]:
    """One probing move (module docstring): the trigger, the latched reading, brake and retract.

    Args:
        machine: set up with its probing line.
        gap: the exact surface's gap for ball centres (machine world frame) [m].
        pretravel: the probe's pre-travel model; rng: its repeatability stream (one draw per touch).

    Returns:
        The outcome; a miss has no trigger, no reading and no stop centre.
    """
    trigger = _watch_for_trigger(machine, gap, _PretravelDraw(pretravel, rng, machine.R_world_probe))
    if trigger is None:
        machine.retract()
        return ProbingOutcome(None, None, None)
    reading = machine.latch(trigger.trigger_t_s)
    stop_centre = machine.brake(trigger.trigger_t_s)
    machine.retract()
    return ProbingOutcome(trigger, reading, stop_centre)


__all__ = ["GapFn", "ProbingMachine", "ProbingOutcome", "probing_move"]
