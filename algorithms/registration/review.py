"""The points a robust fit rejected, reviewed: outlier rejection may never be what makes a wrong
pose look right.

A local fit from a poor start can converge to a wrong pose where most points still lie on the
model and the few that would show the error are far from it: the outlier rule then rejects
exactly those, the remaining residual is consistent with the noise, and the fit check sees
nothing (document 000's workpiece A from 45 deg: the dome fits at a pose turned 90 deg about
its axis, and the side-face points that fix that rotation are rejected). What sets such points
apart from gross errors is not their count but what they would say about the pose, so the
review asks three questions of the rejected set R against the kept set K, at the fit's pose,
and a fourth of the fit itself:

1. **Would they matter?** The information the rejected points would carry if they were sound,
   against the kept points', in the direction where the ratio is largest:
   ``lambda = max eig(I_K^-1 I_R)``, ``I = sum g_i g_i^T`` over each set's rows
   ``g_i = [p_i x n_i, n_i]`` (feet and normals at the fit; the ratio does not depend on how
   the twist is scaled). Below ``REVIEW_INFORMATION`` the rejected points could not have
   changed which directions are determined and the fit stands as it is.
2. **Does another pose explain them?** A global search
   (:func:`algorithms.registration.global_search.global_localize`, Algorithm 5's multistart
   with the same sigma, outlier rule and local method) on every point. Its answer decides:

   * one of its poses is the fit's (not distinct, :func:`.global_search.verify.is_distinct`):
     **confirmed**; the fit keeps its verdict.
   * a trusted pose elsewhere that keeps more points: the fit was in a wrong minimum; the
     search's result is returned (``method`` the local method; the message says so), unless
     the points it rejects in turn cluster (:func:`clustering_ratio` below
     ``CLUSTER_RATIO``): then neither pose explains every feature (a mirrored part whose one
     asymmetric feature is all that tells the poses apart) and it is ``POOR_FIT``.
   * a trusted pose elsewhere that keeps as many points: two poses explain the points
     equally well: **AMBIGUOUS**, both in ``solutions``.
   * a pose elsewhere keeping fewer points: the search found nothing better; confirmed.
   * no trusted pose: **unconfirmed**; when the rejected points would carry at least
     ``LOAD_BEARING_INFORMATION`` of the kept points' information in some direction, an
     ``OK`` fit becomes ``POOR_FIT`` (its reason names the points and the direction).

3. **Is it a surface the model lacks?** Whatever the search found, a trusted answer whose
   rejected points form a coherent patch (:func:`coherent_fraction`: side by side, at similar
   distances from the model, as the points of a missing feature, a fixture or a mirrored part
   lie; spurious returns scatter in both) that would carry at least ``PATCH_INFORMATION`` of
   the kept points' information becomes ``POOR_FIT``, its reason naming the patch.

4. **Does the cost say what the covariance says?** (:func:`profile_checked`, on every fit that
   would be trusted) The covariance is a quadratic model of the sum of squares. Moved
   ``PROFILE_SIGMAS`` standard deviations along each determined coordinate (the others
   following as the covariance says they would: ``m = k C e_j / sqrt(C_jj)``), the model
   predicts a rise of the sum of squares of ``sum_i (g_i . xi)^2`` (``k^2 sigma^2`` over every
   point; taken on a regular subset of ``PROFILE_POINTS`` kept points, less the subset's own
   slope). Where either side rises by less than ``PROFILE_FRACTION`` of that, the points do
   not fix that direction as stated (a near-symmetry whose only hold is the tessellation or a
   few points at an edge, where the minimum wanders far beyond the stated deviation): it
   becomes free and the fit ``UNOBSERVABLE``, its covariance the other coordinates' given the
   freed ones (a Schur complement). Measured on the battery: the two weak partial views that
   were ``ok`` 0.53 deg and 0.58 mm off rise by 0.08 and 0.04 of the prediction, sound fits by
   0.94-1.0.

The review (questions 1-3, :func:`localize`) runs on fits that would be trusted, with the
outlier rule on and at least one point rejected; its outcome is the result's
``rejection_review``. The profile (question 4) runs on every fit that would be trusted. The
local module stays the documents' local fit and never calls it (the global search polishes
with it).
A pose whose kept points leave a direction free is already ``UNOBSERVABLE`` (its directions are
computed on the kept points), so "removing the rejected points changes which directions are
determined" is covered there. The symmetric pipeline (the loop's localization, from the
nominal pose) calls the local fit without the review. The false-alarm
rate of the rule on sound fits and its misses on wrong ones are measured by
``benchmarks/bench_verdicts.py`` (``benchmarks/results_verdicts.md``).
"""

