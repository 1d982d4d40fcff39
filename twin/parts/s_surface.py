"""Document 004's S-shaped surface part, and the analytic height and normal of its top.

The top is a free-form surface ``z = s_surface_height(x, y)`` over a rectangular footprint,
tessellated as a regular grid; flat side walls and a flat bottom at z = 0 close the solid.
:func:`s_surface_height` and :func:`s_surface_normal` take the generator's keyword arguments
so that a caller can evaluate the exact surface of the part it generated (path planning,
normal-error studies).
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from algorithms.arraytypes import FloatArray, IntArray
from twin.parts.kernel import (
    assemble,
    check_finite,
    check_nonnegative,
    check_positive,
    check_resolution,
    edge_points,
    format_mm,
    require,
)
from twin.parts.planar import PLANAR_GRADING, PLANAR_MAX_EDGE_M, planar_patch

__all__ = ["s_surface", "s_surface_height", "s_surface_normal"]


def _s_params(
    length_m: float,
    width_m: float,
    base_thickness_m: float,
    amplitude_m: float,
    amplitude_gradient: float,
    crown_m: float,
) -> tuple[float, float, float, float, float, float]:
    length = check_positive("length_m", length_m)
    width = check_positive("width_m", width_m)
    base = check_positive("base_thickness_m", base_thickness_m)
    amp = check_nonnegative("amplitude_m", amplitude_m)
    grad = check_finite("amplitude_gradient", amplitude_gradient)
    crown = check_finite("crown_m", crown_m)
    require(
        abs(grad) < 1.0,
        f"amplitude_gradient must be in (-1, 1), got {amplitude_gradient!r}",
    )
    lowest = base - amp * (1.0 + abs(grad)) - max(0.0, -crown)
    require(
        lowest >= 0.2 * base and lowest >= 0.002,
        "base_thickness_m must exceed amplitude_m * (1 + |amplitude_gradient|) plus any "
        f"negative crown by a margin (the top must stay >= 2 mm and >= 20 % of the base "
        f"thickness above z = 0), got a lowest top at {format_mm(lowest)}",
    )
    return length, width, base, amp, grad, crown


def s_surface_height(
    x: np.ndarray | float,
    y: np.ndarray | float,
    length_m: float = 0.12,
    width_m: float = 0.08,
    base_thickness_m: float = 0.03,
    amplitude_m: float = 0.01,
    amplitude_gradient: float = 0.3,
    crown_m: float = 0.002,
    resolution_m: float | None = None,
) -> np.ndarray:
    """Analytic height of the S-surface part's top, in the workpiece frame.

    ``z = base + amplitude * (1 + g * yn) * sin(pi * xn) + crown * yn**2`` with
    ``xn = 2 x / length`` and ``yn = 2 y / width`` in [-1, 1] over the footprint: one full
    sine period across x (the S), its amplitude changing linearly across y, and a gentle
    crown in y. The function is defined everywhere; the part covers only its footprint.

    Args:
        x, y: coordinates [m], workpiece frame, any broadcastable shapes.
        length_m, width_m, base_thickness_m, amplitude_m, amplitude_gradient, crown_m: as in
            :func:`s_surface`.
        resolution_m: accepted so that the same keyword set as :func:`s_surface` can be
            passed; it has no effect.

    Returns:
        z [m], the broadcast shape of x and y.
    """
    del resolution_m
    length, width, base, amp, grad, crown = _s_params(
        length_m, width_m, base_thickness_m, amplitude_m, amplitude_gradient, crown_m
    )
    xn = 2.0 * np.asarray(x, dtype=np.float64) / length
    yn = 2.0 * np.asarray(y, dtype=np.float64) / width
    return base + amp * (1.0 + grad * yn) * np.sin(np.pi * xn) + crown * yn**2


def s_surface_normal(
    x: np.ndarray | float,
    y: np.ndarray | float,
    length_m: float = 0.12,
    width_m: float = 0.08,
    base_thickness_m: float = 0.03,
    amplitude_m: float = 0.01,
    amplitude_gradient: float = 0.3,
    crown_m: float = 0.002,
    resolution_m: float | None = None,
) -> np.ndarray:
    """Unit outward (upward) normal of the analytic S-surface top at (x, y).

    Args:
        x, y: coordinates [m], workpiece frame, any broadcastable shapes S.
        Other arguments: as in :func:`s_surface_height`.

    Returns:
        (*S, 3) unit normals, workpiece frame.
    """
    del resolution_m
    length, width, _, amp, grad, crown = _s_params(
        length_m, width_m, base_thickness_m, amplitude_m, amplitude_gradient, crown_m
    )
    x_arr, y_arr = np.broadcast_arrays(
        np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    )
    xn, yn = 2.0 * x_arr / length, 2.0 * y_arr / width
    dz_dx = amp * (1.0 + grad * yn) * np.cos(np.pi * xn) * np.pi * 2.0 / length
    dz_dy = (amp * grad * np.sin(np.pi * xn) + 2.0 * crown * yn) * 2.0 / width
    n = np.stack([-dz_dx, -dz_dy, np.ones_like(dz_dx)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _graded_drop(height: float, fine: float, coarse: float) -> np.ndarray:
    """Distances below a top corner [m], 0 first and ``height`` last, fine near the top."""
    d = [0.0]
    step = fine
    while d[-1] + step < height - 0.5 * min(step, coarse):
        d.append(d[-1] + step)
        step = min(coarse, step * (1.0 + PLANAR_GRADING))
    d.append(height)
    return np.asarray(d)


# Outward normals of the side walls, in the order of the footprint's edges (counter-clockwise
# from the -y edge).
_WALL_OUTWARD = (np.array([0.0, -1.0, 0.0]), np.array([1.0, 0.0, 0.0]),
                 np.array([0.0, 1.0, 0.0]), np.array([-1.0, 0.0, 0.0]))


def _top_patch(length: float, width: float, res: float,
               params: dict[str, float]) -> tuple[FloatArray, IntArray, IntArray]:
    """The top: a regular grid over the footprint, each cell split along the diagonal whose
    midpoint lies closer to the surface.

    Returns:
        vertices ((nx + 1) (ny + 1), 3) [m], triangles (M, 3), and the (nx + 1, ny + 1) vertex
        index of each grid node (x along the rows).

    Raises:
        TwinError: the grid would have more than 400,000 vertices.
    """
    nx = max(2, int(math.ceil(length / res - 1e-9)))
    ny = max(2, int(math.ceil(width / res - 1e-9)))
    require(
        (nx + 1) * (ny + 1) <= 400_000,
        f"resolution_m {format_mm(res)} gives a {nx} x {ny} grid; allowed are at most "
        "400,000 top vertices (MuJoCo refuses meshes over 200k faces)",
    )
    xs = np.linspace(-length / 2, length / 2, nx + 1)
    ys = np.linspace(-width / 2, width / 2, ny + 1)
    xs[0], xs[-1], ys[0], ys[-1] = -length / 2, length / 2, -width / 2, width / 2
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    gz = s_surface_height(gx, gy, **params)
    top_v = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])
    idx = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    v00, v10 = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    v11, v01 = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    xc = 0.5 * (gx[:-1, :-1] + gx[1:, 1:]).ravel()
    yc = 0.5 * (gy[:-1, :-1] + gy[1:, 1:]).ravel()
    zc = s_surface_height(xc, yc, **params)
    err_main = np.abs(0.5 * (top_v[v00, 2] + top_v[v11, 2]) - zc)
    err_anti = np.abs(0.5 * (top_v[v10, 2] + top_v[v01, 2]) - zc)
    main = err_main <= err_anti
    top_f = np.concatenate(
        [
            np.column_stack([v00, v10, v11])[main],
            np.column_stack([v00, v11, v01])[main],
            np.column_stack([v00, v10, v01])[~main],
            np.column_stack([v10, v11, v01])[~main],
        ]
    )
    return top_v, top_f, idx


def _corner_edge(cx: float, cy: float, res: float, coarse: float, params: dict[str, float]) -> FloatArray:
    """Points (n, 3) [m] down the vertical edge at footprint corner (cx, cy), from the top
    (exactly on the surface) to z = 0, spaced ``res`` at the top and growing to ``coarse``."""
    zc_top = float(s_surface_height(cx, cy, **params))
    drop = _graded_drop(zc_top, res, coarse)
    z = zc_top - drop
    z[-1] = 0.0
    z[0] = zc_top
    return np.column_stack([np.full_like(z, cx), np.full_like(z, cy), z])


def _side_walls(corner_xy: list[tuple[float, float]], verticals: list[FloatArray], top_edges: list[FloatArray],
                coarse: float) -> tuple[list[tuple[FloatArray, IntArray]], list[FloatArray]]:
    """The four side walls (patches in the order of ``_WALL_OUTWARD``) and their bottom edges
    (each (n, 3) [m], from corner i to corner i + 1 at z = 0)."""
    patches, bottom_edges = [], []
    for i in range(4):
        j = (i + 1) % 4
        p = np.array([*corner_xy[i], 0.0])
        q = np.array([*corner_xy[j], 0.0])
        bottom = edge_points(p, q, coarse)
        bottom_edges.append(bottom)
        # Loop: bottom edge i -> j, up corner j, top edge j -> i, down corner i.
        loop = np.concatenate(
            [bottom[:-1], verticals[j][::-1][:-1], top_edges[i][::-1][:-1], verticals[i][:-1]]
        )
        u = (q - p) / np.linalg.norm(q - p)
        patches.append(planar_patch([loop], p, u, np.array([0.0, 0.0, 1.0]), _WALL_OUTWARD[i], coarse))
    return patches, bottom_edges


def _bottom_patch(bottom_edges: list[FloatArray], coarse: float) -> tuple[FloatArray, IntArray]:
    """The flat bottom at z = 0, bounded by the walls' bottom edges, facing -z."""
    bottom_loop = np.concatenate([e[:-1] for e in bottom_edges])
    return planar_patch(
        [bottom_loop], bottom_loop[0], np.array([1.0, 0.0, 0.0]),
        np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0]), coarse,
    )


