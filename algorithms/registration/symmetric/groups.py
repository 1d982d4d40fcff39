"""Symmetry subgroups G_0 of document 000's features (Table 1).

A feature is a surface (or a curve) that some rigid motions leave unchanged: the *symmetry
subgroup* ``G_0`` of SE(3). Points measured on it cannot fix the pose along ``G_0``; they fix
it only on the homogeneous space ``SE(3)/G_0``, whose dimension is the number of pose
directions the feature can fix. Document 000's table:

=============  ====================  ==========================================  =========
feature        G_0                   the motions that leave it unchanged          dim Q
=============  ====================  ==========================================  =========
``circle2d``   SO(2)                 rotation about the centre (in its plane)     2
``line2d``     T(1)                  translation along the line (in its plane)    2
``sphere``     SO(3)                 rotations about the centre                   3
``plane``      SE(2)                 rotation about the normal, in-plane moves    3
``line3d``     SO(2) x T(1)          rotation about and translation along it      4
``cylinder``   SO(2) x T(1)          rotation about and translation along axis    4
``cone``       SO(2)                 rotation about the axis                      5
``extruded``   T(1)                  translation along the sweep direction        5
``freeform``   {1}                   the identity only                            6
=============  ====================  ==========================================  =========

The two 2D features live in the plane z = 0 of the workpiece frame and their problem is
planar: the ambient group is SE(2) (rotation about z, translation in x and y), so
``dim Q = 3 - dim G_0``. The others live in SE(3): ``dim Q = 6 - dim G_0``.

Conventions (those of :mod:`algorithms.registration.local` and :mod:`algorithms.registration.uncertainty`):

* A twist is a 6-vector ``[omega, v]`` (angular part first; rad and m) of the right
  perturbation in the **workpiece frame**: the pose ``T`` becomes ``T @ exp_se3(xi)``, which
  moves the model point ``x`` (workpiece frame) by ``omega x x + v``. Twists are taken about
  the workpiece origin: a unit rotation about the axis ``a`` through ``c`` is
  ``[a, c x a]``; a unit translation along ``d`` is ``[0, d]``.
* ``G_0`` is a subgroup of motions in the workpiece frame: ``exp(xi)`` with ``xi`` in its
  Lie algebra ``g_0`` maps the feature onto itself.
* The complement ``m_0`` (``m_0 + g_0 = se(3)``, Proposition 2) is the orthogonal complement
  for the metric ``L^2 |omega|^2 + |v_c|^2`` with ``v_c`` the velocity of the feature's
  reference point ``c`` (its centre, a point on its axis or plane) and ``L`` any length: in
  the feature's local frame (origin ``c``, z along its axis or normal) both bases are
  coordinate axes, so the choice does not depend on ``L``. Bases are unit (``|omega| = 1``
  for rotations, ``|v| = 1`` for translations).

Build a group with :func:`symmetry_group` (a table feature) or :func:`other_group` (a
numerical basis found in data, :mod:`.detect`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray
from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import log_se3

__all__ = [
    "FEATURE_TABLE",
    "FEATURE_TYPES",
    "FeatureInfo",
    "SymmetryGroup",
    "check_feature_type",
    "other_group",
    "perp_basis",
    "symmetry_group",
]

FEATURE_TYPES: tuple[str, ...] = (
    "circle2d", "line2d", "sphere", "plane", "line3d", "cylinder", "cone", "extruded", "freeform",
)
"""The feature types of document 000's Table 1, in the table's order."""

#: A primitive fitted to mesh faces is accepted when the RMS distance of the faces' vertices
#: to it is below this fraction of the faces' bounding-box diagonal (generated and CAD meshes


@dataclass(frozen=True)
class FeatureInfo:
    """One row of document 000's Table 1."""

    name: str
    group: str
    description: str
    quotient_dim: int
    planar: bool

    @property
    def group_dim(self) -> int:
        return (3 if self.planar else 6) - self.quotient_dim


