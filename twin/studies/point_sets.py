"""Point sets of ``kind = "points"``: document 000's simulation protocol (section 9).

"Sample points uniformly on the CAD surfaces, apply known transforms, add noise N(mu, sigma^2)":
the points lie on the faces of the scenario's part selected by ``points.region`` (workpiece
frame), either drawn uniformly by area per trial (``layout = "random"``, ``count`` points) or
on fixed ``grid_rows x grid_cols`` grids, one per selector of the region, as the document
samples "a single surface uniformly on an M x N grid" (``layout = "grid"``: rays cast against
the selector's ``normal``, or along -z, through a regular grid over the bounding rectangle of
its faces seen from that direction; a node whose ray first meets a face outside the selector,
or nothing, is a hole in the grid). Subsampling rules apply to each grid. The known transform is the
scenario's true placement; the noise is ``noise_mean_m + noise_sigma_m * N(0, 1)`` on each
coordinate of the measured point in the machine frame (``noise_direction = "isotropic"``) or
along the surface normal (``"normal"``).

Model error: the true part may differ from the CAD model the fit uses by a form error, a
smooth random deviation along the surface normal of RMS ``form_error_m`` and wavelength
``form_wavelength_m`` (:func:`form_error_m`), a new part (a new field) each trial, drawn from the
trial's error stream before the noise.

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

#: The plane waves of a form error field.
FORM_WAVES = 8


def _selector_faces(mesh, sel: dict) -> np.ndarray:
    """(F,) bool: the faces that pass one selector."""
    ok = np.ones(len(mesh.faces), dtype=bool)
    if "normal" in sel:
        axis = np.asarray(sel["normal"], dtype=np.float64)
        axis /= np.linalg.norm(axis)
        ok &= np.asarray(mesh.face_normals) @ axis >= np.cos(np.radians(sel["cone_deg"])) - 1e-12
    if "box_min_m" in sel:
        centroids = np.asarray(mesh.triangles_center)
        ok &= np.all((centroids >= sel["box_min_m"]) & (centroids <= sel["box_max_m"]), axis=1)
    return ok


def _nonempty(mesh, faces: np.ndarray, what: list) -> np.ndarray:
    if len(faces) == 0 or float(np.asarray(mesh.area_faces)[faces].sum()) <= 0.0:
        raise TwinError(f"points.region {json.dumps(what)} selects no face of the part")
    return faces


def select_faces(mesh, region: list[dict]) -> np.ndarray:
    """Indices of the faces of ``mesh`` that ``region`` selects (module docstring)."""
    if not region:
        return np.arange(len(mesh.faces))
    keep = np.zeros(len(mesh.faces), dtype=bool)
    for sel in region:
        keep |= _selector_faces(mesh, sel)
    return _nonempty(mesh, np.flatnonzero(keep), region)


@dataclass(frozen=True)
class Design:
    """Where the model points of a cell can lie (workpiece frame).

    Attributes:
        faces: the selected faces; ``weights``: their areas normalised to 1.
        grids: ``layout = "grid"``: one (M, N, 3) [m] array of model points per selector (NaN
            where the grid has a hole); else empty.
    """

    faces: np.ndarray
    weights: np.ndarray
    grids: tuple = ()


def make_design(mesh, points: dict) -> Design:
    faces = select_faces(mesh, points["region"])
    area = np.asarray(mesh.area_faces)[faces]
    grids: tuple = ()
    if points["layout"] == "grid":
        selectors = points["region"] or [{}]
        grids = tuple(_grid_points(mesh, sel, points["grid_rows"], points["grid_cols"]) for sel in selectors)
        if sum(int(np.all(np.isfinite(g), axis=2).sum()) for g in grids) < 6:
            raise TwinError(f"points.layout = 'grid': fewer than 6 grid nodes fall on points.region "
                            f"{json.dumps(points['region'])}")
    return Design(faces, area / area.sum(), grids)


def _grid_points(mesh, sel: dict, rows: int, cols: int) -> np.ndarray:
    """The first hits of a ``rows x cols`` grid of parallel rays cast against the selector's
    normal (or along -z) over its faces (module docstring); the longer side gets the columns."""
    faces = _nonempty(mesh, np.flatnonzero(_selector_faces(mesh, sel)), [sel])
    n = np.asarray(sel.get("normal", [0.0, 0.0, 1.0]), dtype=np.float64)
    n /= np.linalg.norm(n)
    a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    verts = np.asarray(mesh.triangles)[faces].reshape(-1, 3)
    pa, pb = verts @ a, verts @ b
    (a0, a1), (b0, b1) = (pa.min(), pa.max()), (pb.min(), pb.max())
    if a1 - a0 < b1 - b0:  # columns along the longer side
        a, b, (a0, a1), (b0, b1) = b, a, (b0, b1), (a0, a1)
    ca = a0 + (np.arange(cols) + 0.5) * (a1 - a0) / cols
    cb = b0 + (np.arange(rows) + 0.5) * (b1 - b0) / rows
    A, B = np.meshgrid(ca, cb)
    lift = float(np.max(np.asarray(mesh.vertices) @ n)) + 1.0
    origins = A.reshape(-1, 1) * a + B.reshape(-1, 1) * b + lift * n
    directions = np.tile(-n, (A.size, 1))
    tri, ray, loc = mesh.ray.intersects_id(origins, directions, multiple_hits=False, return_locations=True)
    out = np.full((A.size, 3), np.nan)
    selected = np.isin(tri, faces)
    out[ray[selected]] = loc[selected]
    return out.reshape(rows, cols, 3)


def model_points(mesh, design: Design, points: dict, subsample: str, rng: np.random.Generator) -> np.ndarray:
    """This trial's model points (K, 3) [m], workpiece frame: ``count`` random points, or the
    grid's nodes kept by the subsampling rule (holes dropped)."""
    if not design.grids:
        f = design.faces[rng.choice(len(design.faces), size=points["count"], p=design.weights)]
        u = rng.uniform(size=(points["count"], 2))
        flip = u.sum(axis=1) > 1.0
        u[flip] = 1.0 - u[flip]
        t = np.asarray(mesh.triangles)[f]
        return t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0])
    M, N = design.grids[0].shape[:2]
    rule = {"none": lambda: full_grid(M, N), "hammersley": lambda: pseudo_hammersley_subsample(M, N),
            "uniform": lambda: uniform_subsample(M, N), "random": lambda: random_subsample(M, N, rng)}[subsample]
    kept = np.concatenate([rule().take(grid) for grid in design.grids])
    return kept[np.all(np.isfinite(kept), axis=1)]


