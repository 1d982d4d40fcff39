"""The library's front door for notebooks and scripts: a scenario or study file in, the
workflow's result out, nothing written (except by :func:`study`, which writes its folder).

    import twin
    result = twin.run("scenarios/s_surface.toml")          # the laser loop (RunResult)
    located = twin.locate("scenarios/locate_s_surface.toml")  # document 001 (LocateResult)
    summary = twin.study("studies/sensor_sigma.toml", "out/sensor_sigma", workers=2)

Each is the same call the ``twin`` command makes; the stage functions stay importable from
their modules (:mod:`twin.workflows`, :mod:`twin.process_paths`, ...) for finer control.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from twin.scenario import Scenario
    from twin.workflows.locate import LocateResult
    from twin.workflows.loop import RunResult

Say = Callable[[str], None]


def _scenario(scenario: str | Path | Scenario, overrides: dict | None, machine: str | None = None) -> Scenario:
    from twin.scenario import Scenario, load_scenario

    if isinstance(scenario, Scenario):
        if overrides:
            raise TypeError("overrides apply to a scenario file; got a Scenario object")
        return scenario
    return load_scenario(scenario, overrides, machine)


def run(scenario: str | Path | Scenario, *, overrides: dict | None = None, strict: bool = False,
        say: Say | None = None) -> RunResult:
    """The laser loop on a scenario (its TOML path, or a loaded :class:`twin.scenario.Scenario`):
    scan, localize, process paths, IK, replay (:func:`twin.workflows.loop.run`).

    Args:
        scenario: the scenario file or object.
        overrides: nested tables merged over the file before validation
            (``{"noise": {"gaussian": False}}``).
        strict: a path stretch that cannot be processed fails the run instead of being dropped.
        say: receives one progress line per stage (default: silent).

    Returns:
        The frozen :class:`twin.workflows.loop.RunResult` (``failure`` names a failed stage).
    """
    from twin.realize import realize
    from twin.workflows import loop

    return loop.run(realize(_scenario(scenario, overrides)), say=say or (lambda msg: None), strict=strict)


def locate(scenario: str | Path | Scenario, *, overrides: dict | None = None, coarse: str | None = None,
           points: int | None = None, planner: str | None = None, say: Say | None = None) -> LocateResult:
    """Document 001's locate-then-machine on a scenario with a ``[probe]`` table
    (:func:`twin.workflows.locate.locate`); ``coarse``, ``points`` and ``planner`` override the
    scenario's ``locate.coarse``, ``probe.points`` and ``locate.planner``."""
    from twin.realize import realize
    from twin.workflows.locate import locate as locate_workflow

    return locate_workflow(realize(_scenario(scenario, overrides)), say=say or (lambda msg: None), coarse=coarse,
                           points=points, planner=planner)


def study(study_file: str | Path, out: str | Path, *, workers: int = 1, scheduler: str = "local",
          resume: bool = False, force: bool = False) -> dict:
    """Run a Monte Carlo / benchmark study file into the folder ``out``
    (:func:`twin.studies.runner.run_study`): ``results.parquet`` and ``report.md``, the same
    rows whatever ``workers`` or ``scheduler`` (``local``, ``dask`` or ``tcp://HOST:PORT``).
    Returns the summary the ``twin study`` command prints."""
    from twin.studies.runner import run_study
    from twin.studies.spec import load_study

    return run_study(load_study(study_file), Path(out), workers=workers, scheduler=scheduler, resume=resume,
                     force=force)
