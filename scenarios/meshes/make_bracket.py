"""Make ``bracket.stl``: a machined mounting bracket, the user-mesh part of ``scenarios/bracket.toml``.

Run once from the repository root (``python scenarios/meshes/make_bracket.py``); the STL is
committed, so the scenario does not depend on this script.

The part (millimetres, workpiece frame: origin at the centre of the bottom face, z up, the part
standing on the plane z = 0):

* a block 120 x 80 mm, 25 mm high;
* a step: the end x < -20 mm is milled down to a 12 mm flange;
* two 10 mm through holes in the flange, at (-40, -22) and (-40, +22);
* a rectangular pocket 40 x 36 mm, 10 mm deep, at x in [0, 40], y in [-18, 18].

Every face is planar or vertical, so the solid is a 2.5-D height field over its footprint: one
2-D triangulation of the footprint (a Delaunay triangulation of a rectilinear grid whose lines
include every step and pocket edge, with the holes' circles sampled and the grid points near
them left out) gives the bottom face and, lifted to each region's height, the top faces; walls
join the heights on either side of every edge where they differ. Walls are split wherever
another face has a vertex on their vertical edges, so the mesh is closed and conforming
without any boolean operation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import Delaunay

OUT = Path(__file__).resolve().parent / "bracket.stl"

LENGTH_MM, WIDTH_MM, HEIGHT_MM = 120.0, 80.0, 25.0
STEP_X_MM, FLANGE_HEIGHT_MM = -20.0, 12.0
HOLES_MM = ((-40.0, -22.0), (-40.0, 22.0))
HOLE_RADIUS_MM = 5.0
HOLE_SEGMENTS = 48
POCKET_MM = ((0.0, -18.0), (40.0, 18.0))
POCKET_FLOOR_MM = HEIGHT_MM - 10.0
GRID_MM = 4.0            # largest grid spacing
HOLE_CLEARANCE_MM = 2.0  # grid points this far outside a hole's circle are left out


def grid_lines(lo: float, hi: float, breaks: tuple[float, ...]) -> np.ndarray:
    """Coordinates from ``lo`` to ``hi`` including every break, at most GRID_MM apart."""
    knots = np.unique(np.array([lo, hi, *breaks]))
    out = [knots[:1]]
    for a, b in zip(knots[:-1], knots[1:], strict=True):
        n = int(np.ceil((b - a) / GRID_MM - 1e-9))
        out.append(np.linspace(a, b, n + 1)[1:])
    return np.concatenate(out)


def footprint_points() -> np.ndarray:
    """2-D vertices: the grid (minus the points near the holes) and the holes' circles."""
    (px0, py0), (px1, py1) = POCKET_MM
    xs = grid_lines(-LENGTH_MM / 2, LENGTH_MM / 2, (STEP_X_MM, px0, px1))
    ys = grid_lines(-WIDTH_MM / 2, WIDTH_MM / 2, (py0, py1))
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    keep = np.ones(len(pts), dtype=bool)
    circles = []
    a = np.linspace(0.0, 2 * np.pi, HOLE_SEGMENTS, endpoint=False)
    for cx, cy in HOLES_MM:
        keep &= np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) > HOLE_RADIUS_MM + HOLE_CLEARANCE_MM
        circles.append(np.column_stack([cx + HOLE_RADIUS_MM * np.cos(a), cy + HOLE_RADIUS_MM * np.sin(a)]))
    return np.concatenate([pts[keep], *circles])


def top_height(xy: np.ndarray) -> np.ndarray:
    """Height of the top face over each 2-D point (triangle centroids); NaN inside a hole."""
    (px0, py0), (px1, py1) = POCKET_MM
    h = np.full(len(xy), HEIGHT_MM)
    h[xy[:, 0] < STEP_X_MM] = FLANGE_HEIGHT_MM
    in_pocket = (xy[:, 0] > px0) & (xy[:, 0] < px1) & (xy[:, 1] > py0) & (xy[:, 1] < py1)
    h[in_pocket] = POCKET_FLOOR_MM
    for cx, cy in HOLES_MM:
        h[np.hypot(xy[:, 0] - cx, xy[:, 1] - cy) < HOLE_RADIUS_MM] = np.nan
    return h


def footprint_triangles(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Counter-clockwise triangles of the footprint (holes removed) and their top heights."""
    tri = Delaunay(pts).simplices
    h = top_height(pts[tri].mean(axis=1))
    tri, h = tri[np.isfinite(h)], h[np.isfinite(h)]
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    cross = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    if np.any(np.abs(cross) < 1e-9):
        raise RuntimeError("degenerate triangle in the footprint triangulation")
    tri[cross < 0] = tri[cross < 0][:, ::-1]
    return tri, h


def build_mesh() -> trimesh.Trimesh:
    pts = footprint_points()
    tri, h = footprint_triangles(pts)
    vertex_ids: dict[tuple[int, float], int] = {}

    def vid(i: int, z: float) -> int:
        return vertex_ids.setdefault((int(i), float(z)), len(vertex_ids))

    faces = []
    heights_at: list[set[float]] = [set() for _ in range(len(pts))]
    for (i, j, k), z in zip(tri, h, strict=True):
        faces.append((vid(i, 0.0), vid(k, 0.0), vid(j, 0.0)))  # bottom, facing -z
        faces.append((vid(i, z), vid(j, z), vid(k, z)))        # top, facing +z
        for v in (i, j, k):
            heights_at[v].update((0.0, float(z)))

    # Each directed edge (a, b) of a counter-clockwise triangle has its solid on the left.
    # A wall stands where the edge's other side is lower (or empty: the outside, a hole).
    edge_height = {}
    for (i, j, k), z in zip(tri, h, strict=True):
        for a, b in ((i, j), (j, k), (k, i)):
            edge_height[(int(a), int(b))] = float(z)
    for (a, b), z in edge_height.items():
        z_other = edge_height.get((b, a), 0.0)
        if z_other >= z:
            continue
        # Wall from z_other up to z, facing right of a -> b; split at every height that the
        # two vertical edges carry in between (T-junction free).
        za = sorted(x for x in heights_at[a] if z_other <= x <= z)
        zb = sorted(x for x in heights_at[b] if z_other <= x <= z)
        ia, ib = 0, 0
        while ia < len(za) - 1 or ib < len(zb) - 1:
            if ib == len(zb) - 1 or (ia < len(za) - 1 and za[ia + 1] <= zb[ib + 1]):
                faces.append((vid(a, za[ia]), vid(b, zb[ib]), vid(a, za[ia + 1])))
                ia += 1
            else:
                faces.append((vid(a, za[ia]), vid(b, zb[ib]), vid(b, zb[ib + 1])))
                ib += 1

    verts = np.empty((len(vertex_ids), 3))
    for (i, z), n in vertex_ids.items():
        verts[n] = (pts[i, 0], pts[i, 1], z)
    mesh = trimesh.Trimesh(verts, np.array(faces), process=True)
    if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
        raise RuntimeError("the bracket mesh is not a closed, consistently wound solid")
    return mesh


def main() -> None:
    mesh = build_mesh()
    mesh.export(OUT, file_type="stl")
    print(f"{OUT.name}: {len(mesh.faces)} faces, {mesh.volume / 1e3:.1f} cm^3, "
          f"bounds {mesh.bounds.tolist()} mm, {OUT.stat().st_size / 1e3:.0f} kB")


if __name__ == "__main__":
    main()
