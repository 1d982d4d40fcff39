"""Hypothesis verification of a global search: distinct candidates, the residual test, ambiguity.

The best pose is trusted only if its RMS residual is consistent with the noise
(``rms <= 2 sigma_eff``) and the points constrain all six degrees of freedom
(:func:`algorithms.registration.uncertainty.observability` with smooth normals). The best is
compared with the other *distinct* solutions found (rotation differing by more than 2 degrees
or translation by more than 1 % of the part's size, refined with exact closest points on the
same points): a distinct pose whose residual is lower by more than the noise can explain
means the search ended in a local minimum (``Status.FAILED``); a best pose whose residual the
noise cannot explain is a poor fit (``Status.POOR_FIT``: points of another part, or no start
reached the pose); one that is statistically indistinguishable
(``|eps_2 - eps_1| <= 2 chi2_0.999(6) sigma_eff^2``, about 45 sigma_eff^2) makes the result
*ambiguous* (``Status.AMBIGUOUS``): ``solutions`` lists the equally good poses. A symmetric
or near-symmetric part is therefore never reported as a confident unique success.

The distinct solutions come from the multistart's coarse minima (for ``"genetic"`` and
``"pso"`` too: the coarse multistart phase runs for them as pre-registration or as this
check), at most ``max_candidates`` of them, refined on ``n_verify`` points (screened: a
candidate still in a clearly worse basin after SCREEN_ITERATIONS steps is not refined
further). Besides, every rigid motion ``S`` that maps the model onto itself
(:func:`algorithms.registration.symmetric.model_symmetries`: a cube's 24 rotations, a block's
half turns) gives the pose ``T S``, which fits any points exactly as well as ``T``: those
poses join ``solutions`` (when their residual on the verification points agrees), so a part
with a discrete symmetry lists every equally good pose, not only those the search happened to
visit.

Outliers: the verification uses the points the polish kept as inliers (the robust rule of
:mod:`algorithms.registration.robust`); when some verification points are outliers, the
candidates are refined again on the inliers alone.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np

from algorithms.arraytypes import FloatArray, IntArray, Pose
from algorithms.geometry.se3 import rotation_error_rad, translation_error_m
from algorithms.registration.global_search.fields import NearestSurface
from algorithms.registration.global_search.multistart import NOISE_ACCEPT_FACTOR, LaneResult, descend
from algorithms.registration.result import Status
from algorithms.registration.symmetric.discrete import model_symmetries

__all__ = [
    "AMBIGUITY_CHI2",
    "DISTINCT_ROTATION_RAD",
    "DISTINCT_TRANSLATION_FRAC",
    "Verdict",
    "distinct",
    "is_distinct",
    "refine_candidates",
    "symmetries_of",
    "verify",
]

#: 2 * chi-square 0.999 quantile with 6 DOF: two fits of the same points whose eps differ by
#: less than this many sigma^2 cannot be told apart.
AMBIGUITY_CHI2 = 2.0 * 22.4577
DISTINCT_ROTATION_RAD = math.radians(2.0)
DISTINCT_TRANSLATION_FRAC = 0.01


def distinct(Ts: FloatArray, order: IntArray, size: float, k: int) -> list[int]:
    """Greedy: indices (in ``order``) of up to k mutually distinct poses of Ts (B, 4, 4);
    ``size`` [m] scales the translation test."""
    picked: list[int] = []
    for i in order:
        ok = True
        for j in picked:
            if (
                rotation_error_rad(Ts[i], Ts[j]) < DISTINCT_ROTATION_RAD
                and translation_error_m(Ts[i], Ts[j]) < DISTINCT_TRANSLATION_FRAC * size
            ):
                ok = False
                break
        if ok:
            picked.append(int(i))
            if len(picked) >= k:
                break
    return picked


def is_distinct(A: Pose, B: Pose, size: float) -> bool:
    """Whether two poses differ by DISTINCT_ROTATION_RAD or DISTINCT_TRANSLATION_FRAC x size [m]."""
    return (
        rotation_error_rad(A, B) >= DISTINCT_ROTATION_RAD
        or translation_error_m(A, B) >= DISTINCT_TRANSLATION_FRAC * size
    )


def refine_candidates(exact: NearestSurface, y_v: FloatArray, primary: Pose | None, lanes: LaneResult,
                      extent: float, max_candidates: int, L: float) -> tuple[FloatArray, FloatArray]:
    """The method's own pose (``primary``, or None) and the best distinct coarse minima,
    refined with exact closest points on the verification points ``y_v``.

    Returns:
        ((K, 4, 4) refined poses, (K,) their eps, the sum of squared distances [m^2]).
    """
    cand: list[Pose] = []
    if primary is not None:
        cand.append(primary)
    order = np.argsort(lanes.eps)
    pick = distinct(lanes.T, order, extent, int(max_candidates))
    cand.extend(lanes.T[i] for i in pick)
    cand_T = np.asarray(cand)
    keep = distinct(cand_T, np.arange(len(cand_T)), extent, len(cand_T))
    return refine(exact, y_v, cand_T[keep], L)


#: Exact refinement: at most REFINE_ITERATIONS Gauss-Newton steps per candidate; after the
#: first SCREEN_ITERATIONS, a candidate whose RMS residual is still above SCREEN_RMS_FACTOR x
#: the best's plus SCREEN_RMS_FRAC x L (a wrong basin: millimetres against micrometres) stops
#: there, since it cannot come near the best; the others go on.
REFINE_ITERATIONS = 15
SCREEN_ITERATIONS = 3
SCREEN_RMS_FACTOR = 2.0
SCREEN_RMS_FRAC = 1e-3


def refine(exact: NearestSurface, y_v: FloatArray, T: FloatArray, L: float) -> tuple[FloatArray, FloatArray]:
    """A short exact descent from each pose of T (B, 4, 4) on the points y_v (n, 3) [m]
    (screened: see REFINE_ITERATIONS).

    Returns:
        ((B, 4, 4) refined poses, (B,) their eps [m^2]).
    """

    def run(T0: FloatArray, iterations: int) -> LaneResult:
        return descend(exact, y_v, T0, L=L, delta1=1e-6, delta2=np.inf, delta3=1e-7,
                       max_iter_per_descent=iterations, rng=None)

    ref = run(T, SCREEN_ITERATIONS)
    T_out, eps = ref.T.copy(), ref.eps.copy()
    rms = np.sqrt(eps / len(y_v))
    go_on = (ref.iterations >= SCREEN_ITERATIONS) & (rms <= SCREEN_RMS_FACTOR * rms.min() + SCREEN_RMS_FRAC * L)
    if go_on.any():
        more = run(T_out[go_on], REFINE_ITERATIONS - SCREEN_ITERATIONS)
        better = more.eps < eps[go_on]
        idx = np.flatnonzero(go_on)[better]
        T_out[idx], eps[idx] = more.T[better], more.eps[better]
    return T_out, eps


_SYMMETRY_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def symmetries_of(index: Any) -> FloatArray:
    """The model's symmetries (K, 4, 4) (identity first), cached per mesh index."""
    try:
        S = _SYMMETRY_CACHE.get(index)
    except TypeError:
        S = None
    if S is None:
        S = model_symmetries(index.mesh, index=index)
        try:
            _SYMMETRY_CACHE[index] = S
        except TypeError:
            pass
    return S


