"""A ball-end raster finishing program of a mesh: the CAM program document 003 relocates.

Drop-cutter: at each raster position ``(x, y)`` the ball of radius ``r`` is lowered along ``-z``
until it touches the surface; its centre's height is ``max(z_p + sqrt(r^2 - d_p^2))`` over the
surface's samples ``p`` within ``d_p <= r`` of ``(x, y)``. The surface is sampled on a barycentric
grid of every triangle no coarser than ``sample_m``, so a ball between samples can sink into a
convex patch by at most about ``sample_m^2 / (8 r)`` (0.8 um at 0.2 mm and r = 5 mm).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree


def surface_samples(vertices: np.ndarray, faces: np.ndarray, sample_m: float) -> np.ndarray:
    """Points on every triangle on a barycentric grid with edges of at most ``sample_m``."""
    tri = vertices[faces]
    longest = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    out = [vertices]
    for n in np.unique(np.maximum(1, np.ceil(longest / sample_m)).astype(int)):
        if n < 2:
            continue
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = (i + j) <= n
        a, b = i[keep] / n, j[keep] / n
        bary = np.stack([1.0 - a - b, a, b], axis=1)
        sel = tri[np.ceil(longest / sample_m).astype(int) == n]
        out.append(np.einsum("kc,fcd->fkd", bary, sel).reshape(-1, 3))
    return np.concatenate(out)


def drop_cutter_raster(vertices: np.ndarray, faces: np.ndarray, *, tool_radius_m: float, stepover_m: float,
                       step_m: float, xy_min_m: tuple[float, float], xy_max_m: tuple[float, float],
                       sample_m: float = 2e-4) -> list[np.ndarray]:
    """Raster passes along ``x`` (zig-zag), ``stepover_m`` apart in ``y``, a point every
    ``step_m``, over the box ``xy_min_m``-``xy_max_m`` of the mesh's frame [m]: each pass an
    (N, 3) array of tool tips [m] (the ball's lowest point, centre minus ``r z``)."""
    if not (tool_radius_m > 0 and stepover_m > 0 and step_m > 0 and sample_m > 0):
        raise ValueError("tool_radius_m, stepover_m, step_m and sample_m must be > 0")
    pts = surface_samples(np.asarray(vertices, dtype=np.float64), np.asarray(faces), sample_m)
    tree = cKDTree(pts[:, :2])
    xs = np.linspace(xy_min_m[0], xy_max_m[0], max(2, math.floor((xy_max_m[0] - xy_min_m[0]) / step_m) + 1))
    ys = np.linspace(xy_min_m[1], xy_max_m[1], max(2, math.floor((xy_max_m[1] - xy_min_m[1]) / stepover_m) + 1))
    passes = []
    for k, y in enumerate(ys):
        line = xs if k % 2 == 0 else xs[::-1]
        xy = np.column_stack([line, np.full(len(line), y)])
        z = np.full(len(line), np.nan)
        for m, near in enumerate(tree.query_ball_point(xy, tool_radius_m)):
            if near:
                d2 = np.sum((pts[near, :2] - xy[m]) ** 2, axis=1)
                z[m] = np.max(pts[near, 2] + np.sqrt(np.maximum(tool_radius_m ** 2 - d2, 0.0)))
        ok = np.isfinite(z)
        if ok.any():
            passes.append(np.column_stack([xy[ok], z[ok] - tool_radius_m]))
    return passes