FEATURE_TABLE: dict[str, FeatureInfo] = {
    "circle2d": FeatureInfo("circle2d", "SO(2)", "rotation about the centre", 2, True),
    "line2d": FeatureInfo("line2d", "T(1)", "translation along the line", 2, True),
    "sphere": FeatureInfo("sphere", "SO(3)", "rotations about the centre", 3, False),
    "plane": FeatureInfo("plane", "SE(2)", "rotation about the normal and translations in the plane", 3, False),
    "line3d": FeatureInfo("line3d", "SO(2)xT(1)", "rotation about the line and translation along it", 4, False),
    "cylinder": FeatureInfo("cylinder", "SO(2)xT(1)", "rotation about the axis and translation along it", 4, False),
    "cone": FeatureInfo("cone", "SO(2)", "rotation about the axis", 5, False),
    "extruded": FeatureInfo("extruded", "T(1)", "translation along the sweep direction", 5, False),
    "freeform": FeatureInfo("freeform", "{1}", "the identity only", 6, False),
}

# Local-frame basis of g_0 for each kind: indices into [wx, wy, wz, vx, vy, vz] of the
# feature frame (origin c, z along the axis / normal; for line2d x along the line).
_G0_LOCAL = {
    "circle2d": (2,),
    "line2d": (3,),
    "sphere": (0, 1, 2),
    "plane": (2, 3, 4),
    "line3d": (2, 5),
    "cylinder": (2, 5),
    "cone": (2,),
    "extruded": (5,),
    "freeform": (),
}
_PLANAR_AMBIENT = (2, 3, 4)  # se(2) inside se(3): wz, vx, vy


def check_feature_type(kind: object) -> str:
    """Return ``kind`` if it names a feature of the table, else raise listing the valid ones."""
    if not isinstance(kind, str) or kind not in FEATURE_TABLE:
        raise AlgorithmError(
            f"unknown feature type {kind!r}; valid types are: {', '.join(FEATURE_TYPES)}"
        )
    return kind


def _unit(v: ArrayLike, name: str) -> FloatArray:
    v = np.asarray(v, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise AlgorithmError(f"{name} must be a finite 3-vector, got {np.asarray(v).tolist()}")
    n = np.linalg.norm(v)
    if not n > 1e-12:
        raise AlgorithmError(f"{name} must be a non-zero vector")
    return v / n


def _point(p: ArrayLike, name: str) -> FloatArray:
    p = np.asarray(p, dtype=np.float64).reshape(-1)
    if p.shape == (2,):
        p = np.array([p[0], p[1], 0.0])
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise AlgorithmError(f"{name} must be a finite 3-vector [m], got {np.asarray(p).tolist()}")
    return p


def perp_basis(a: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Two unit vectors completing ``a`` to a right-handed frame (e1, e2, a), deterministic."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(helper, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    return e1, e2


def _adjoint_rows(local: FloatArray, R: FloatArray, c: FloatArray) -> FloatArray:
    """Twists (k, 6) given in a frame (R, c) as twists about the workpiece origin."""
    if len(local) == 0:
        return np.zeros((0, 6))
    w = local[:, :3] @ R.T
    v = local[:, 3:] @ R.T + np.cross(c, w)
    return np.hstack([w, v])


def _rotation_angle(R: FloatArray) -> float:
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def _angle_between(a: FloatArray, b: FloatArray) -> float:
    return float(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b)))