@dataclass(frozen=True)
class Verdict:
    """The outcome of :func:`verify`.

    Attributes:
        status: FAILED, AMBIGUOUS, UNOBSERVABLE or OK.
        message: the verdict in words.
        solutions: the equally good poses, the result first.
        candidates: ``(T, rms_m)`` of the distinct minima, the result first.
        sigma_eff_m: the effective noise sigma used [m] (estimated when not given).
        rms_m: the result's RMS residual on the verification points [m].
        n_points: verification points used.
    """

    status: Status
    message: str
    solutions: tuple[Pose, ...]
    candidates: tuple[tuple[Pose, float], ...]
    sigma_eff_m: float
    rms_m: float
    n_points: int


@dataclass(frozen=True)
class _ResultFit:
    """The result's fit on the verification points and the tests' thresholds."""

    eps: float  # [m^2] sum of squared distances
    rms_m: float
    sigma_eff_m: float
    threshold: float  # [m^2] eps differences within it cannot be told apart
    n_points: int


def verify(index: Any, y_v: FloatArray, T_final: Pose, refined_T: FloatArray, refined_eps: FloatArray, *,
           extent: float, sig_eff: float | None, model_error_m: float, method: str, observable: bool,
           polish_message: str, symmetries: FloatArray) -> Verdict:
    """Compare the result with the other distinct minima and the model's symmetric poses.

    Args:
        index: the model's MeshIndex.
        y_v: (n, 3) [m] verification points (inliers), world frame.
        T_final: (4, 4) the result.
        refined_T, refined_eps: (K, 4, 4) the refined candidates and (K,) their eps [m^2] on ``y_v``.
        extent: the model's size [m].
        sig_eff: the effective noise sigma [m], or None (estimated from the result's residual).
        model_error_m: allowance for model error [m] (added in quadrature when estimating).
        method: the global method's name (for the message).
        observable: whether the polish found every direction fixed.
        polish_message: the polish's message (for an unobservable verdict).
        symmetries: (K, 4, 4) the model's symmetries, identity first.
    """
    fit = _result_fit(index, y_v, T_final, sig_eff, model_error_m)
    others = _distinct_others(refined_T, refined_eps, T_final, extent)
    equivalent = [T_final] + [T for e, T in others if abs(e - fit.eps) <= fit.threshold]
    better = [T for e, T in others if e < fit.eps - fit.threshold]
    candidates = [(T_final, fit.rms_m)] + [(T, math.sqrt(e / fit.n_points)) for e, T in others]
    _add_symmetric_poses(index, y_v, T_final, symmetries, extent, fit, equivalent, candidates)
    status, message = _verdict(fit, others, len(equivalent), bool(better), method, observable, polish_message)
    return Verdict(status, message, tuple(equivalent), tuple(candidates), fit.sigma_eff_m, fit.rms_m, fit.n_points)


