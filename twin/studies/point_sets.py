"""Point sets of ``kind = "points"``: document 000's simulation protocol (section 9).

"Sample points uniformly on the CAD surfaces, apply known transforms, add noise N(mu, sigma^2)":
the points lie on the faces of the scenario's part selected by ``points.region`` (workpiece
frame), either drawn uniformly by area per trial (``layout = "random"``, ``count`` points) or
on a fixed ``grid_rows x grid_cols`` grid over the region seen from above (``layout = "grid"``:
rays cast along -z through a regular grid over the region's x-y bounding box; a node whose ray
first meets an unselected face, or nothing, is a hole in the grid). The known transform is the
scenario's true placement; the noise is ``noise_mean_m + noise_sigma_m * N(0, 1)`` on each
coordinate of the measured point in the machine frame (``noise_direction = "isotropic"``) or
along the surface normal (``"normal"``).

A region is a list of selectors; a face is selected when it passes any one of them, and passes
a selector when its normal is within ``cone_deg`` of ``normal`` (if given) and its centroid is
inside the box ``[box_min_m, box_max_m]`` (if given). An empty list selects every face.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from algorithms.geometry.se3 import transform_points
from algorithms.registration.subsampling import (
    full_grid,
    pseudo_hammersley_subsample,
    random_subsample,
    uniform_subsample,
)
from twin.errors import TwinError


def select_faces(mesh, region: list[dict]) -> np.ndarray:
    """Indices of the faces of ``mesh`` that ``region`` selects (module docstring)."""
    n_faces = len(mesh.faces)
    if not region:
        return np.arange(n_faces)
    normals = np.asarray(mesh.face_normals)
    centroids = np.asarray(mesh.triangles_center)
    keep = np.zeros(n_faces, dtype=bool)
    for sel in region:
        ok = np.ones(n_faces, dtype=bool)
        if "normal" in sel:
            axis = np.asarray(sel["normal"], dtype=np.float64)
            axis /= np.linalg.norm(axis)
            ok &= normals @ axis >= np.cos(np.radians(sel["cone_deg"])) - 1e-12
        if "box_min_m" in sel:
            ok &= np.all((centroids >= sel["box_min_m"]) & (centroids <= sel["box_max_m"]), axis=1)
        keep |= ok
    faces = np.flatnonzero(keep)
    if len(faces) == 0 or float(np.asarray(mesh.area_faces)[faces].sum()) <= 0.0:
        raise TwinError(f"points.region {json.dumps(region)} selects no face of the part")
    return faces


@dataclass(frozen=True)
class Design:
    """Where the model points of a cell can lie (workpiece frame).

    Attributes:
        faces: the selected faces; ``weights``: their areas normalised to 1.
        grid: (M, N, 3) [m] the grid's model points (NaN where the grid has a hole), or None.
    """

    faces: np.ndarray
    weights: np.ndarray
    grid: np.ndarray | None


def make_design(mesh, points: dict) -> Design:
    faces = select_faces(mesh, points["region"])
    area = np.asarray(mesh.area_faces)[faces]
    grid = None
    if points["layout"] == "grid":
        grid = _grid_points(mesh, faces, points["grid_rows"], points["grid_cols"])
    return Design(faces, area / area.sum(), grid)


def _grid_points(mesh, faces: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """The first hit from above of a ``rows x cols`` grid of vertical rays over the region."""
    verts = np.asarray(mesh.triangles)[faces].reshape(-1, 3)
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    pad = 1e-6 * max(float(np.max(hi - lo)), 1e-3)
    # node centres of an even grid (rows along y, columns along x: M <= N puts N on the longer side
    # when x is longer)
    xs = lo[0] + (np.arange(cols) + 0.5) * (hi[0] - lo[0]) / cols
    ys = lo[1] + (np.arange(rows) + 0.5) * (hi[1] - lo[1]) / rows
    X, Y = np.meshgrid(xs, ys)
    top = float(np.asarray(mesh.bounds)[1, 2]) + 1.0 + pad
    origins = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, top)])
    directions = np.tile([0.0, 0.0, -1.0], (X.size, 1))
    tri, ray, loc = mesh.ray.intersects_id(origins, directions, multiple_hits=False, return_locations=True)
    out = np.full((X.size, 3), np.nan)
    selected = np.isin(tri, faces)
    out[ray[selected]] = loc[selected]
    if np.count_nonzero(np.all(np.isfinite(out), axis=1)) < 6:
        raise TwinError(f"points.layout = 'grid': fewer than 6 of the {rows} x {cols} grid nodes fall on the region")
    return out.reshape(rows, cols, 3)


def model_points(mesh, design: Design, points: dict, subsample: str, rng: np.random.Generator) -> np.ndarray:
    """This trial's model points (K, 3) [m], workpiece frame: ``count`` random points, or the
    grid's nodes kept by the subsampling rule (holes dropped)."""
    if design.grid is None:
        f = design.faces[rng.choice(len(design.faces), size=points["count"], p=design.weights)]
        u = rng.uniform(size=(points["count"], 2))
        flip = u.sum(axis=1) > 1.0
        u[flip] = 1.0 - u[flip]
        t = np.asarray(mesh.triangles)[f]
        return t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0])
    M, N = design.grid.shape[:2]
    rule = {"none": lambda: full_grid(M, N), "hammersley": lambda: pseudo_hammersley_subsample(M, N),
            "uniform": lambda: uniform_subsample(M, N), "random": lambda: random_subsample(M, N, rng)}[subsample]
    kept = rule().take(design.grid)
    return kept[np.all(np.isfinite(kept), axis=1)]


def measured_points(x_model: np.ndarray, normals: np.ndarray, T_true: np.ndarray, points: dict,
                    rng: np.random.Generator) -> np.ndarray:
    """The model points moved by the noise (module docstring) and mapped by the known transform."""
    mean, sigma = points["noise_mean_m"], points["noise_sigma_m"]
    if points["noise_direction"] == "normal":
        x = x_model + (mean + sigma * rng.standard_normal(len(x_model)))[:, None] * normals
        return transform_points(T_true, x)
    # on each coordinate of the measured point (machine frame), as the document adds it
    return transform_points(T_true, x_model) + mean + sigma * rng.standard_normal(x_model.shape)