from __future__ import annotations

import time
from dataclasses import fields, replace
from typing import TYPE_CHECKING

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray, Pose
from algorithms.geometry.se3 import exp_se3, inv_pose, rotation_error_rad, transform_points, translation_error_m
from algorithms.registration.inputs import finite_rows, mesh_index
from algorithms.registration.local import DEFAULT_METHOD
from algorithms.registration.local import localize as local_localize
from algorithms.registration.rejected import (
    LOAD_BEARING_INFORMATION,
    RejectedInformation,
    rejected_information,
)
from algorithms.registration.result import RegistrationResult, Status
from algorithms.registration.robust import OutlierConfig, outlier_config
from algorithms.registration.uncertainty import information_rows

if TYPE_CHECKING:
    import trimesh

    from algorithms.geometry.mesh_index import MeshIndex

__all__ = ["LOAD_BEARING_INFORMATION", "PROFILE_FRACTION", "PROFILE_SIGMAS", "REVIEW_INFORMATION",
           "RejectedInformation", "localize", "profile_checked", "rejected_information", "review_rejected"]

#: The rejected points are reviewed when, were they sound, they would add at least this
#: fraction of the kept points' information in some direction.
REVIEW_INFORMATION = 0.05
#: ... and a patch makes the fit a poor fit only when its points would carry at least this
#: fraction of the kept points' information: a table or fixture beyond the part's edges, seen
#: past a cube's sides, carries 0.05 and leaves the pose alone; the mirrored parts' 0.15.
PATCH_INFORMATION = 0.1
#: The profile of the cost (question 4) is taken this many standard deviations along each
#: determined coordinate, and must rise by at least ``PROFILE_FRACTION`` of the covariance's
#: prediction.
PROFILE_SIGMAS = 10.0
PROFILE_FRACTION = 0.25
#: The profile is taken on a regular subset of at most this many kept points, its prediction
#: from their own information rows.
PROFILE_POINTS = 500
#: Rejected points whose mean nearest-neighbour distance is below this fraction of that of as
#: many points drawn at random from all cluster (a feature, not scattered gross errors).
CLUSTER_RATIO = 0.5
#: Random draws of the clustering ratio's reference.
CLUSTER_DRAWS = 20
#: The global search's random stream (the review is deterministic).
REVIEW_SEED = 0


def localize(points: ArrayLike, mesh: trimesh.Trimesh | None = None, method: str = DEFAULT_METHOD,
             init: ArrayLike | None = None, sigma: float | None = None, max_iterations: int | None = None,
             tolerance: float | None = None, outlier: OutlierConfig = "mad",
             index: MeshIndex | None = None, variant: str = "ours") -> RegistrationResult:
    """:func:`algorithms.registration.local.localize` (same arguments, same result), its
    rejected points reviewed when it would be trusted (module docstring): the localization
    ``algorithms.registration.localize`` and ``twin localize`` give. The local fit alone, as
    the documents print it, stays :func:`algorithms.registration.local.localize`."""
    t_start = time.perf_counter()
    index = mesh_index(mesh, index)
    result = local_localize(points, method=method, init=init, sigma=sigma, max_iterations=max_iterations,
                            tolerance=tolerance, outlier=outlier, index=index, variant=variant)
    if not result.trusted:
        return result
    cfg = None if variant == "printed" else outlier_config(outlier)
    P, rows = finite_rows(points)
    if cfg is not None and result.n_outliers > 0:
        result = review_rejected(result, P[rows], rows, index, sigma=sigma, outlier_cfg=cfg, method=method)
    # time_s: the whole call, the review's global search included
    return replace(profile_checked(result, P[rows], rows, index), time_s=time.perf_counter() - t_start)


