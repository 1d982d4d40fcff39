"""Restarts that leave a wrong minimum next to the right one: a converged local fit whose
residuals the given noise sigma cannot explain is started again a few standard deviations
along its weakest directions (:func:`escape_wrong_minimum`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from algorithms.arraytypes import FloatArray, Pose
from algorithms.geometry.se3 import exp_se3
from algorithms.registration.inputs import MIN_POINTS
from algorithms.registration.iteration_state import LocalFit
from algorithms.registration.uncertainty import OBSERVABILITY_TOL, observability

__all__ = [
    "ESCAPE_DIRECTIONS",
    "ESCAPE_MIN_GAIN",
    "ESCAPE_RMS_SIGMAS",
    "ESCAPE_ROUNDS",
    "ESCAPE_SIGMAS",
    "escape_wrong_minimum",
]

#: A converged fit above this RMS [sigma] may sit in a wrong minimum next to the right one.
ESCAPE_RMS_SIGMAS = 1.3
#: Restarts this many standard deviations either way along each weak direction.
ESCAPE_SIGMAS = 5.0
#: The number of weakest directions tried.
ESCAPE_DIRECTIONS = 2
#: A restart is taken when it lowers the sum of squares by more than this [sigma^2]: a
#: likelihood ratio no neighbouring minimum of a faceted distance comes near.
ESCAPE_MIN_GAIN = 25.0
#: At most this many restart rounds.
ESCAPE_ROUNDS = 3


def escape_wrong_minimum(fit: LocalFit, restart: Callable[[Pose], LocalFit], sigma_m: float) -> LocalFit:
    """Leave a wrong minimum next to the right one.

    A converged fit whose RMS exceeds ``ESCAPE_RMS_SIGMAS`` sigma is started again (``restart``,
    the same iteration from another T_world_workpiece) ``ESCAPE_SIGMAS`` standard deviations
    either way along its ``ESCAPE_DIRECTIONS`` weakest directions (face normals at its feet;
    consistent units, see :func:`observability`). It moves to the lowest minimum found when that
    keeps as many points and lowers the sum of squares by more than ``ESCAPE_MIN_GAIN`` sigma^2,
    and looks again from there (at most ``ESCAPE_ROUNDS`` rounds). The verdicts do not change:
    a fit still above the poor-fit limit is reported so. Unobservable fits are left as they are.

    Args:
        fit: a fit of the iteration.
        restart: the iteration from a given start pose.
        sigma_m: the given noise sigma [m].
    """
    for _ in range(ESCAPE_ROUNDS):
        better = _escape_round(fit, restart, sigma_m)
        if better is None:
            return fit
        fit = better
    return fit


def _escape_round(fit: LocalFit, restart: Callable[[Pose], LocalFit], sigma_m: float) -> LocalFit | None:
    """One round of restarts: the better fit it leads to, with the iterations, history and
    status of both, or None (no restart called for, or none better)."""
    if not fit.converged:
        return None
    sse, n_used = fit.sum_sq()
    if sse <= (ESCAPE_RMS_SIGMAS * sigma_m) ** 2 * n_used or n_used < MIN_POINTS:
        return None
    best = _lowest_restart(fit, restart, sigma_m, sse, n_used)
    if best is None:
        return None
    return replace(
        best,
        iterations=best.iterations + fit.iterations,
        history=fit.history + best.history,
        poses=fit.poses + best.poses,
        status=best.status + (f" (after a restart {ESCAPE_SIGMAS:g} standard deviations along a weak direction "
                              f"from a minimum of RMS {np.sqrt(sse / n_used):.3g} m)"),
    )


def _weak_steps(fit: LocalFit, sigma_m: float, n_used: int) -> FloatArray | None:
    """One standard deviation along each of the ``ESCAPE_DIRECTIONS`` weakest directions,
    sigma / sqrt(N w), as (k, 6) twists; None when the fit leaves directions free."""
    obs = observability(fit.cp.foot[fit.mask], fit.cp.normal[fit.mask], OBSERVABILITY_TOL)
    if not obs.observable:
        return None
    k = ESCAPE_DIRECTIONS
    return obs.determined_directions[:k] * (sigma_m / np.sqrt(n_used * obs.eigenvalues[:k]))[:, None]


def _lowest_restart(fit: LocalFit, restart: Callable[[Pose], LocalFit], sigma_m: float, sse: float,
                    n_used: int) -> LocalFit | None:
    """The converged restart with the lowest sum of squares, if it keeps at least ``n_used``
    points and gains more than ``ESCAPE_MIN_GAIN`` sigma^2 over ``sse``."""
    steps = _weak_steps(fit, sigma_m, n_used)
    if steps is None:
        return None
    best, best_sse = None, sse - ESCAPE_MIN_GAIN * sigma_m**2
    for xi in steps:
        for sign in (1.0, -1.0):
            trial = restart(fit.T @ exp_se3(sign * ESCAPE_SIGMAS * xi))
            sse_t, n_t = trial.sum_sq()
            if trial.converged and n_t >= n_used and sse_t < best_sse:
                best, best_sse = trial, sse_t
    return best