@dataclass(frozen=True)
class SymmetryGroup:
    """A symmetry subgroup ``G_0`` with bases of its Lie algebra and of the complement.

    Build one with :func:`symmetry_group` (or take ``Feature.group``).

    Attributes:
        kind: the table feature whose ``G_0`` this is, or ``"other"`` (a subgroup found in
            data that the table does not name; then ``g0``/``m0`` are numerical bases).
        origin: (3,) [m] reference point, workpiece frame: the centre (sphere, circle), a
            point on the axis or line, a point on the plane.
        axis: (3,) unit axis (line, cylinder, cone), normal (plane), sweep direction
            (extruded), line direction (line2d); +z for the 2D circle; unused otherwise.
        g0: (r, 6) unit twists ``[omega, v]`` about the workpiece origin spanning ``g_0``.
        m0: (q, 6) unit twists spanning the complement ``m_0`` (q = dim SE(3)/G_0, or
            dim SE(2)/G_0 for the planar features).
        planar: True for the 2D features (ambient group SE(2) in the plane z = 0).
        name: the group's name (``"SO(2)xT(1)"``, ...).
    """

    kind: str
    origin: FloatArray
    axis: FloatArray
    g0: FloatArray
    m0: FloatArray
    planar: bool
    name: str

    @property
    def dim(self) -> int:
        """dim G_0: the number of free pose directions."""
        return int(len(self.g0))

    @property
    def quotient_dim(self) -> int:
        """dim SE(3)/G_0 (SE(2)/G_0 when planar): the number of fixed pose directions."""
        return int(len(self.m0))

    def distance(self, D: ArrayLike) -> tuple[float, float]:
        """How far a motion ``D`` (4x4, workpiece frame) is from ``G_0``.

        Returns:
            (angle [rad], distance [m]): zero for every element of ``G_0``. For the table's
            groups these are exact geometric measures: the tilt of the axis or normal that
            ``D`` causes and the offset of the reference point off its orbit (a rotation of a
            free-form feature is its full angle). For ``"other"`` they are the angular and
            linear norms of the part of ``log(D)`` outside ``g_0``.
        """
        D = np.asarray(D, dtype=np.float64)
        R, t = D[:3, :3], D[:3, 3]
        c, a = self.origin, self.axis
        dc = R @ c + t - c
        k = self.kind
        if k == "freeform":
            return _rotation_angle(R), float(np.linalg.norm(t))
        if k == "extruded":
            return _rotation_angle(R), float(np.linalg.norm(t - np.dot(t, a) * a))
        if k == "sphere":
            return 0.0, float(np.linalg.norm(dc))
        if k in ("cone", "circle2d"):
            return _angle_between(R @ a, a), float(np.linalg.norm(dc))
        if k in ("cylinder", "line3d"):
            return _angle_between(R @ a, a), float(np.linalg.norm(dc - np.dot(dc, a) * a))
        if k == "plane":
            return _angle_between(R @ a, a), float(abs(np.dot(dc, a)))
        if k == "line2d":
            return _rotation_angle(R), float(np.linalg.norm(dc - np.dot(dc, a) * a))
        # "other": remove the g_0 part of the logarithm (first order)
        xi = log_se3(D)
        if len(self.g0):
            coef, *_ = np.linalg.lstsq(self.g0.T, xi, rcond=None)
            xi = xi - self.g0.T @ coef
        return float(np.linalg.norm(xi[:3])), float(np.linalg.norm(xi[3:]))

    def contains(self, D: ArrayLike, tol_rad: float = 1e-6, tol_m: float = 1e-6) -> bool:
        """Whether the motion ``D`` (workpiece frame) lies in ``G_0`` within the tolerances."""
        ang, dist = self.distance(D)
        return ang <= tol_rad and dist <= tol_m

    def describe(self) -> str:
        """One line: the group, its geometry and the free and fixed counts."""
        c = ", ".join(f"{v:.6g}" for v in self.origin)
        a = ", ".join(f"{v:.6g}" for v in self.axis)
        geo = {
            "circle2d": f"centre ({c}) m",
            "line2d": f"through ({c}) m along ({a})",
            "sphere": f"centre ({c}) m",
            "plane": f"normal ({a}) through ({c}) m",
            "line3d": f"axis ({a}) through ({c}) m",
            "cylinder": f"axis ({a}) through ({c}) m",
            "cone": f"axis ({a}) through ({c}) m",
            "extruded": f"direction ({a})",
            "freeform": "",
            "other": "numerical basis",
        }[self.kind]
        return (f"{self.kind} G_0 = {self.name} {geo}: {self.dim} free, "
                f"{self.quotient_dim} fixed direction(s)").replace("  ", " ")