def profile_checked(result: RegistrationResult, Y: FloatArray, rows: np.ndarray,
                    index: MeshIndex) -> RegistrationResult:
    """The fit with every determined coordinate whose cost profile is flat made free (module
    docstring, question 4); unchanged when every coordinate holds or the fit is not trusted.

    Args:
        result: a fit (its ``inliers`` over the input rows).
        Y: (M, 3) the finite points it used, world frame [m]; ``rows``: their input rows.
        index: the model's mesh index.
    """
    C = None if result.covariance is None else np.asarray(result.covariance, dtype=np.float64)
    if not result.trusted or C is None or len(C) == 0 or not result.sigma_m > 0:
        return result
    D = np.asarray(result.determined_directions, dtype=np.float64)
    X = Y[result.inliers[rows]]
    X = X[:: max(1, -(-len(X) // PROFILE_POINTS))]   # a regular subset: the ratio needs no more
    T = result.T_world_workpiece
    Xm = transform_points(inv_pose(T), X)
    cp = index.query(Xm)
    rows_info = information_rows(cp.foot, cp.normal)
    signed = np.einsum("ij,ij->i", Xm - cp.foot, cp.normal)

    def ssq(T_moved: Pose) -> float:
        return float(np.sum(index.query(transform_points(inv_pose(T_moved), X)).distance ** 2))

    base, k = float(np.sum(cp.distance**2)), PROFILE_SIGMAS
    rises = []
    for j in range(len(C)):
        twist = (k * C[:, j] / np.sqrt(C[j, j])) @ D
        along = rows_info @ twist
        predicted = float(np.sum(along**2))
        # the subset's own slope taken out (zero at the minimum of all the points, not of a subset)
        slope = -2.0 * float(np.sum(signed * along))
        rise = min(ssq(T @ exp_se3(sign * twist)) - base - sign * slope for sign in (1.0, -1.0))
        rises.append(rise / max(predicted, 1e-300))
    flat = [j for j, r in enumerate(rises) if r < PROFILE_FRACTION]
    if not flat:
        return result
    keep = [j for j in range(len(C)) if j not in flat]
    freed = C[:, flat].T @ D
    freed /= np.linalg.norm(freed, axis=1, keepdims=True)
    # the kept coordinates' covariance given the freed ones (the Schur complement)
    C_kept = C[np.ix_(keep, keep)] \
        - C[np.ix_(keep, flat)] @ np.linalg.solve(C[np.ix_(flat, flat)], C[np.ix_(flat, keep)])
    words = "; ".join(f"[{', '.join(f'{v:+.2f}' for v in freed[i])}] rises {rises[j]:.2g} x"
                      for i, j in enumerate(flat))
    note = (f"unobservable: the sum of squares {k:g} standard deviations along {len(flat)} direction(s) rises by less "
            f"than {PROFILE_FRACTION:g} of what the covariance predicts (twists [omega, v]: {words}): the points do "
            "not fix them as stated")
    return replace(result, status=Status.UNOBSERVABLE, message=f"{note}; {result.message}",
                   determined_directions=D[keep], covariance=C_kept,
                   free_directions=np.vstack([np.asarray(result.free_directions, dtype=np.float64).reshape(-1, 6),
                                              freed]))


def clustering_ratio(X: FloatArray, rejected: np.ndarray) -> float:
    """The rejected points' mean nearest-neighbour distance over its mean for as many points
    drawn at random from all of ``X`` (``CLUSTER_DRAWS`` draws, a fixed seed): about 1 for
    scattered gross errors, well below for the points of one feature; inf for fewer than 3."""
    m = int(rejected.sum())
    if m < 3 or m >= len(X):
        return float("inf")
    from scipy.spatial import cKDTree

    def mean_nn(P: FloatArray) -> float:
        return float(cKDTree(P).query(P, k=2)[0][:, 1].mean())

    rng = np.random.default_rng(REVIEW_SEED)
    reference = np.mean([mean_nn(X[rng.choice(len(X), m, replace=False)]) for _ in range(CLUSTER_DRAWS)])
    return mean_nn(X[rejected]) / max(float(reference), 1e-300)


def review_rejected(result: RegistrationResult, Y: FloatArray, rows: np.ndarray, index: MeshIndex, *,
                    sigma: float | None, outlier_cfg: OutlierConfig, method: str) -> RegistrationResult:
    """The fit after the review of its rejected points (module docstring): the global search's
    answer (:func:`_searched`), then not trusted while the model leaves a coherent patch of
    points unexplained."""
    info = rejected_information(Y, result.inliers[rows], result.T_world_workpiece, index)
    if info.n_rejected == 0 or info.ratio < REVIEW_INFORMATION:
        return result
    reviewed = _searched(result, info, Y, rows, index, sigma=sigma, outlier_cfg=outlier_cfg, method=method)
    if reviewed.T_world_workpiece is not result.T_world_workpiece:
        info = rejected_information(Y, reviewed.inliers[rows], reviewed.T_world_workpiece, index)
        X = transform_points(inv_pose(reviewed.T_world_workpiece), Y)
        ratio = clustering_ratio(X, ~reviewed.inliers[rows])
        if reviewed.trusted and ratio < CLUSTER_RATIO:
            reason = (f"the pose the search found leaves {info.n_rejected} point(s) unexplained that cluster (their "
                      f"mean nearest-neighbour distance is {ratio:.2f} of that of as many random points): neither "
                      "pose explains every feature (a mirrored or another part?)")
            return replace(reviewed, status=Status.POOR_FIT, poor_fit_reason=reason,
                           message=f"{reviewed.message}; poor fit: {reason}")
    if reviewed.trusted and info.patch and info.ratio >= PATCH_INFORMATION:
        reason = (f"the model leaves a coherent patch unexplained: {_rejected_words(info)}, "
                  f"{info.coherent_fraction:.0%} of them side by side at similar distances "
                  "(a feature the model lacks, a fixture, or another part)")
        return replace(reviewed, status=Status.POOR_FIT, poor_fit_reason=reason,
                       message=f"{reviewed.message}; poor fit: {reason}")
    return reviewed


def _searched(result: RegistrationResult, info: RejectedInformation, Y: FloatArray, rows: np.ndarray,
              index: MeshIndex, *,
              sigma: float | None, outlier_cfg: OutlierConfig, method: str) -> RegistrationResult:
    """The global search's answer on the fit (module docstring, question 2).

    Args:
        result: the local fit (its ``inliers`` over the input rows); info: its rejected points.
        Y: (M, 3) the finite points it used, world frame [m]; ``rows``: their input rows.
        index: the model's mesh index.
        sigma: the given noise sigma [m] or None; outlier_cfg: the checked outlier rule.
        method: the local method (the global search polishes with it).
    """
    # here, not at the top: a fit whose rejected points need no review never loads the search
    from algorithms.registration.global_search import global_localize
    from algorithms.registration.global_search.verify import is_distinct

    found = global_localize(Y, _trimesh_of(index), index=index, noise_sigma_m=sigma, outlier=outlier_cfg,
                            polish=method, rng=np.random.default_rng(REVIEW_SEED))
    T = result.T_world_workpiece
    what = _rejected_words(info)
    if any(not is_distinct(S, T, index.extent) for S in found.solutions):
        return replace(result, rejection_review=f"confirmed: {what}; a global search found this pose too")
    away = (f"{np.degrees(rotation_error_rad(found.T_world_workpiece, T)):.3g} deg / "
            f"{1e3 * translation_error_m(found.T_world_workpiece, T):.3g} mm away")
    if found.status in (Status.OK, Status.AMBIGUOUS) and found.n_points_used > result.n_points_used:
        note = (f"wrong minimum: {what} at the pose from the start; a global search found a pose {away} "
                f"that keeps {found.n_points_used - result.n_points_used} more point(s)")
        base = {f.name: getattr(found, f.name) for f in fields(RegistrationResult)}
        inliers = np.zeros(len(result.inliers), dtype=bool)  # over the input rows, as the fit's
        inliers[rows] = found.inliers
        base.update(method=method, message=f"{note}; {found.message}", rejection_review=note, inliers=inliers,
                    n_dropped_nonfinite=result.n_dropped_nonfinite, time_s=result.time_s + found.time_s)
        return RegistrationResult(**base)
    if found.trusted and found.n_points_used == result.n_points_used and result.trusted:
        note = f"ambiguous: {what}; a global search found another pose {away} that keeps as many points"
        return replace(result, status=Status.AMBIGUOUS, message=f"{note}; {result.message}", rejection_review=note,
                       solutions=(T, found.T_world_workpiece))
    if found.status in (Status.OK, Status.AMBIGUOUS):
        return replace(result, rejection_review=f"confirmed: {what}; a global search found no pose that keeps more "
                                                f"points (its best, {away}, keeps {found.n_points_used})")
    note = f"unconfirmed: {what}; a global search found no trusted pose ({found.status.value})"
    if result.trusted and info.ratio >= LOAD_BEARING_INFORMATION:
        reason = f"the outlier rule {what}, and {note.split('; ', 1)[1]}"
        return replace(result, status=Status.POOR_FIT, poor_fit_reason=reason,
                       message=f"{result.message}; poor fit: {reason}", rejection_review=note)
    return replace(result, rejection_review=note)


def _rejected_words(info: RejectedInformation) -> str:
    """"rejected N points (near x, y, z mm) that would carry R x the kept points' information
    along [omega; v]"."""
    c = ", ".join(f"{1e3 * v:.1f}" for v in info.centroid_m)
    u = ", ".join(f"{v:+.2f}" for v in info.direction)
    ratio = "more than all" if not np.isfinite(info.ratio) else f"{info.ratio:.2g} x"
    return (f"rejected {info.n_rejected} point(s) (around [{c}] mm, workpiece frame) that would carry {ratio} "
            f"the kept points' information along the twist [{u}]")


def _trimesh_of(index: MeshIndex):
    """The index's mesh as a trimesh (the global search's coarse field samples its surface)."""
    import trimesh

    mesh = index.mesh
    if isinstance(mesh, trimesh.Trimesh):
        return mesh
    return trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False)