def _eps_at(index: Any, y: FloatArray, T: Pose) -> float:
    """[m^2] the sum of squared exact distances of the points y (n, 3) [m] from the model at T."""
    x = (y - T[:3, 3]) @ T[:3, :3]
    return float(np.sum(index.query(x).distance ** 2))


def _result_fit(index: Any, y_v: FloatArray, T_final: Pose, sig_eff: float | None,
                model_error_m: float) -> _ResultFit:
    eps_final = _eps_at(index, y_v, T_final)
    nv = len(y_v)
    if sig_eff is None:
        sig_eff = math.hypot(math.sqrt(eps_final / max(nv - 6, 1)), model_error_m)
    return _ResultFit(eps_final, math.sqrt(eps_final / nv), sig_eff, AMBIGUITY_CHI2 * sig_eff**2, nv)


def _distinct_others(refined_T: FloatArray, refined_eps: FloatArray, T_final: Pose,
                     extent: float) -> list[tuple[float, Pose]]:
    """``(eps, T)`` of the refined candidates distinct from the result and from each other
    (refinement can merge coarse minima), best first."""
    others: list[tuple[float, Pose]] = []
    for i in np.argsort(refined_eps):
        T, e = refined_T[i], float(refined_eps[i])
        if np.isfinite(e) and is_distinct(T, T_final, extent) and all(
            is_distinct(T, To, extent) for _, To in others
        ):
            others.append((e, T))
    return others


def _add_symmetric_poses(index: Any, y_v: FloatArray, T_final: Pose, symmetries: FloatArray, extent: float,
                         fit: _ResultFit, equivalent: list[Pose], candidates: list[tuple[Pose, float]]) -> None:
    """The model's symmetries S: ``T S`` fits every point as T does; those distinct from the
    equivalent poses and within the threshold join ``equivalent`` and ``candidates``."""
    for S in symmetries[1:]:
        T = T_final @ S
        if all(is_distinct(T, Te, extent) for Te in equivalent):
            e = _eps_at(index, y_v, T)
            if abs(e - fit.eps) <= fit.threshold:
                equivalent.append(T)
                candidates.append((T, math.sqrt(e / fit.n_points)))


def _verdict(fit: _ResultFit, others: list[tuple[float, Pose]], n_equivalent: int, better: bool, method: str,
             observable: bool, polish_message: str) -> tuple[Status, str]:
    """FAILED (a distinct pose fits better), POOR_FIT (the noise does not explain the
    residual), AMBIGUOUS, UNOBSERVABLE or OK, and the message."""
    nv, sig_eff, rms_final = fit.n_points, fit.sigma_eff_m, fit.rms_m
    if better:
        return Status.FAILED, (
            f"failed: a distinct pose fits better (rms {math.sqrt(others[0][0] / nv):.3g} m vs "
            f"{rms_final:.3g} m): the {method} search ended in a local minimum"
        )
    if not rms_final <= NOISE_ACCEPT_FACTOR * sig_eff:
        return Status.POOR_FIT, (
            f"poor fit: rms residual {rms_final:.3g} m is above {NOISE_ACCEPT_FACTOR:g} x the expected "
            f"noise {sig_eff:.3g} m: the points are not of this part (or no start reached the true pose)"
        )
    if n_equivalent > 1:
        return Status.AMBIGUOUS, (
            f"ambiguous: {n_equivalent} distinct poses fit equally well (rms within the noise "
            f"{sig_eff:.3g} m): the part is symmetric for these points; solutions lists them"
        )
    if not observable:
        return Status.UNOBSERVABLE, "unobservable: " + polish_message.split(":", 1)[-1].strip()
    return Status.OK, (
        f"ok: unique pose, rms {rms_final:.3g} m consistent with the noise {sig_eff:.3g} m; "
        "second-best distinct pose rms "
        + (f"{math.sqrt(others[0][0] / nv):.3g} m" if others else "none found")
    )
