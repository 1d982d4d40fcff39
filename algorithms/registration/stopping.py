"""How a step of the local iteration (:mod:`algorithms.registration.local`) ends: the trial
taken or refused, and the stopping rules (:func:`conclude`); after a stop, whether the
iteration goes on (:func:`go_on`: the feet were approximate, or the final outlier cut changes
the inliers)."""

from __future__ import annotations

import numpy as np

from algorithms.registration.iteration_state import Candidate, IterationSetup, IterationState, Settled, Trial
from algorithms.registration.robust import count, same_mask

__all__ = ["FALLBACK_MIN_SIGMAS", "RISE_REL", "conclude", "exact_feet", "floor_message", "go_on"]

#: An overshooting update whose fallback step moves the pose by less than this many standard
#: deviations ends the iteration, converged: it sits at a minimum of the faceted distance.
FALLBACK_MIN_SIGMAS = 0.1
#: A mean squared distance within this fraction above the last one counts as no rise.
RISE_REL = 1e-6


def floor_message(e: float) -> str:
    """The status of a stop at the numerical floor, ``e`` the mean squared distance [m^2]."""
    return f"converged: residual at the numerical floor (RMS {np.sqrt(e):.3g} m)"


def conclude(setup: IterationSetup, it: IterationState, outcome: Trial | Settled) -> bool:
    """Take the trial (or stop); True when a stopping rule ends the iteration."""
    if isinstance(outcome, Settled):
        return it.stop(True, outcome.message)
    e_new, e_prev = outcome.at.e, it.e_prev
    at_minimum = outcome.overshoot and e_new <= e_prev and _fallback_settles(setup, it, e_new)
    if not e_new <= e_prev:  # no decrease: keep the previous pose
        if e_new <= e_prev * (1.0 + RISE_REL):
            return it.stop(True, f"converged: no further decrease (1 - e_k/e_(k-1) = {1.0 - e_new / e_prev:.3g})")
        return it.stop(False, "not converged: stalled, no step along the update lowers the residual "
                              f"(1 - e_k/e_(k-1) = {1.0 - e_new / e_prev:.3g})")
    rel = 1.0 - e_new / e_prev if e_prev > 0 else 0.0
    mask_changed = _accept(setup, it, outcome.at)
    if it.e_prev <= setup.floor2:
        return it.stop(True, floor_message(it.e_prev))
    if mask_changed:
        return False
    if at_minimum:
        return it.stop(True, "converged: the update overshoots and the fallback step moves the pose by "
                             f"less than {FALLBACK_MIN_SIGMAS:g} of its standard deviation "
                             f"(1 - e_k/e_(k-1) = {rel:.3g})")
    if setup.method == "fine_001":
        step = outcome.step
        return step is not None and step < setup.tol and it.stop(
            True, f"converged: step sum dtheta^2 + sum dDelta^2 = {step:.3g} < d = {setup.tol:g}")
    return rel < setup.tol and it.stop(
        True, f"converged: relative decrease 1 - e_k/e_(k-1) = {rel:.3g} < delta = {setup.tol:g}")


def _fallback_settles(setup: IterationSetup, it: IterationState, e_new: float) -> bool:
    """Whether the fallback step after an overshooting update (mean squared distance ``e_new``)
    moves the pose by less than ``FALLBACK_MIN_SIGMAS`` of its standard deviation: at a minimum
    of the piecewise-smooth distance (feet on edges) the update overshoots and the shortened or
    point-to-point steps after it gain next to nothing, forever. A gain of g in the sum of
    squares moves the pose by sqrt(g) / sigma, sigma^2 ~ e_prev N / (N - 6)."""
    gain = (1.0 - e_new / it.e_prev) * max(count(it.mask, len(setup.Y)) - 6, 1)
    return gain < FALLBACK_MIN_SIGMAS**2


def _accept(setup: IterationSetup, it: IterationState, at: Candidate) -> bool:
    """Move to the candidate pose and apply the outlier rule there; True if the inliers changed."""
    it.n_updates += 1
    it.T, it.cp, it.Ym = at.T, at.cp, at.Ym
    it.history.append(float(np.sqrt(at.e)))
    it.poses.append(at.T)
    new_mask = setup.stages.mask(it.cp.distance)
    changed = not same_mask(new_mask, it.mask)
    it.mask = new_mask
    it.e_prev = setup.mse(it.cp, it.mask)
    return changed


def exact_feet(setup: IterationSetup, it: IterationState) -> None:
    """Replace approximate feet (far from the model) by exact ones at the current pose."""
    setup.feet.far = False
    it.cp, it.Ym = setup.feet(it.T, it.cp.face)
    it.mask = setup.stages.mask(it.cp.distance)


def go_on(setup: IterationSetup, it: IterationState, tighten: bool) -> bool:
    """Whether a stopped iteration goes on: it stopped on approximate feet (the iteration never
    stops on those), or it converged and the final outlier cut (``tighten``) changes the
    inliers."""
    if it.cp.rel_error > 0.0:
        exact_feet(setup, it)
        it.reopen(setup.mse(it.cp, it.mask))
        return True
    if it.converged and tighten and setup.stages.tighten():
        new_mask = setup.stages.mask(it.cp.distance)
        if not same_mask(new_mask, it.mask):
            it.mask = new_mask
            it.reopen(setup.mse(it.cp, it.mask))
            return True
    return False
