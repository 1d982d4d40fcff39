"""Exact surfaces and their foot points: document 000's step (3), Newton on ``[psi_u psi_v]^T (x - psi) = 0``.

A :class:`ParametricModel` is a part's exact surfaces, each a plane, a sphere, a vertical
cylinder or a surface of revolution of cubic Bezier segments (document 000's workpiece B: "a dozen Bezier patches").
Its :meth:`~ParametricModel.query` answers what :meth:`MeshIndex.query` answers (foot, distance,
surface number as ``face``, outward normal), so document 000's Algorithm 1 as printed
(:mod:`algorithms.registration.printed`) runs on it with the document's own foot points:

* plane, sphere and cylinder: the closest point in closed form;
* surface of revolution ``psi(t, phi) = o + a(t) d + r(t) (cos(phi) e1 + sin(phi) e2)``: the
  nearest ``phi`` is the point's own (``psi_phi . (x - psi) = 0``), and Newton solves
  ``c'(t) . (c(t) - q) = 0`` for the profile ``c(t) = (a(t), r(t))`` against the point's
  (axial, radial) coordinates ``q``, from the nearest of 17 samples of each segment (the
  document's "nearest reference point"), ``t`` kept in [0, 1].

Each point's foot is the nearest over the surfaces whose trim holds it (a plane's disk and
holes, a sphere's lowest height, a cylinder's height range); a point no trim holds takes the
nearest untrimmed foot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from algorithms.geometry.mesh_index import ClosestPoints

#: Newton iterations on a profile segment, and the step [in t] below which it stops.
NEWTON_ITERATIONS, NEWTON_STEP_TOL = 30, 1e-14
#: Samples of each Bezier segment the Newton starts from.
START_SAMPLES = 17
#: A foot outside its surface's trim counts this much farther [m]: a point takes a trimmed
#: surface's foot only where no surface holds one within its trim (near a trim's edge).
TRIM_PENALTY_M = 1.0


@dataclass(frozen=True)
class Plane:
    """The plane through ``point`` with outward unit ``normal`` (workpiece frame, metres);
    trimmed (:meth:`inside`) to the disk ``within`` = (centre, radius) when given, and outside
    each disk of ``holes``."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    within: tuple[tuple[float, float, float], float] | None = None
    holes: tuple[tuple[tuple[float, float, float], float], ...] = ()

    def feet(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = np.asarray(self.normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        s = (x - np.asarray(self.point)) @ n
        return x - s[:, None] * n, np.broadcast_to(n, x.shape).copy()

    def inside(self, foot: np.ndarray) -> np.ndarray:
        ok = np.ones(len(foot), dtype=bool)
        if self.within is not None:
            ok &= np.linalg.norm(foot - np.asarray(self.within[0]), axis=1) <= self.within[1]
        for centre, radius in self.holes:
            ok &= np.linalg.norm(foot - np.asarray(centre), axis=1) >= radius
        return ok


@dataclass(frozen=True)
class Sphere:
    """The sphere of ``centre`` and ``radius`` (outward normals), trimmed to ``z >= z_min``."""

    centre: tuple[float, float, float]
    radius: float
    z_min: float = -np.inf

    def feet(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = x - np.asarray(self.centre)
        n = w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-300)
        return np.asarray(self.centre) + self.radius * n, n

    def inside(self, foot: np.ndarray) -> np.ndarray:
        return foot[:, 2] >= self.z_min


@dataclass(frozen=True)
class Cylinder:
    """The vertical cylinder of axis ``(x, y)`` = ``axis_xy`` and ``radius`` (outward normals),
    trimmed to ``z_range``."""

    axis_xy: tuple[float, float]
    radius: float
    z_range: tuple[float, float]

    def feet(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = x[:, :2] - np.asarray(self.axis_xy)
        n2 = w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-300)
        foot = np.column_stack([np.asarray(self.axis_xy) + self.radius * n2, x[:, 2]])
        return foot, np.column_stack([n2, np.zeros(len(x))])

    def inside(self, foot: np.ndarray) -> np.ndarray:
        return (foot[:, 2] >= self.z_range[0]) & (foot[:, 2] <= self.z_range[1])


@dataclass(frozen=True)
class BezierRevolution:
    """The surface of revolution of a profile of cubic Bezier segments about the axis through
    ``origin`` along ``axis``: ``segments`` (K, 4, 2) control points ``(a, r)`` (axial position
    along ``axis`` from ``origin``, radius), traversed with ``a`` increasing (outward normals
    then point away from the axis)."""

    origin: tuple[float, float, float]
    axis: tuple[float, float, float]
    segments: np.ndarray

    def feet(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = np.asarray(self.axis, dtype=np.float64)
        d = d / np.linalg.norm(d)
        w = x - np.asarray(self.origin)
        a = w @ d
        radial = w - a[:, None] * d
        rho = np.linalg.norm(radial, axis=1)
        e = radial / np.maximum(rho, 1e-300)[:, None]
        q = np.column_stack([a, rho])
        best_c, best_n, best_d = np.zeros_like(q), np.zeros_like(q), np.full(len(q), np.inf)
        for ctrl in np.asarray(self.segments, dtype=np.float64):
            c, n = _segment_feet(ctrl, q)
            dist = np.linalg.norm(c - q, axis=1)
            take = dist < best_d
            best_c[take], best_n[take], best_d[take] = c[take], n[take], dist[take]
        foot = np.asarray(self.origin) + best_c[:, :1] * d + best_c[:, 1:] * e
        normal = best_n[:, :1] * d + best_n[:, 1:] * e
        return foot, normal

    def inside(self, foot: np.ndarray) -> np.ndarray:
        return np.ones(len(foot), dtype=bool)


def _bezier(ctrl: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A cubic Bezier segment's point, first and second derivative at ``t`` (N,): each (N, 2)."""
    t = t[:, None]
    s = 1.0 - t
    p = s**3 * ctrl[0] + 3 * s**2 * t * ctrl[1] + 3 * s * t**2 * ctrl[2] + t**3 * ctrl[3]
    dp = 3 * (s**2 * (ctrl[1] - ctrl[0]) + 2 * s * t * (ctrl[2] - ctrl[1]) + t**2 * (ctrl[3] - ctrl[2]))
    ddp = 6 * (s * (ctrl[2] - 2 * ctrl[1] + ctrl[0]) + t * (ctrl[3] - 2 * ctrl[2] + ctrl[1]))
    return p, dp, ddp


def _segment_feet(ctrl: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The closest point of one profile segment to each (axial, radial) point ``q`` (N, 2) and
    the outward unit normal there: Newton on ``c'(t) . (c(t) - q) = 0`` (module docstring)."""
    grid = np.linspace(0.0, 1.0, START_SAMPLES)
    samples, _, _ = _bezier(ctrl, grid)
    t = grid[np.argmin(((q[:, None, :] - samples[None]) ** 2).sum(axis=2), axis=1)]
    for _ in range(NEWTON_ITERATIONS):
        p, dp, ddp = _bezier(ctrl, t)
        f = np.einsum("ij,ij->i", dp, p - q)
        df = np.einsum("ij,ij->i", dp, dp) + np.einsum("ij,ij->i", ddp, p - q)
        step = np.where(df > 0, f / np.where(df > 0, df, 1.0), 0.0)
        t_new = np.clip(t - step, 0.0, 1.0)
        moved = np.max(np.abs(t_new - t))
        t = t_new
        if moved < NEWTON_STEP_TOL:
            break
    p, dp, _ = _bezier(ctrl, t)
    n = np.column_stack([-dp[:, 1], dp[:, 0]])
    return p, n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


class ParametricModel:
    """A part's exact surfaces (module docstring), queried like a :class:`MeshIndex`."""

    def __init__(self, surfaces: list, extent: float):
        if not surfaces:
            raise ValueError("a parametric model needs at least one surface")
        if not extent > 0:
            raise ValueError(f"extent must be > 0 (the part's size [m]), got {extent}")
        self.surfaces = tuple(surfaces)
        self.extent = float(extent)

    def query(self, points: ArrayLike, hint: ArrayLike | None = None, rel_error: float = 0.0) -> ClosestPoints:
        """The nearest foot point over the surfaces of each point (N, 3) [m], workpiece frame."""
        del hint, rel_error  # the feet are exact
        x = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        foot, normal = np.zeros_like(x), np.zeros_like(x)
        rank, dist = np.full(len(x), np.inf), np.full(len(x), np.inf)
        which = np.zeros(len(x), dtype=np.int64)
        for k, surface in enumerate(self.surfaces):
            f, n = surface.feet(x)
            d = np.linalg.norm(x - f, axis=1)
            r = np.where(surface.inside(f), d, d + TRIM_PENALTY_M)
            take = r < rank
            foot[take], normal[take], dist[take], which[take], rank[take] = f[take], n[take], d[take], k, r[take]
        return ClosestPoints(foot=foot, distance=dist, face=which, normal=normal)

    def smooth_normals(self, face: ArrayLike, foot: ArrayLike) -> np.ndarray:
        """The exact outward normal of surface ``face`` at each ``foot`` (on that surface)."""
        face, foot = np.asarray(face), np.asarray(foot, dtype=np.float64).reshape(-1, 3)
        out = np.zeros_like(foot)
        for k, surface in enumerate(self.surfaces):
            sel = face == k
            if sel.any():
                out[sel] = surface.feet(foot[sel])[1]
        return out
