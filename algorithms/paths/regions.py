"""Process regions and line pieces: what a contact process touches, and where its lines end.

A process region selects surface points by their CAD normal and position, in the workpiece
frame (:class:`ProcessRegion`):

* a normal cone: the normal within ``max_angle_rad`` of ``axis`` (default: the surfaces a
  ball-end tool reaches from above within a tilt limit: ``axis`` = +z);
* a box: the point inside ``[lo, hi]``;
* faces: the point on one of the given faces of the CAD mesh (a named feature's faces).

Lines end at sharp edges and steps (:func:`split_runs`): a line of contact or scan points is
cut wherever a point leaves the region, two consecutive points are farther apart than a gap
(a hole, a step seen from above, the part's border) or their normals turn by more than an
edge angle (a sharp CAD edge). Every run long enough is kept, so a face with a hole in it
gives two pieces per line, not the longest one.

Pieces on consecutive lines are chained into patches (:func:`chain_pieces`) so that the
cross-line triangulation of document 004 only ever pairs points of one smooth patch: a piece
continues the piece of the previous line that overlaps it most along the line direction and
lies within ``max_link_m`` of it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray, IntArray
from algorithms.errors import AlgorithmError

EDGE_DEG = 20.0        # normals turning more than this between consecutive points: a sharp edge
MIN_RUN_POINTS = 4     # a shorter run is dropped


class RegionError(AlgorithmError):
    """Bad process region or line-splitting input."""


@dataclass(frozen=True)
class ProcessRegion:
    """Which surface points a process touches (workpiece frame).

    Attributes:
        axis: (3,) unit axis of the normal cone.
        max_angle_rad: half-angle of the cone, in (0, pi/2].
        box_lo_m, box_hi_m: optional (3,) corners of a box the points must lie in.
        faces: optional indices of the mesh faces the points must lie on.
    """

    axis: tuple[float, ...] = (0.0, 0.0, 1.0)
    max_angle_rad: float = np.radians(60.0)
    box_lo_m: tuple[float, ...] | None = None
    box_hi_m: tuple[float, ...] | None = None
    faces: IntArray | None = None

    def __post_init__(self) -> None:
        a = np.asarray(self.axis, dtype=np.float64)
        if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-12:
            raise RegionError(f"region axis must be a finite non-zero 3-vector, got {self.axis!r}")
        if not (np.isfinite(self.max_angle_rad) and 0.0 < self.max_angle_rad <= np.pi / 2 + 1e-12):
            raise RegionError(f"region cone angle must lie in (0, 90] deg, got {np.degrees(self.max_angle_rad):g}")
        if (self.box_lo_m is None) != (self.box_hi_m is None):
            raise RegionError("a region box needs both corners")
        if self.box_lo_m is not None:
            lo, hi = np.asarray(self.box_lo_m, float), np.asarray(self.box_hi_m, float)
            if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(lo) & np.isfinite(hi)) \
                    or not np.all(lo < hi):
                raise RegionError(f"a region box needs finite corners with lo < hi, got "
                                  f"{self.box_lo_m}, {self.box_hi_m}")

    def select(self, points_m: ArrayLike, normals: ArrayLike, faces: ArrayLike | None = None) -> BoolArray:
        """(N,) bool: the points (N, 3) with unit normals (N, 3), on the mesh faces ``faces``
        (N,) (needed when the region names faces), that this region processes."""
        p = np.asarray(points_m, dtype=np.float64)
        n = np.asarray(normals, dtype=np.float64)
        a = np.asarray(self.axis, dtype=np.float64)
        a = a / np.linalg.norm(a)
        keep = n @ a >= np.cos(self.max_angle_rad) - 1e-12
        if self.box_lo_m is not None:
            keep &= np.all((p >= np.asarray(self.box_lo_m)) & (p <= np.asarray(self.box_hi_m)), axis=1)
        if self.faces is not None:
            if faces is None:
                raise RegionError("this region selects faces: the points' faces are needed")
            keep &= np.isin(np.asarray(faces), self.faces)
        return keep


def split_runs(points_m: ArrayLike, normals: ArrayLike, keep: ArrayLike | None = None, max_gap_m: float = 0.002,
               edge_rad: float = np.radians(EDGE_DEG), min_points: int = MIN_RUN_POINTS) -> list[IntArray]:
    """Index arrays of the runs of one ordered line (see the module docstring).

    Args:
        points_m: (n, 3) the line's points in order [m].
        normals: (n, 3) their unit normals (the CAD's: sharp edges stay sharp).
        keep: optional (n,) bool, points in the process region.
        max_gap_m: a larger step between consecutive points cuts the line [m].
        edge_rad: a larger turn of the normal between consecutive points cuts the line [rad].
        min_points: shorter runs are dropped.
    """
    p = np.asarray(points_m, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
        raise RegionError(f"points and normals must both be (n, 3), got {p.shape} and {n.shape}")
    k = np.ones(len(p), dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
    if len(p) == 0:
        return []
    cut = np.zeros(len(p) - 1, dtype=bool)
    if len(p) > 1:
        cut |= np.linalg.norm(np.diff(p, axis=0), axis=1) > max_gap_m
        cos = np.clip(np.einsum("ij,ij->i", n[:-1], n[1:]), -1.0, 1.0)
        cut |= cos < np.cos(edge_rad)
    runs, start = [], None
    for i in range(len(p)):
        if not k[i]:
            if start is not None:
                runs.append(np.arange(start, i))
            start = None
            continue
        if start is None:
            start = i
        if i == len(p) - 1 or cut[i] or not k[i + 1]:
            runs.append(np.arange(start, i + 1))
            start = None
    return [r for r in runs if len(r) >= min_points]


def chain_pieces(lines_pieces: Sequence[Sequence[FloatArray]], direction: ArrayLike,
                 max_link_m: float) -> list[list[tuple[int, int]]]:
    """Patches of pieces on consecutive lines (see the module docstring).

    Args:
        lines_pieces: per line (in order across the part), a list of (m, 3) point arrays.
        direction: (3,) the direction the lines run along.
        max_link_m: the largest distance between linked pieces [m].

    Returns:
        patches: lists of (line, piece) pairs, one piece per consecutive line.
    """
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    owner: dict[tuple[int, int], int] = {}
    patches: list[list[tuple[int, int]]] = []
    for i, pieces in enumerate(lines_pieces):
        prev = lines_pieces[i - 1] if i > 0 else []
        taken = set()
        for j, P in enumerate(pieces):
            best, best_overlap = None, 0.0
            lo, hi = float((P @ d).min()), float((P @ d).max())
            for jj, Q in enumerate(prev):
                if (i - 1, jj) not in owner or (i - 1, jj) in taken:
                    continue
                overlap = min(hi, float((Q @ d).max())) - max(lo, float((Q @ d).min()))
                if overlap <= best_overlap:
                    continue
                mid = P[len(P) // 2]
                if np.min(np.linalg.norm(Q - mid, axis=1)) > max_link_m:
                    continue
                best, best_overlap = jj, overlap
            if best is None:
                owner[(i, j)] = len(patches)
                patches.append([(i, j)])
            else:
                taken.add((i - 1, best))
                owner[(i, j)] = owner[(i - 1, best)]
                patches[owner[(i, j)]].append((i, j))
    return patches
