"""One trial of a study, whatever its kind: the pose trials (``fast``, ``full``, ``points``:
:mod:`twin.studies.trials`) and the normals trials (``normals``: :mod:`twin.studies.normal_trials`).

A trial is a pure function of (study, cell, trial) returning a flat dict of metrics; its
randomness comes only from ``np.random.SeedSequence(study.seed, spawn_key=(cell, trial))``.
"""

from __future__ import annotations

from twin.studies.full_trials import full_trial
from twin.studies.normal_trials import NORMALS_COLUMNS, normals_trial
from twin.studies.spec import Study
from twin.studies.trials import METRIC_COLUMNS, fast_trial, points_trial

TRIALS = {"fast": fast_trial, "full": full_trial, "points": points_trial, "normals": normals_trial}


def run_trial(study: Study, cell: int, trial: int) -> dict:
    """One trial: ``{"cell", "trial", *metric_columns(study.kind)}``."""
    return {"cell": int(cell), "trial": int(trial), **TRIALS[study.kind](study, cell, trial)}


def metric_columns(kind: str) -> tuple[str, ...]:
    """The metric columns of a trial of ``kind``, in order."""
    return NORMALS_COLUMNS if kind == "normals" else METRIC_COLUMNS