def s_surface(
    length_m: float = 0.12,
    width_m: float = 0.08,
    base_thickness_m: float = 0.03,
    amplitude_m: float = 0.01,
    amplitude_gradient: float = 0.3,
    crown_m: float = 0.002,
    resolution_m: float = 0.0005,
) -> trimesh.Trimesh:
    """Document 004's S-shaped surface part: a block whose top is a free-form S surface.

    The top is :func:`s_surface_height` over the footprint [-length/2, length/2] x
    [-width/2, width/2], tessellated as a regular grid (each cell split along the diagonal
    that better fits the surface); vertical side walls and a flat bottom at z = 0 close it.
    Document 004 names the part ("S 形表面的工件") without dimensions; the defaults are sized
    for its Keyence IL-065 sensor (55-105 mm range) and 4 mm scan-line spacing.

    The amplitude gradient and crown make the top free-form (not an extruded or revolved
    surface), and the sine is odd in x, so no rigid motion other than the identity maps the
    part onto itself: it can be localised in all 6 DOF, from the top alone.

    Args:
        length_m: footprint along x [m].
        width_m: footprint along y [m].
        base_thickness_m: mean height of the top above the bottom face [m].
        amplitude_m: amplitude of the S (sine) across x at y = 0 [m].
        amplitude_gradient: relative change of the amplitude from y = 0 to the y = +-width/2
            edges (dimensionless, |g| < 1).
        crown_m: rise of the top at the y edges relative to y = 0 [m] (may be negative).
        resolution_m: grid spacing of the top [m] (the walls and bottom are graded from it
            up to 5 mm).

    Returns:
        Watertight mesh [m], workpiece frame, bottom face at z = 0.

    Raises:
        TwinError: a parameter is not a positive finite number or the top would come within
            2 mm of the bottom.
    """
    length, width, base, amp, grad, crown = _s_params(
        length_m, width_m, base_thickness_m, amplitude_m, amplitude_gradient, crown_m
    )
    (res,) = check_resolution(resolution_m)
    params = dict(
        length_m=length, width_m=width, base_thickness_m=base, amplitude_m=amp,
        amplitude_gradient=grad, crown_m=crown,
    )
    top_v, top_f, idx = _top_patch(length, width, res, params)
    coarse = max(res, PLANAR_MAX_EDGE_M)
    x0, x1, y0, y1 = -length / 2, length / 2, -width / 2, width / 2
    corner_xy = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    verticals = [_corner_edge(cx, cy, res, coarse, params) for cx, cy in corner_xy]
    # Top edges of the walls, each running between consecutive corners (counter-clockwise).
    top_edges = [
        top_v[idx[:, 0]],
        top_v[idx[-1, :]],
        top_v[idx[::-1, -1]],
        top_v[idx[0, ::-1]],
    ]
    walls, bottom_edges = _side_walls(corner_xy, verticals, top_edges, coarse)
    patches = [(top_v, top_f), *walls, _bottom_patch(bottom_edges, coarse)]
    # the top, the walls in the order of ``_WALL_OUTWARD`` (-y, +x, +y, -x), the bottom
    return assemble(patches, "s_surface", ["s_surface", "side_front", "side_right", "side_back", "side_left",
                                           "bottom"])
