"""Randomized teaching: teach sequences an operator could make on the project's parts, for
testing the GOTO planners beyond the document's two experiments.

An operator measures a few features in a random order, each with a few points: points on the
top face (probe straight down), on the wall of a cavity or a bore (probe straight down,
entering through the opening), in either end of a through hole (the head indexed so that the
probe points into the hole). Between features the operator goes up above the part (a random
height over the safety plane), indexes the head there when the next feature needs another
stylus, moves across and comes down over the feature. Between two points of a cavity feature
the operator either goes up over the obstacle in the middle or, at random, goes around it
below the top face (the detour document 002's planner cannot see).

Every sequence is checked as :func:`twin.workflows.cmm.check_teach` checks a user's teach file (touches on
the part, every move clear of it); a draw that fails is drawn again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithms.probing.safety_plane import Teach, TeachMove, TeachStep, TeachStylus, TeachTouch
from twin.cmm_machine import CmmSetup
from twin.errors import TwinError
from twin.workflows.cmm import check_teach

#: Parts with the features the generator knows, and the styli it uses (scenarios/cmm/*.toml).
PARTS = ("inner_sphere", "through_hole", "bore_and_face")
APPROACH_M = 0.002
MAX_DRAWS = 50
#: The operator indexes the head with the ball this high over the part's top [m].
INDEX_HEIGHT_M = 0.12


@dataclass(frozen=True)
class _Point:
    point: np.ndarray
    normal: np.ndarray


def _top_points(rng, n: int, top_z: float, half: tuple[float, float], avoid) -> list[_Point]:
    out: list[_Point] = []
    while len(out) < n:
        xy = rng.uniform(-1, 1, 2) * (np.array(half) - 0.008)
        if avoid(xy):
            continue
        out.append(_Point(np.array([xy[0], xy[1], top_z]), np.array([0.0, 0.0, 1.0])))
    return out


def _cavity_points(rng, n: int) -> list[_Point]:
    """inner_sphere's defaults: radius 40 mm, centre 10 mm below the 60 mm top."""
    out = []
    for _ in range(n):
        phi, el = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(-60.0, -35.0))
        u = np.array([np.cos(el) * np.cos(phi), np.cos(el) * np.sin(phi), np.sin(el)])
        out.append(_Point(np.array([0.0, 0.0, 0.05]) + 0.04 * u, -u))
    return out


def _bore_points(rng, n: int) -> list[_Point]:
    """bore_and_face's defaults: 30 mm bore, 15 mm deep, at (12, 6) mm, top at 25 mm."""
    out = []
    for _ in range(n):
        phi, z = rng.uniform(0, 2 * np.pi), rng.uniform(0.013, 0.021)
        u = np.array([np.cos(phi), np.sin(phi), 0.0])
        out.append(_Point(np.array([0.012, 0.006, z]) + 0.015 * u, -u))
    return out


def _hole_points(rng, n: int, end: int) -> list[_Point]:
    """through_hole's defaults: 20 mm hole along x at 20 mm height, 80 mm long."""
    out = []
    depth = rng.uniform(0.006, 0.014)
    for _ in range(n):
        psi = rng.uniform(0, 2 * np.pi)
        u = np.array([0.0, np.cos(psi), np.sin(psi)])
        out.append(_Point(np.array([end * (0.04 - depth), 0.0, 0.02]) + 0.01 * u, -u))
    return out


def _features(part: str, rng) -> list[tuple[str, str, list[_Point]]]:
    """(kind, stylus, points) of 2-4 features of ``part``, in a random order."""
    n = lambda: int(rng.integers(1, 5))  # noqa: E731
    if part == "inner_sphere":
        pool = [("top", "S1", _top_points(rng, n(), 0.06, (0.05, 0.05), lambda xy: np.hypot(*xy) < 0.045)),
                ("cavity", "S1", _cavity_points(rng, n() + 1)), ("cavity", "S1", _cavity_points(rng, n()))]
    elif part == "through_hole":
        pool = [("top", "S1", _top_points(rng, n(), 0.04, (0.04, 0.03), lambda xy: False)),
                ("hole+", "S2", _hole_points(rng, n(), +1)), ("hole-", "S3", _hole_points(rng, n(), -1))]
    elif part == "bore_and_face":
        pool = [("top", "S1", _top_points(rng, n(), 0.025, (0.05, 0.04),
                                          lambda xy: np.hypot(xy[0] - 0.012, xy[1] - 0.006) < 0.021)),
                ("bore", "S1", _bore_points(rng, n() + 1))]
    else:
        raise TwinError(f"no random features for part {part!r}; parts: {', '.join(PARTS)}")
    k = int(rng.integers(2, len(pool) + 1))
    return [pool[i] for i in rng.permutation(len(pool))[:k]]


