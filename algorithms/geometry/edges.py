"""Sharp edges of a triangle mesh and how far points are from them.

Near a sharp edge the closest face of a point flips with a sub-millimetre change of pose, so
a point-to-plane fit that is unsure of the pose by that much can mistake a point of one face
for one of its neighbour and draw information from the mistake.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from algorithms.arraytypes import ArrayLike, FloatArray

__all__ = ["SHARP_EDGE_DEG", "SharpEdges"]

#: Faces meeting at more than this angle make a sharp edge.
SHARP_EDGE_DEG = 30.0


class SharpEdges:
    """The mesh's sharp edges, sampled every ``step_m`` for distance queries.

    Args:
        vertices: (V, 3), faces: (F, 3) the mesh (any frame; queries in the same frame).
        angle_deg: the dihedral angle above which an edge is sharp.
        step_m: sample spacing along the edges [m]; distances are exact to ``step_m / 2``.
    """

    def __init__(self, vertices: ArrayLike, faces: ArrayLike, angle_deg: float = SHARP_EDGE_DEG,
                 step_m: float = 5e-5) -> None:
        mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64),
                               process=False)
        edges = mesh.face_adjacency_edges[mesh.face_adjacency_angles > np.radians(angle_deg)]
        samples = []
        for a, b in mesh.vertices[edges]:
            n = max(2, int(np.ceil(np.linalg.norm(b - a) / step_m)) + 1)
            samples.append(np.linspace(a, b, n))
        self.step_m = step_m
        self.tree = cKDTree(np.vstack(samples)) if samples else None

    def distance(self, points: ArrayLike) -> FloatArray:
        """(N,) distance of each point to the nearest sharp edge [m] (inf without edges)."""
        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if self.tree is None:
            return np.full(len(P), np.inf)
        return self.tree.query(P)[0]
