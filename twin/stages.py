"""The one stage runner of the workflows: a workflow runs its stages by name, the runner keeps
each stage's wall time, and an error inside a stage ends the workflow with that stage named
(never guessed afterwards). The finished stages' records stay with the workflow, so a failed
run still writes its evidence and a report marked incomplete.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

from algorithms.errors import AlgorithmError
from twin.errors import TwinError


class StageFailed(TwinError):
    """A stage of a workflow could not finish; the workflow keeps what the earlier stages made."""

    def __init__(self, stage: str, reason: str):
        super().__init__(f"{stage}: {reason}")
        self.stage = stage
        self.reason = reason


@dataclass
class StageRunner:
    """Runs one workflow's stages.

    Attributes:
        timings_s: wall time per stage [s], keyed ``<stage>_s`` unless a stage names its key.
        failure: None while every stage finished, else (stage, reason) of the one that failed.
    """

    timings_s: dict[str, float] = field(default_factory=dict)
    failure: tuple[str, str] | None = None

    @contextmanager
    def within(self, name: str) -> Iterator[None]:
        """Run the ``with`` body as part of stage ``name``: a :class:`TwinError` or
        :class:`AlgorithmError` raised in it becomes :class:`StageFailed` naming this stage (one
        raised already keeps its own stage)."""
        try:
            yield
        except StageFailed:
            raise
        except (TwinError, AlgorithmError) as exc:
            raise StageFailed(name, str(exc)) from None

    @contextmanager
    def stage(self, name: str, timing: str | None = None) -> Iterator[None]:
        """:meth:`within`, and the body's wall time kept in ``timings_s[timing]`` (default
        ``f"{name}_s"``) when it finishes."""
        t0 = time.perf_counter()
        with self.within(name):
            yield
        self.timings_s[timing or f"{name}_s"] = time.perf_counter() - t0

    def run(self, stages: Callable[[], None]) -> None:
        """Run ``stages`` (a function running the workflow's stages in order); a stage that
        fails ends them and sets ``failure``."""
        try:
            stages()
        except StageFailed as exc:
            self.failure = (exc.stage, exc.reason)