def _approach(p: _Point) -> np.ndarray:
    return p.point + (0.001 + APPROACH_M) * p.normal


def _entry(kind: str, a: np.ndarray, top_z: float) -> list[np.ndarray]:
    """Where the operator comes down (and goes back up) for a point: straight over it, or for
    a hole end beside the end face at the hole's height, then along the axis."""
    if kind.startswith("hole"):
        side = 1.0 if kind == "hole+" else -1.0
        return [np.array([side * 0.09, 0.0, 0.02]), np.array([a[0], 0.0, 0.02])]
    return []


def random_teach(part: str, setup: CmmSetup, rng: np.random.Generator, name: str = "random") -> Teach:
    """A random teach sequence on ``part`` (one of :data:`PARTS`) that passes :func:`check_teach`."""
    for _ in range(MAX_DRAWS):
        teach = _draw(part, setup, rng, name)
        try:
            check_teach(teach, setup)
        except TwinError:
            continue
        return teach
    raise TwinError(f"no valid random teach on {part} in {MAX_DRAWS} draws")


def _draw(part: str, setup: CmmSetup, rng: np.random.Generator, name: str) -> Teach:
    top_z = float(setup.mesh.vertices[:, 2].max())
    feats = _features(part, rng)
    safe = float(rng.uniform(0.02, 0.04))
    stylus = feats[0][1]
    steps: list[TeachStep] = []
    label = 0
    for f, (kind, sty, pts) in enumerate(feats):
        hover = top_z + float(rng.uniform(0.03, 0.06))
        first = _approach(pts[0])
        entry = _entry(kind, first, top_z)
        over = entry[0] if entry else first
        # over the feature, at the hover height (indexing the head there if needed)
        if sty != stylus:  # index high enough that a stylus swinging down stays above the part
            steps.append(TeachMove((float(over[0]), float(over[1]), top_z + INDEX_HEIGHT_M)))
            steps.append(TeachStylus(sty))
            stylus = sty
        steps.append(TeachMove((float(over[0]), float(over[1]), hover)))
        for e in entry:
            steps.append(TeachMove(tuple(e)))  # type: ignore[arg-type]
        for j, p in enumerate(pts):
            a = _approach(p)
            if j > 0:
                if kind == "cavity" and rng.random() < 0.5:
                    steps += [TeachMove(tuple(w)) for w in _around_post(_approach(pts[j - 1]), a)]  # type: ignore[misc]
                elif kind in ("cavity", "top"):
                    prev = _approach(pts[j - 1])
                    steps += [TeachMove((float(prev[0]), float(prev[1]), hover)),
                              TeachMove((float(a[0]), float(a[1]), hover))]
                elif kind.startswith("hole"):
                    steps.append(TeachMove((float(a[0]), 0.0, 0.02)))
            elif not entry:
                steps.append(TeachMove((float(a[0]), float(a[1]), hover)))
            label += 1
            steps.append(TeachTouch(f"F{f + 1}_{j + 1}", f"F{f + 1}", tuple(p.point), tuple(p.normal)))  # type: ignore[arg-type]
        last = _approach(pts[-1])
        if entry:
            steps += [TeachMove((float(last[0]), 0.0, 0.02))] + [TeachMove(tuple(e)) for e in entry[::-1]]  # type: ignore[misc]
            out = entry[0]
        else:
            out = last
        steps.append(TeachMove((float(out[0]), float(out[1]), hover)))
    start = steps[0]
    assert isinstance(start, TeachMove)
    first_move = TeachMove((start.xyz_m[0], start.xyz_m[1], start.xyz_m[2] + 0.02))
    return Teach(name, feats[0][1], (first_move, *steps), safe)


def _around_post(a: np.ndarray, b: np.ndarray) -> list[np.ndarray]:
    """Ring points 25 mm from the cavity's axis, 24 mm above the bottom... going the short way
    round from the azimuth of ``a`` to that of ``b`` in steps of at most 45 degrees."""
    pa, pb = np.arctan2(a[1], a[0]), np.arctan2(b[1], b[0])
    d = (pb - pa + np.pi) % (2 * np.pi) - np.pi
    k = max(1, int(np.ceil(abs(d) / np.radians(45.0))))
    return [np.array([0.025 * np.cos(pa + d * i / k), 0.025 * np.sin(pa + d * i / k), 0.025]) for i in range(0, k + 1)]
