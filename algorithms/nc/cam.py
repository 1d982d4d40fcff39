"""A ball-end raster finishing program of a mesh: the CAM program document 003 relocates.

Drop-cutter: at each raster position ``(x, y)`` the ball of radius ``r`` is lowered along ``-z``
until it first touches the mesh; its centre's height is the highest of the touches against

* each upward facing triangle's interior: ``z_c = (r + n . v_0 - n_x x - n_y y) / n_z`` where the
  contact point ``c - r n`` falls inside the triangle (exact);
* its edges and vertices, sampled no coarser than ``sample_m``: ``z_p + sqrt(r^2 - d_p^2)`` over
  the samples within ``d_p <= r``. Between two samples of a straight edge the ball can sink by
  at most ``sample_m^2 / (8 r)`` (1 nm at 0.2 mm and r = 5 mm).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree


def edge_samples(vertices: np.ndarray, faces: np.ndarray, sample_m: float) -> np.ndarray:
    """The vertices and points along every edge, no more than ``sample_m`` apart."""
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    a, b = vertices[edges[:, 0]], vertices[edges[:, 1]]
    n = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / sample_m)).astype(int)
    out = [vertices]
    for k in np.unique(n[n > 1]):
        t = np.arange(1, k)[None, :, None] / k
        sel = n == k
        out.append((a[sel][:, None, :] * (1 - t) + b[sel][:, None, :] * t).reshape(-1, 3))
    return np.concatenate(out)


def _facet_heights(xy: np.ndarray, r: float, tri: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The ball centre's height touching each triangle's interior (NaN where the contact point
    falls outside it), for the ball over ``xy``."""
    x, y = xy
    z = (r + np.einsum("fd,fd->f", normals, tri[:, 0]) - normals[:, 0] * x - normals[:, 1] * y) / normals[:, 2]
    p = np.column_stack([np.full(len(z), x), np.full(len(z), y), z]) - r * normals
    e1, e2, w = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], p - tri[:, 0]
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    w1, w2 = (w * e1).sum(1), (w * e2).sum(1)
    det = d11 * d22 - d12 ** 2
    u, v = (d22 * w1 - d12 * w2) / det, (d11 * w2 - d12 * w1) / det
    inside = (u >= 0) & (v >= 0) & (u + v <= 1)
    return np.where(inside, z, np.nan)


def drop_cutter_raster(vertices: np.ndarray, faces: np.ndarray, *, tool_radius_m: float, stepover_m: float,
                       step_m: float, xy_min_m: tuple[float, float], xy_max_m: tuple[float, float],
                       sample_m: float = 2e-4) -> list[np.ndarray]:
    """Raster passes along ``x`` (zig-zag), ``stepover_m`` apart in ``y``, a point every
    ``step_m``, over the box ``xy_min_m``-``xy_max_m`` of the mesh's frame [m]: each pass an
    (N, 3) array of tool tips [m] (the ball's lowest point, centre minus ``r z``)."""
    r = float(tool_radius_m)
    if not (r > 0 and stepover_m > 0 and step_m > 0 and sample_m > 0):
        raise ValueError("tool_radius_m, stepover_m, step_m and sample_m must be > 0")
    V, F = np.asarray(vertices, dtype=np.float64), np.asarray(faces)
    tri = V[F]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    up = normals[:, 2] > 1e-9
    tri, normals = tri[up], normals[up]
    lo, hi = tri[:, :, :2].min(axis=1), tri[:, :, :2].max(axis=1)
    pts = edge_samples(V, F, sample_m)
    tree = cKDTree(pts[:, :2])
    xs = np.linspace(xy_min_m[0], xy_max_m[0], max(2, math.floor((xy_max_m[0] - xy_min_m[0]) / step_m) + 1))
    ys = np.linspace(xy_min_m[1], xy_max_m[1], max(2, math.floor((xy_max_m[1] - xy_min_m[1]) / stepover_m) + 1))
    passes = []
    for k, y in enumerate(ys):
        line = xs if k % 2 == 0 else xs[::-1]
        z = np.full(len(line), -np.inf)
        for m, x in enumerate(line):
            near = tree.query_ball_point((x, y), r)
            if near:
                d2 = (pts[near, 0] - x) ** 2 + (pts[near, 1] - y) ** 2
                z[m] = np.max(pts[near, 2] + np.sqrt(np.maximum(r * r - d2, 0.0)))
            sel = np.nonzero((lo[:, 0] <= x + r) & (hi[:, 0] >= x - r) & (lo[:, 1] <= y + r) & (hi[:, 1] >= y - r))[0]
            if len(sel):
                zf = _facet_heights(np.array([x, y]), r, tri[sel], normals[sel])
                if np.any(np.isfinite(zf)):
                    z[m] = max(z[m], float(np.nanmax(zf)))
        ok = np.isfinite(z)
        if ok.any():
            passes.append(np.column_stack([line[ok], np.full(int(ok.sum()), y), z[ok] - r]))
    return passes