def symmetry_group(kind: str, origin: ArrayLike = (0.0, 0.0, 0.0), axis: ArrayLike | None = None) -> SymmetryGroup:
    """The subgroup ``G_0`` of a table feature, with bases of ``g_0`` and ``m_0``.

    Args:
        kind: one of :data:`FEATURE_TYPES`.
        origin: (3,) [m] reference point in the workpiece frame (centre, point on the axis,
            line or plane). For the 2D features a 2-vector (x, y) is accepted; z must be 0.
        axis: (3,) axis / normal / direction (normalised here). For ``circle2d`` it is the
            plane normal and must be +-z; for ``line2d`` the line direction, in the xy plane.
            Default: +x for ``line2d``, +z otherwise.

    Raises:
        AlgorithmError: unknown kind (the message lists the valid ones), bad vectors, or a
            2D feature outside the plane z = 0.
    """
    check_feature_type(kind)
    info = FEATURE_TABLE[kind]
    c = _point(origin, "origin")
    if axis is None:
        axis = (1.0, 0.0, 0.0) if kind == "line2d" else (0.0, 0.0, 1.0)
    a = _unit(axis, "axis")
    if info.planar:
        if abs(c[2]) > 1e-12:
            raise AlgorithmError(f"a {kind} lies in the plane z = 0; its origin has z = {c[2]:g}")
        if kind == "circle2d":
            a = np.array([0.0, 0.0, 1.0])
        else:
            if abs(a[2]) > 1e-9:
                raise AlgorithmError(f"a line2d direction must lie in the xy plane, got {a.tolist()}")
            a = np.array([a[0], a[1], 0.0]) / np.hypot(a[0], a[1])
    if kind == "line2d":
        e1 = a
        e3 = np.array([0.0, 0.0, 1.0])
        R = np.column_stack([e1, np.cross(e3, e1), e3])
    elif kind in ("sphere", "freeform"):
        R = np.eye(3)
        a = np.array([0.0, 0.0, 1.0])
    else:
        e1, e2 = perp_basis(a)
        R = np.column_stack([e1, e2, a])
    eye = np.eye(6)
    g_idx = _G0_LOCAL[kind]
    ambient = _PLANAR_AMBIENT if info.planar else tuple(range(6))
    m_idx = tuple(i for i in ambient if i not in g_idx)
    g0 = _adjoint_rows(eye[list(g_idx)], R, c) if g_idx else np.zeros((0, 6))
    m0 = _adjoint_rows(eye[list(m_idx)], R, c)
    return SymmetryGroup(kind, c, a, g0, m0, info.planar, info.group)


def other_group(g0: ArrayLike, origin: ArrayLike, length: float) -> SymmetryGroup:
    """A subgroup not in the table, from a numerical basis of its Lie algebra.

    ``m_0`` is the orthogonal complement for ``L^2 |omega|^2 + |v_c|^2`` about ``origin``.

    Args:
        g0: (r, 6) twists about the workpiece origin.
        origin: (3,) [m] reference point (e.g. the centroid of the measured points).
        length: L [m], the characteristic length of the metric.
    """
    c = _point(origin, "origin")
    G = np.atleast_2d(np.asarray(g0, dtype=np.float64)).reshape(-1, 6)
    # to scaled coordinates about c: [L omega, v + omega x c]
    S = np.hstack([G[:, :3] * length, G[:, 3:] + np.cross(G[:, :3], c)])
    U, s, Vt = np.linalg.svd(S, full_matrices=True)
    r = int(np.sum(s > 1e-9 * max(s.max(initial=0.0), 1e-300)))

    def back(rows: FloatArray) -> FloatArray:
        w = rows[:, :3] / length
        return np.hstack([w, rows[:, 3:] - np.cross(w, c)])

    g = back(Vt[:r])
    m = back(Vt[r:])
    # unit: |omega| = 1 when there is rotation, else |v| = 1
    def norm_rows(X: FloatArray) -> FloatArray:
        out = X.copy()
        for i, x in enumerate(X):
            nw = np.linalg.norm(x[:3])
            out[i] = x / (nw if nw > 1e-9 else np.linalg.norm(x[3:]))
        return out

    return SymmetryGroup("other", c, np.array([0.0, 0.0, 1.0]), norm_rows(g), norm_rows(m), False,
                         f"{r}-dimensional subgroup not in the table")
