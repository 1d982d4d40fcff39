"""Tool axes tilted within a cone so that the shank and holder clear the part.

A ball-end tool touches the surface at the same point whatever its axis, as long as the axis
passes through the ball's centre ``c + r n`` (contact ``c``, outward normal ``n``, ball radius
``r``). Where the axis along the normal (document 003's eq. 11) would bring the shank or the
holder too close to the part (the far wall of a cavity, a flank below an overhang), the axis
may tilt from the normal by up to ``max_tilt_rad`` about the ball's centre.

:func:`clear_axes` picks, for each contact point whose normal axis is not clear, the
smallest tilt (in ``levels`` steps up to the limit) at which it is, preferring, at equal
tilt, the direction towards ``up`` (the part's +z: away from the table), then the others of
``azimuths`` directions around the normal. Along each line the tilts are then spread over a
window (a point next to a tilted one tilts as far, and the tilt ramps in and out over the
window) so the axis turns smoothly for the arm. A point where no axis in the cone is clear gets
no tilt of its own (the spread may lend it a neighbour's); the caller's clearance check drops
it if it is still not clear.

A tilted shank's foot (from the ball's equator to the first profile sample) stays as near a
wall as the ball is, while the samples above lean clear of it: :func:`foot_gap_m` checks it
(``min_foot_gap_m``).

The same freedom serves the arm: where it cannot follow the axes (a wrist that would jump
where the normal turns fast, a pose out of reach), :func:`steer_axes` re-chooses the axes
around the trouble within the cone, for the lowest cost the caller measures on the arm (the
twin: its largest joint step on the closed-form IK), the tool kept clear.

What the tilt gains on the example parts: ``benchmarks/results_history_symmetric_paths.md``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.ndimage import uniform_filter1d

from algorithms.arraytypes import ArrayLike, FloatArray


@dataclass(frozen=True)
class ToolProfile:
    """The tool above its ball, for clearance checks: the distances [m] from the ball's centre
    up the axis at which it is sampled (every ``step_m`` from ``tip_radius_m + step_m``), the
    tool's radius [m] at each, and the shank's radius [m] (for the shank's foot, below the
    first sample: :func:`foot_gap_m`)."""

    distance_m: FloatArray
    radius_m: FloatArray
    tip_radius_m: float
    shank_radius_m: float
    step_m: float


def tool_profile(reach_m: float, tip_radius_m: float, shank_radius_m: float, holder_radius_m: float,
                 holder_length_m: float, step_m: float) -> ToolProfile:
    """Samples every ``step_m`` from just above the ball to ``reach_m`` (the flange's distance
    from the ball's centre), the holder's radius over its last ``holder_length_m``."""
    s = np.arange(tip_radius_m + step_m, reach_m, step_m)
    r = np.where(s > reach_m - holder_length_m, max(holder_radius_m, shank_radius_m), shank_radius_m)
    return ToolProfile(s, r, tip_radius_m, shank_radius_m, step_m)


#: With a limit, the tool's profile is first computed every this many samples (profile_gaps_m).
PROFILE_STRIDE = 8


def profile_gaps_m(centres: FloatArray, axes: FloatArray, profile: ToolProfile,
                   signed_distance: Callable[[FloatArray], FloatArray], limit_m: float | None = None) -> FloatArray:
    """(N, S) gap [m] between the part and the tool at each profile sample (along ``axes``
    from the ball ``centres``).

    With ``limit_m`` only the gaps under it are exact; the others are lower bounds of at least
    ``limit_m`` (each row's minimum is exact wherever it is under the limit). The signed
    distance is 1-Lipschitz, so the exact distances every ``PROFILE_STRIDE`` samples up the
    axis bound the samples between them (``d(s) >= d(s0) - |s - s0|``), and only the samples
    whose bound falls under the limit are computed: most of a tool far from the part is not.
    """
    n_poses, n_samples = len(centres), len(profile.distance_m)
    samples = centres[:, None, :] + profile.distance_m[None, :, None] * axes[:, None, :]
    radius = profile.radius_m[None, :]
    if limit_m is None or n_samples <= PROFILE_STRIDE:
        return signed_distance(samples.reshape(-1, 3)).reshape(n_poses, n_samples) - radius
    strided = np.unique(np.r_[np.arange(0, n_samples, PROFILE_STRIDE), n_samples - 1])
    exact = signed_distance(samples[:, strided].reshape(-1, 3)).reshape(n_poses, len(strided))
    at = np.clip(np.searchsorted(strided, np.arange(n_samples) - PROFILE_STRIDE // 2), 0, len(strided) - 1)
    apart = np.abs(profile.distance_m - profile.distance_m[strided[at]])
    gaps = exact[:, at] - apart[None, :] - radius - 1e-12
    gaps[:, strided] = exact - radius[:, strided]
    todo = gaps < limit_m
    todo[:, strided] = False
    rows, cols = np.nonzero(todo)
    if len(rows):
        gaps[rows, cols] = signed_distance(samples[rows, cols]) - profile.radius_m[cols]
    return gaps


def clearance_m(centres: FloatArray, axes: FloatArray, profile: ToolProfile,
                signed_distance: Callable[[FloatArray], FloatArray], limit_m: float | None = None) -> FloatArray:
    """(N,) smallest gap [m] between the tool (along ``axes`` from the ball ``centres``) and the
    part; with ``limit_m`` exact where it is under the limit, else a value of at least the limit."""
    if len(centres) == 0 or len(profile.distance_m) == 0:
        return np.full(len(centres), np.inf)
    return np.min(profile_gaps_m(centres, axes, profile, signed_distance, limit_m), axis=1)


FOOT_AZIMUTHS = 12


def foot_gap_m(centres: FloatArray, axes: FloatArray, profile: ToolProfile,
               signed_distance: Callable[[FloatArray], FloatArray]) -> FloatArray:
    """(N,) smallest gap [m] between the part and the shank's foot: its surface from the
    ball's equator up to the first profile sample (rings of FOOT_AZIMUTHS points every
    profile step). The profile starts above the ball because the contact surface lies at
    the ball; with the axis on the normal a wall near the ball is as near the first sample,
    but a tilt leaning away from the wall clears the samples while the foot stays as near
    the wall as the ball is. Above a plane the foot is ``tip_radius_m (1 - sin tilt)`` high."""
    if len(centres) == 0 or profile.shank_radius_m <= 0:
        return np.full(len(centres), np.inf)
    heights = np.arange(0.0, profile.tip_radius_m + profile.step_m, profile.step_m)
    e1 = np.cross(axes, np.where(np.abs(axes[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(axes, e1)
    phi = np.linspace(0.0, 2.0 * np.pi, FOOT_AZIMUTHS, endpoint=False)
    ring = np.cos(phi)[None, :, None] * e1[:, None, :] + np.sin(phi)[None, :, None] * e2[:, None, :]
    pts = (centres[:, None, None, :] + heights[None, :, None, None] * axes[:, None, None, :]
           + profile.shank_radius_m * ring[:, None, :, :])
    return signed_distance(pts.reshape(-1, 3)).reshape(len(centres), -1).min(axis=1)


# Below this length of ``up``'s projection (a face within about 15 deg of facing ``up``) its
# direction is set by the normal's noise; such points take a fixed reference direction instead,
# so that neighbours on a flat face share one tangent basis.
_LEVEL_PROJECTION = 0.25


def _tangent_towards(normals: FloatArray, up: FloatArray) -> FloatArray:
    """Unit tangents: ``up`` projected on each tangent plane; where the face nearly faces ``up``,
    a fixed direction perpendicular to ``up`` projected instead."""
    t = up[None, :] - (normals @ up)[:, None] * normals
    level = np.linalg.norm(t, axis=1) < _LEVEL_PROJECTION
    if level.any():
        ref = np.cross(up, [0.0, 1.0, 0.0] if abs(up[1]) < 0.9 else [1.0, 0.0, 0.0])
        t[level] = ref - (normals[level] @ ref)[:, None] * normals[level]
    return t / np.linalg.norm(t, axis=1, keepdims=True)


def clear_axes(contacts: FloatArray, normals: FloatArray, tip_radius_m: float, profile: ToolProfile,
               signed_distance: Callable[[FloatArray], FloatArray], max_tilt_rad: float, min_clearance_m: float,
               min_foot_gap_m: float = 0.0, up: ArrayLike = (0.0, 0.0, 1.0), levels: int = 4, azimuths: int = 8,
               window: int = 7) -> FloatArray:
    """Tool axes (N, 3) for one line of contact points (see the module docstring).

    Args:
        contacts, normals: (N, 3) contact points [m] and unit outward normals, in line order,
            in the frame ``signed_distance`` takes (the part's).
        tip_radius_m: the ball's radius [m]; profile: the tool above it.
        signed_distance: (M, 3) -> (M,) distance to the part [m], negative inside.
        max_tilt_rad: the cone's half angle; min_clearance_m: the gap the tool must keep
            above its foot; min_foot_gap_m: the gap the foot of a tilted shank must keep
            (:func:`foot_gap_m`).
        up: the preferred tilt direction; levels, azimuths: the candidate tilts and directions.
        window: points over which a tilt is spread along the line (odd).
    """
    n = np.asarray(normals, dtype=np.float64)
    centres = np.asarray(contacts, dtype=np.float64) + tip_radius_m * n
    if max_tilt_rad <= 0 or len(n) == 0:
        return n.copy()
    # each point's tilt as a 2-D vector theta (cos psi, sin psi) in its own tangent basis
    # (t1 towards ``up``, t2 = n x t1), so that a tilt passed to a neighbour keeps its meaning
    t1 = _tangent_towards(n, np.asarray(up, dtype=np.float64))
    t2 = np.cross(n, t1)
    tilt = np.zeros((len(n), 2))
    todo = np.flatnonzero(clearance_m(centres, n, profile, signed_distance, min_clearance_m) < min_clearance_m)
    if len(todo) == 0:
        return n.copy()
    # the directions around the normal, "up" first, then alternately either side of it
    order = [0] + [k for j in range(1, azimuths // 2 + 1) for k in (j, -j)][: azimuths - 1]
    psi = 2.0 * np.pi * np.array(order) / azimuths
    for level in range(1, levels + 1):
        if len(todo) == 0:
            break
        theta = max_tilt_rad * level / levels
        dirs = np.cos(psi)[None, :, None] * t1[todo][:, None, :] + np.sin(psi)[None, :, None] * t2[todo][:, None, :]
        cand = np.cos(theta) * n[todo][:, None, :] + np.sin(theta) * dirs            # (T, A, 3)
        gap = clearance_m(np.repeat(centres[todo], len(psi), axis=0), cand.reshape(-1, 3), profile,
                          signed_distance, min_clearance_m).reshape(len(todo), len(psi))
        ok = gap >= min_clearance_m
        if min_foot_gap_m > 0 and ok.any():
            t, a = np.nonzero(ok)
            ok[t, a] = foot_gap_m(centres[todo][t], cand[t, a], profile, signed_distance) >= min_foot_gap_m
        found = ok.any(axis=1)
        first = psi[np.argmax(ok, axis=1)]
        tilt[todo[found]] = theta * np.column_stack([np.cos(first[found]), np.sin(first[found])])
        todo = todo[~found]
    # spread along the line: each point takes the largest tilt within the window around it,
    # then the running mean of those ramps the tilt in and out
    if window > 1 and len(n) > 1:
        size = min(window, 2 * ((len(n) - 1) // 2) + 1)
        h = size // 2
        angle = np.linalg.norm(tilt, axis=1)
        within = np.argmax(sliding_window_view(np.pad(angle, h, mode="edge"), size), axis=1)
        tilt = uniform_filter1d(tilt[np.clip(np.arange(len(n)) - h + within, 0, len(n) - 1)], size=size, axis=0,
                                mode="nearest")
    theta = np.minimum(np.linalg.norm(tilt, axis=1), max_tilt_rad)
    direction = tilt[:, :1] * t1 + tilt[:, 1:] * t2
    norm = np.linalg.norm(direction, axis=1, keepdims=True)
    direction = np.divide(direction, norm, out=np.zeros_like(direction), where=norm > 0)
    axes = np.cos(theta)[:, None] * n + np.sin(theta)[:, None] * direction
    return axes / np.linalg.norm(axes, axis=1, keepdims=True)


def into_cone(axes: FloatArray, normals: FloatArray, max_tilt_rad: float) -> FloatArray:
    """Unit axes (N, 3): each axis, or where it leans more than ``max_tilt_rad`` from its
    normal, the axis in the cone's boundary nearest it."""
    a = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    cos = np.sum(a * normals, axis=1)
    out = a.copy()
    far = cos < np.cos(max_tilt_rad)
    if far.any():
        t = a[far] - cos[far, None] * normals[far]
        norm = np.linalg.norm(t, axis=1, keepdims=True)
        t = np.divide(t, norm, out=np.zeros_like(t), where=norm > 0)
        out[far] = np.cos(max_tilt_rad) * normals[far] + np.sin(max_tilt_rad) * t
    return out


def steer_axes(contacts: FloatArray, normals: FloatArray, axes: FloatArray, lo: int, hi: int,
               cost: Callable[[FloatArray, FloatArray], float], tip_radius_m: float, profile: ToolProfile,
               signed_distance: Callable[[FloatArray], FloatArray], max_tilt_rad: float, min_clearance_m: float,
               min_foot_gap_m: float = 0.0, windows: Sequence[int] = (5, 9, 17, 33), up: ArrayLike = (0.0, 0.0, 1.0),
               levels: int = 4,
               azimuths: int = 8, ramp: int = 3) -> FloatArray | None:
    """Re-choose the axes around one stretch of a line for the arm: the line's axes (N, 3)
    with the stretch ``lo:hi`` and its surroundings changed to the candidate of the lowest
    ``cost``, or None when no candidate keeps the tool clear and costs less than the current
    axes. The contact points stay where they are (every axis passes through its ball centre).

    Candidates, each within every point's cone and blended into the current axes over
    ``ramp`` points on each side:

    * the current axes smoothed along the line (a running mean over each of ``windows``
      points, pulled back into the cones) over the stretch widened by half the window: the
      axis turns as far, over more points, so the wrist turns slower;
    * one tilt for the whole stretch (``levels`` angles up to the limit, ``azimuths``
      directions in each point's tangent basis, as :func:`clear_axes` gives them).

    Args:
        contacts, normals, axes: (N, 3) the line's contact points [m], unit outward normals and
            current tool axes, in the frame ``signed_distance`` takes.
        lo, hi: the stretch (points ``lo`` to ``hi - 1``).
        cost: (M, 3) ball centres, (M, 3) axes of consecutive points around the stretch ->
            the arm's trouble there (e.g. its largest joint step); lower is better.
        tip_radius_m, profile, signed_distance, max_tilt_rad, min_clearance_m, min_foot_gap_m,
            up: as :func:`clear_axes`.
    """
    n = np.asarray(normals, dtype=np.float64)
    axes = np.asarray(axes, dtype=np.float64)
    N = len(n)
    centres = np.asarray(contacts, dtype=np.float64) + tip_radius_m * n
    reach = max(windows) // 2 + ramp
    ea, eb = max(0, lo - reach), min(N, hi + reach)          # every candidate changes only ea:eb

    def blended(target: FloatArray, a: int, b: int) -> FloatArray:
        """The axes with ``target`` (N, 3) on a:b, ramping from the current ones over ``ramp``."""
        w = np.zeros(N)
        w[a:b] = 1.0
        for k in range(1, ramp + 1):
            if a - k >= 0:
                w[a - k] = 1.0 - k / (ramp + 1)
            if b - 1 + k < N:
                w[b - 1 + k] = 1.0 - k / (ramp + 1)
        out = (1.0 - w)[:, None] * axes + w[:, None] * target
        return into_cone(out, n, max_tilt_rad)

    candidates = []
    for window in windows:
        h = window // 2
        smooth = uniform_filter1d(axes, size=window, axis=0, mode="nearest")
        candidates.append(blended(into_cone(smooth, n, max_tilt_rad), max(0, lo - h), min(N, hi + h)))
    t1 = _tangent_towards(n, np.asarray(up, dtype=np.float64))
    t2 = np.cross(n, t1)
    for level in range(1, levels + 1):
        theta = max_tilt_rad * level / levels
        for psi in 2.0 * np.pi * np.arange(azimuths) / azimuths:
            target = np.cos(theta) * n + np.sin(theta) * (np.cos(psi) * t1 + np.sin(psi) * t2)
            candidates.append(blended(target, lo, hi))
    best_cost, best = cost(centres[ea:eb], axes[ea:eb]), None
    for cand in candidates:
        c = cost(centres[ea:eb], cand[ea:eb])
        if not c < best_cost:
            continue
        changed = np.flatnonzero(np.any(np.abs(cand - axes) > 1e-12, axis=1))
        if np.min(clearance_m(centres[changed], cand[changed], profile, signed_distance, min_clearance_m),
                  initial=np.inf) < min_clearance_m:
            continue
        tilted = changed[np.sum(cand[changed] * n[changed], axis=1) < np.cos(1e-6)]
        if min_foot_gap_m > 0 and len(tilted) and np.min(
                foot_gap_m(centres[tilted], cand[tilted], profile, signed_distance)) < min_foot_gap_m:
            continue
        best_cost, best = c, cand
    return best