def form_error_m(x: np.ndarray, amplitude_m: float, wavelength_m: float, rng: np.random.Generator) -> np.ndarray:
    """A smooth random deviation (N,) [m] of the true part from its CAD model at the model
    points ``x`` (N, 3) [m]: ``FORM_WAVES`` plane waves of ``wavelength_m`` with random
    directions and phases, scaled to the RMS ``amplitude_m``
    (``A sqrt(2 / K) sum_j cos(2 pi / lambda d_j . x + phi_j)``)."""
    d = rng.standard_normal((FORM_WAVES, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    phase = rng.uniform(0.0, 2.0 * np.pi, FORM_WAVES)
    waves = np.cos((2.0 * np.pi / wavelength_m) * (x @ d.T) + phase)
    return amplitude_m * np.sqrt(2.0 / FORM_WAVES) * waves.sum(axis=1)


def measured_points(x_model: np.ndarray, normals: np.ndarray, T_true: np.ndarray, points: dict,
                    rng: np.random.Generator) -> np.ndarray:
    """The model points moved onto the true part (its form error, where the study gives one),
    then by the noise (module docstring), and mapped by the known transform."""
    if points["form_error_m"] > 0.0:   # drawn only then: a study without form error keeps its numbers
        x_model = x_model + form_error_m(x_model, points["form_error_m"], points["form_wavelength_m"], rng)[:, None] \
            * normals
    mean, sigma = points["noise_mean_m"], points["noise_sigma_m"]
    if points["noise_direction"] == "normal":
        x = x_model + (mean + sigma * rng.standard_normal(len(x_model)))[:, None] * normals
        return transform_points(T_true, x)
    # on each coordinate of the measured point (machine frame), as the document adds it
    return transform_points(T_true, x_model) + mean + sigma * rng.standard_normal(x_model.shape)
