"""Discrete symmetries of a model, and the pseudo-normal table of its faces, edges and vertices.

A model that a finite set of rigid motions maps onto itself (a cube: 24; a square plate with
four identical blind holes: 4, with through holes 8) gives the same residual at ``T S`` as at
``T`` for every such ``S``: no measurement on the model can tell them apart.
:func:`model_symmetries` finds them. The candidates are the motions about the surface centroid
that map the largest flat-face normal clusters onto clusters of equal area (and the
principal-axis flips and turns); a candidate is accepted when it maps the surface onto itself
within ``SYMMETRY_TOL_REL`` of the model's size.

:func:`pseudo_normals` gives the angle-weighted pseudo-normals of a mesh (Baerentzen and
Aanaes, 2005) and its sharp edges: the sign of a point's distance from a closed mesh, and
whether a foot lies on or beside an edge.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import FloatArray, IntArray
from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import hat as _hat
from algorithms.geometry.se3 import transform_points
from algorithms.registration.symmetric.features import TriangleMesh

__all__ = ["SYMMETRY_TOL_REL", "model_symmetries", "pseudo_normals"]

#: A motion is a symmetry of the model when it moves no surface sample farther than this
#: fraction of the model's bounding-box diagonal from the surface (generated meshes deviate
#: from their design surfaces by 1e-5 m; real asymmetries move the surface by millimetres).
SYMMETRY_TOL_REL = 5e-4


@dataclass(frozen=True)
class _Surface:
    """Area moments of a mesh's surface (workpiece frame).

    Attributes:
        triangles: (F, 3, 3) [m] the faces' corners.
        area: (F,) [m^2] face areas.
        total: [m^2] their sum, > 0.
        centroid: (3,) [m] the area centroid.
        moments: (3,) eigenvalues of the second moment about it [m^2], ascending.
        axes: (3, 3) its principal axes, one per column.
    """

    triangles: FloatArray
    area: FloatArray
    total: float
    centroid: FloatArray
    moments: FloatArray
    axes: FloatArray


def model_symmetries(mesh: TriangleMesh, tol_rel: float = SYMMETRY_TOL_REL,
                     index: MeshIndex | None = None) -> FloatArray:
    """Rigid motions (K, 4, 4) of the workpiece frame that map the model onto itself.

    Always holds the identity first. Candidates: rotations about the area centroid of the
    surface that map the two largest flat-face normal clusters onto clusters of the same
    area and angle, the flips about the principal axes of the surface's second moment and,
    when two principal moments agree, the turns by 2 pi / n (n <= 12) about the third axis.
    A candidate is kept when none of 4000 area-uniform surface samples moves farther than
    ``tol_rel`` of the bounding-box diagonal from the surface.

    Args:
        mesh: the model (a trimesh; workpiece frame, metres).
        tol_rel: tolerance relative to the model's size.
        index: a prebuilt :class:`MeshIndex` of ``mesh``.

    Raises:
        AlgorithmError: a model without surface area.
    """
    index = index if index is not None else MeshIndex(mesh)
    known = _SYMMETRIES.setdefault(index, {})   # a property of the model: found once per index
    if tol_rel not in known:
        known[tol_rel] = _symmetries(index, tol_rel)
    return known[tol_rel].copy()


_SYMMETRIES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _symmetries(index: MeshIndex, tol_rel: float) -> FloatArray:
    surface = _surface(index)
    candidates = [np.eye(3), *_cluster_rotations(index.face_normals, surface),
                  *_principal_axis_motions(surface)]
    kept = _symmetries_among(candidates, index, surface, tol_rel * index.extent)
    c = surface.centroid
    out = np.empty((len(kept), 4, 4))
    for i, R in enumerate(kept):
        out[i] = np.eye(4)
        out[i, :3, :3] = R
        out[i, :3, 3] = c - R @ c
    return out


def _surface(index: MeshIndex) -> _Surface:
    tri = index.vertices[index.faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    total = area.sum()
    if not total > 0:
        raise AlgorithmError("the model has zero surface area")
    cen = tri.mean(axis=1)
    c = (area @ cen) / total
    d = cen - c
    M = (d * area[:, None]).T @ d / total
    evals, evecs = np.linalg.eigh(M)
    return _Surface(triangles=tri, area=area, total=total, centroid=c, moments=evals, axes=evecs)


def _cluster_rotations(face_normals: FloatArray, surface: _Surface) -> list[FloatArray]:
    """Rotations (3, 3) mapping the two largest flat-face normal clusters onto clusters of the
    same area (within 1 %) at the same angle."""
    area = surface.area
    key = np.round(face_normals, 4)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    c_area = np.bincount(inv, weights=area, minlength=len(uniq))
    normals = np.zeros((len(uniq), 3))
    np.add.at(normals, inv, face_normals * area[:, None])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    big = np.nonzero(c_area >= 0.01 * surface.total)[0]
    big = big[np.argsort(-c_area[big], kind="stable")]
    if len(big) < 2:
        return []
    i0 = big[0]
    others = [j for j in big[1:] if abs(np.dot(normals[i0], normals[j])) < 0.99]
    if not others:
        return []
    j0 = others[0]
    F0 = _frame(normals[i0], normals[j0])
    ang0 = np.dot(normals[i0], normals[j0])
    same_i = [k for k in big if abs(c_area[k] - c_area[i0]) <= 0.01 * c_area[i0]]
    same_j = [k for k in big if abs(c_area[k] - c_area[j0]) <= 0.01 * c_area[j0]]
    return [_frame(normals[a], normals[b]) @ F0.T for a in same_i for b in same_j
            if a != b and abs(np.dot(normals[a], normals[b]) - ang0) < 1e-3]


def _principal_axis_motions(surface: _Surface) -> list[FloatArray]:
    """Flips (3, 3) about the principal axes and, about an axis whose two other moments agree,
    the turns by 2 pi m / n (n <= 12); none when all three moments agree."""
    evals, evecs = surface.moments, surface.axes
    scale = max(evals[-1], 1e-300)
    gaps = np.diff(evals) / scale
    degenerate = gaps < 1e-3
    if degenerate.all():
        return []
    out = [2.0 * np.outer(evecs[:, i], evecs[:, i]) - np.eye(3) for i in range(3)]
    for j in np.nonzero(degenerate)[0]:
        # degenerate pair (j, j+1): turns about the unique axis
        u = evecs[:, 2 if j == 0 else 0]
        out += [_axis_angle(u, 2 * np.pi * m / n) for n in range(2, 13) for m in range(1, n)]
    return out


def _surface_samples(surface: _Surface) -> FloatArray:
    """(4000, 3) [m] area-uniform surface samples (fixed seed: the answer must not vary between calls)."""
    tri, area = surface.triangles, surface.area
    rng = np.random.default_rng(20010)
    f = rng.choice(len(area), size=4000, p=area / surface.total)
    u, v = rng.random(4000), rng.random(4000)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    return tri[f, 0] + u[:, None] * (tri[f, 1] - tri[f, 0]) + v[:, None] * (tri[f, 2] - tri[f, 0])


def _symmetries_among(candidates: list[FloatArray], index: MeshIndex, surface: _Surface,
                      tol: float) -> list[FloatArray]:
    """The distinct candidate rotations (about the centroid) that move no surface sample
    farther than ``tol`` [m] from the surface."""
    samples = _surface_samples(surface)
    c = surface.centroid
    keep: list[FloatArray] = []
    for R in candidates:
        # candidates closer than the tolerance to a kept one are the same motion
        if any(np.max(np.abs(R - K)) * index.extent < tol for K in keep):
            continue
        S = np.eye(4)
        S[:3, :3] = R
        S[:3, 3] = c - R @ c
        if np.max(np.abs(R - np.eye(3))) < 1e-12:
            keep.append(R)
            continue
        # a few samples first: most candidates fail at once
        if index.query(transform_points(S, samples[::25])).distance.max() > tol:
            continue
        if index.query(transform_points(S, samples)).distance.max() <= tol:
            keep.append(R)
    return keep


def _axis_angle(u: FloatArray, a: float) -> FloatArray:
    K = _hat(u)
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def _frame(a: FloatArray, b: FloatArray) -> FloatArray:
    e1 = a / np.linalg.norm(a)
    e2 = b - np.dot(b, e1) * e1
    e2 /= np.linalg.norm(e2)
    return np.column_stack([e1, e2, np.cross(e1, e2)])


# ------------------------------------------------------------------ pseudo-normals
_PSEUDO_CACHE: dict[int, tuple[MeshIndex, _PseudoNormalTable]] = {}


class _PseudoNormalTable:
    """Angle-weighted pseudo-normals of the faces, edges and vertices of a mesh."""

    def __init__(self, index: MeshIndex) -> None:
        V, F = index.vertices, index.faces
        fn = index.face_normals
        tri = V[F]
        ang = np.empty((len(F), 3))
        for k in range(3):
            e1 = tri[:, (k + 1) % 3] - tri[:, k]
            e2 = tri[:, (k + 2) % 3] - tri[:, k]
            cosang = np.einsum("ij,ij->i", e1, e2) / np.maximum(
                np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300)
            ang[:, k] = np.arccos(np.clip(cosang, -1.0, 1.0))
        vn = np.zeros_like(V)
        for k in range(3):
            np.add.at(vn, F[:, k], fn * ang[:, k:k + 1])
        self.vertex = vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        # local edge k of face f joins corners k and k+1
        edges = np.sort(np.stack([F, np.roll(F, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
        _, inv = np.unique(edges, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        en = np.zeros((inv.max() + 1, 3))
        np.add.at(en, inv, np.repeat(fn, 3, axis=0))
        en /= np.maximum(np.linalg.norm(en, axis=1, keepdims=True), 1e-300)
        self.edge = en[inv].reshape(len(F), 3, 3)
        # sharp edges: dihedral angle above 10 degrees, or a border (one face only)
        count = np.bincount(inv)
        tilt = np.einsum("fkj,fj->fk", self.edge, fn)
        self.sharp = (tilt < np.cos(np.radians(5.0))) | (count[inv].reshape(len(F), 3) == 1)
        self.face = fn
        self.faces = F
        self.V = V

    def at(self, face: IntArray, foot: FloatArray) -> FloatArray:
        """(N, 3) pseudo-normals at feet (N, 3) on faces (N,): the face's inside it, the edge's
        on an edge, the vertex's at a corner."""
        F = self.faces[face]
        a, b, c = self.V[F[:, 0]], self.V[F[:, 1]], self.V[F[:, 2]]
        ab, ac, ap = b - a, c - a, foot - a
        d00 = np.einsum("ij,ij->i", ab, ab)
        d01 = np.einsum("ij,ij->i", ab, ac)
        d11 = np.einsum("ij,ij->i", ac, ac)
        d20 = np.einsum("ij,ij->i", ap, ab)
        d21 = np.einsum("ij,ij->i", ap, ac)
        den = d00 * d11 - d01 * d01
        with np.errstate(divide="ignore", invalid="ignore"):
            v = (d11 * d20 - d01 * d21) / den
            w = (d00 * d21 - d01 * d20) / den
        u = 1.0 - v - w
        bary = np.column_stack([u, v, w])
        zero = np.abs(bary) < 1e-9
        zero[~np.isfinite(bary)] = False
        out = self.face[face].copy()
        nz = zero.sum(axis=1)
        rows = np.arange(len(face))
        # one zero coordinate: on the edge opposite that corner (local edge (k+1) % 3)
        e_rows = nz == 1
        if e_rows.any():
            k = np.argmax(zero[e_rows], axis=1)
            out[e_rows] = self.edge[face[e_rows], (k + 1) % 3]
        # two zeros: at the corner with the non-zero coordinate
        v_rows = nz >= 2
        if v_rows.any():
            k = np.argmax(~zero[v_rows], axis=1)
            out[v_rows] = self.vertex[F[rows[v_rows], k]]
        return out

    def sharp_edge_distance(self, face: IntArray, foot: FloatArray) -> FloatArray:
        """(N,) distance [m] from feet to the nearest sharp edge of their face (inf: none)."""
        F = self.faces[face]
        out = np.full(len(face), np.inf)
        for k in range(3):
            sharp = self.sharp[face, k]
            if not sharp.any():
                continue
            a = self.V[F[sharp, k]]
            b = self.V[F[sharp, (k + 1) % 3]]
            ab = b - a
            t = np.clip(np.einsum("ij,ij->i", foot[sharp] - a, ab) / np.maximum(
                np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
            dist = np.linalg.norm(foot[sharp] - (a + t[:, None] * ab), axis=1)
            out[sharp] = np.minimum(out[sharp], dist)
        return out


def pseudo_normals(index: MeshIndex) -> _PseudoNormalTable:
    """The (cached) angle-weighted pseudo-normal table of a mesh index."""
    key = id(index)
    hit = _PSEUDO_CACHE.get(key)
    if hit is None or hit[0] is not index:
        if len(_PSEUDO_CACHE) > 8:
            _PSEUDO_CACHE.clear()
        hit = (index, _PseudoNormalTable(index))
        _PSEUDO_CACHE[key] = hit
    return hit[1]

