"""Document 000's features as geometry: closest points, and primitives fitted to mesh faces.

Features are given explicitly (``Feature.cylinder(point, axis, radius)``, ...), by name
(:func:`make_feature`) or as mesh faces (:meth:`Feature.from_mesh`: the primitive is fitted to
the faces and classified when no kind is given). Closest points are analytic for the
primitives and exact on the triangles (:class:`algorithms.geometry.mesh_index.MeshIndex`) for
extruded and free-form surfaces. Each feature carries its symmetry subgroup ``G_0``
(:mod:`.groups`, with the table and the twist conventions).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray, IntArray
from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.registration.symmetric.groups import (
    FEATURE_TABLE,
    FeatureInfo,
    SymmetryGroup,
    check_feature_type,
    perp_basis,
    symmetry_group,
)

__all__ = [
    "EXTRUDED_TOL_RAD",
    "FIT_NORMAL_TOL_RAD",
    "FIT_TOL_REL",
    "Feature",
    "FeatureProjection",
    "TriangleMesh",
    "make_feature",
]

FIT_TOL_REL = 1e-5
#: A fitted primitive must also agree with the faces' normals: at every face centroid the
#: primitive's normal is within this angle of the face normal (a tessellation's facets
#: deviate by half their angular size at most; two rings of vertices also lie on a sphere,
#: the eight corners of a box on a cylinder: the normals tell them apart).
FIT_NORMAL_TOL_RAD = float(np.radians(5.0))
#: Extruded surface: every face normal must be perpendicular to the sweep direction within
#: this angle [rad].
EXTRUDED_TOL_RAD = 1e-4


class TriangleMesh(Protocol):
    """A triangle mesh as the symmetric methods read it (a ``trimesh.Trimesh``, say)."""

    @property
    def vertices(self) -> ArrayLike:
        """(V, 3) [m] vertex coordinates, workpiece frame."""

    @property
    def faces(self) -> ArrayLike:
        """(F, 3) vertex indices of each triangle."""


@dataclass(frozen=True)
class FeatureProjection:
    """Closest points on a feature.

    Attributes:
        foot: (N, 3) [m] closest points on the feature (workpiece frame).
        normals: (N, m, 3) unit normals at the feet: m = 1 for surfaces and the 2D curves
            (in-plane normal), m = 2 for the 3D line (a basis of the plane across it).
        distance: (N,) [m] distance from the point to the feature (signed along the normal
            for surfaces: positive on the side the normal points to; unsigned for curves).
    """

    foot: FloatArray
    normals: FloatArray
    distance: FloatArray


@dataclass(frozen=True)
class Feature:
    """A feature of the table: geometry, closest points and symmetry subgroup.

    Create with the constructors (``Feature.plane``, ``Feature.cylinder``, ...), with
    :func:`make_feature` (by name) or :meth:`Feature.from_mesh` (fitted to mesh faces).

    Attributes:
        kind: one of :data:`FEATURE_TYPES`.
        group: its :class:`SymmetryGroup`.
        origin: (3,) [m] centre / apex / point on the axis, line or plane (workpiece frame).
        axis: (3,) unit axis / normal / direction (see :func:`symmetry_group`).
        radius: [m] sphere, cylinder, circle radius; 0 otherwise.
        half_angle: [rad] cone half-angle (0 < half_angle < pi/2); 0 otherwise.
        profile: (K, 2) [m] extruded profile polyline in the frame (e1, e2) across the
            direction (see ``group``), or None.
        closed: whether ``profile`` is a closed loop.
        fit_rms_m: RMS distance of the source vertices to a fitted primitive (0 when given
            explicitly).
        source: "explicit", "mesh faces" or "mesh".
    """

    kind: str
    group: SymmetryGroup
    origin: FloatArray
    axis: FloatArray
    radius: float = 0.0
    half_angle: float = 0.0
    profile: FloatArray | None = None
    closed: bool = False
    fit_rms_m: float = 0.0
    source: str = "explicit"
    index: MeshIndex | None = field(default=None, repr=False, compare=False)

    # ------------------------------------------------------------ constructors
    @classmethod
    def plane(cls, point: ArrayLike, normal: ArrayLike) -> Feature:
        """Plane through ``point`` [m] with unit ``normal`` (its outward side)."""
        g = symmetry_group("plane", point, normal)
        return cls("plane", g, g.origin, g.axis)

    @classmethod
    def sphere(cls, center: ArrayLike, radius: float) -> Feature:
        """Sphere of ``radius`` [m] about ``center`` [m]."""
        r = _positive(radius, "radius")
        g = symmetry_group("sphere", center)
        return cls("sphere", g, g.origin, g.axis, radius=r)

    @classmethod
    def cylinder(cls, point: ArrayLike, axis: ArrayLike, radius: float) -> Feature:
        """Cylinder of ``radius`` [m] about the line through ``point`` along ``axis``."""
        r = _positive(radius, "radius")
        g = symmetry_group("cylinder", point, axis)
        return cls("cylinder", g, g.origin, g.axis, radius=r)

    @classmethod
    def line3d(cls, point: ArrayLike, direction: ArrayLike) -> Feature:
        """Straight line through ``point`` [m] along ``direction``."""
        g = symmetry_group("line3d", point, direction)
        return cls("line3d", g, g.origin, g.axis)

    @classmethod
    def cone(cls, apex: ArrayLike, axis: ArrayLike, half_angle: float) -> Feature:
        """Cone (one nappe) with ``apex`` [m], opening along ``axis``, ``half_angle`` [rad]."""
        ha = float(half_angle)
        if not (np.isfinite(ha) and 0.0 < ha < np.pi / 2):
            raise AlgorithmError(f"half_angle must be in (0, pi/2) rad, got {half_angle!r}")
        g = symmetry_group("cone", apex, axis)
        return cls("cone", g, g.origin, g.axis, half_angle=ha)

    @classmethod
    def circle2d(cls, center: ArrayLike, radius: float) -> Feature:
        """Circle of ``radius`` [m] about ``center`` (x, y) [m] in the plane z = 0."""
        r = _positive(radius, "radius")
        g = symmetry_group("circle2d", center)
        return cls("circle2d", g, g.origin, g.axis, radius=r)

    @classmethod
    def line2d(cls, point: ArrayLike, direction: ArrayLike) -> Feature:
        """Line through ``point`` (x, y) [m] along ``direction`` (x, y) in the plane z = 0."""
        d = np.asarray(direction, dtype=np.float64).reshape(-1)
        if d.shape == (2,):
            d = np.array([d[0], d[1], 0.0])
        g = symmetry_group("line2d", point, d)
        return cls("line2d", g, g.origin, g.axis)

    @classmethod
    def extruded(cls, direction: ArrayLike, profile: ArrayLike | None = None, origin: ArrayLike = (0.0, 0.0, 0.0),
                 closed: bool = False, mesh: TriangleMesh | MeshIndex | None = None) -> Feature:
        """Surface swept along ``direction``: by a 2D ``profile`` polyline or as a mesh.

        Args:
            direction: (3,) sweep direction.
            profile: (K, 2) [m] polyline across the direction, in the frame (e1, e2) of
                ``group`` (``e1, e2 = perpendicular basis of direction``) about ``origin``.
            origin: (3,) [m] origin of the profile frame.
            closed: the profile is a closed loop.
            mesh: instead of a profile, the surface's triangles (workpiece frame); every face
                normal must be perpendicular to ``direction``.
        """
        g = symmetry_group("extruded", origin, direction)
        if (profile is None) == (mesh is None):
            raise AlgorithmError("an extruded feature needs exactly one of profile or mesh")
        if mesh is not None:
            index = _index(mesh)
            tilt = np.abs(index.face_normals @ g.axis)
            if tilt.max() > EXTRUDED_TOL_RAD:
                raise AlgorithmError(
                    f"mesh is not extruded along {g.axis.tolist()}: a face normal is "
                    f"{np.degrees(np.arcsin(min(tilt.max(), 1.0))):.3g} deg off perpendicular"
                )
            return cls("extruded", g, g.origin, g.axis, source="mesh", index=index)
        P = np.asarray(profile, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != 2 or len(P) < 2 or not np.all(np.isfinite(P)):
            raise AlgorithmError(f"profile must be (K, 2) with K >= 2 finite points [m], got {P.shape}")
        return cls("extruded", g, g.origin, g.axis, profile=P, closed=bool(closed))

    @classmethod
    def freeform(cls, mesh: TriangleMesh | MeshIndex) -> Feature:
        """A free-form surface given by its triangles (workpiece frame); G_0 = {1}."""
        index = _index(mesh)
        c = index.vertices.mean(axis=0)
        g = symmetry_group("freeform", c)
        return cls("freeform", g, g.origin, g.axis, source="mesh", index=index)

    @classmethod
    def from_mesh(cls, mesh: TriangleMesh, faces: ArrayLike | None = None, kind: str | None = None,
                  surface: str = "primitive", tol_rel: float = FIT_TOL_REL) -> Feature:
        """A feature from mesh faces: fit the primitive, or classify when ``kind`` is None.

        Classification tries plane, sphere, cylinder, cone, extruded in that order and takes
        the first whose fit is within ``tol_rel`` of the faces' size (RMS of the vertices'
        distances; for extruded: every normal perpendicular to the direction within
        ``EXTRUDED_TOL_RAD``); otherwise free-form.

        Args:
            mesh: a triangle mesh (workpiece frame, metres).
            faces: indices of the faces that form the feature (default: all).
            kind: a table type to fit (not circle2d/line2d/line3d: those are not surfaces),
                or None to classify.
            surface: ``"primitive"``: closest points on the fitted analytic surface (the
                design surface, free of facets); ``"faces"``: on the triangles themselves.
            tol_rel: fit tolerance relative to the faces' bounding-box diagonal.

        Raises:
            AlgorithmError: unknown kind, a curve kind, no faces, or faces that do not fit
                the requested kind within the tolerance (the message gives the RMS).
        """
        if surface not in ("primitive", "faces"):
            raise AlgorithmError(f"surface must be 'primitive' or 'faces', got {surface!r}")
        if kind is not None:
            check_feature_type(kind)
            if kind in ("circle2d", "line2d", "line3d"):
                raise AlgorithmError(
                    f"a {kind} is a curve, not a surface: give it explicitly "
                    f"(Feature.{kind}(...)), not as mesh faces"
                )
        V = np.asarray(mesh.vertices, dtype=np.float64)
        F = np.asarray(mesh.faces, dtype=np.int64)
        if faces is not None:
            idx = np.asarray(faces, dtype=np.int64).reshape(-1)
            if len(idx) == 0 or idx.min() < 0 or idx.max() >= len(F):
                raise AlgorithmError(f"faces must be indices into the mesh's {len(F)} faces")
            F = F[np.unique(idx)]
        if len(F) == 0:
            raise AlgorithmError("no faces given")
        used, inv = np.unique(F, return_inverse=True)
        sub_v = V[used]
        sub_f = inv.reshape(-1, 3)
        sub = _SimpleMesh(sub_v, sub_f)
        tri = sub_v[sub_f]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area = 0.5 * np.linalg.norm(cross, axis=1)
        ok = area > 0
        normals = np.zeros_like(cross)
        normals[ok] = cross[ok] / (2.0 * area[ok, None])
        size = float(np.linalg.norm(np.ptp(sub_v, axis=0)))
        tol = tol_rel * max(size, 1e-300)
        kinds = [kind] if kind is not None else ["plane", "sphere", "cylinder", "cone", "extruded"]
        last_rms = np.inf
        for k in kinds:
            if k == "freeform":
                break
            feat, rms = _fit(k, sub_v, normals, area, tri)
            if feat is not None and k != "extruded" and rms <= tol:
                # the primitive's normals at the face centroids must match the faces'
                pn = feat.closest(tri.mean(axis=1)).normals[:, 0, :]
                cosang = np.abs(np.einsum("ij,ij->i", pn, normals))[area > 0]
                if cosang.size and cosang.min() < np.cos(FIT_NORMAL_TOL_RAD):
                    rms = max(rms, float(np.arccos(np.clip(cosang.min(), -1, 1))) * size)
            last_rms = rms
            if feat is not None and rms <= tol:
                if k == "extruded" or surface == "faces":
                    index = MeshIndex(sub)
                    return cls(feat.kind, feat.group, feat.origin, feat.axis, feat.radius,
                               feat.half_angle, None, False, rms, "mesh faces", index)
                return cls(feat.kind, feat.group, feat.origin, feat.axis, feat.radius,
                           feat.half_angle, None, False, rms, "mesh faces")
        if kind is not None and kind != "freeform":
            raise AlgorithmError(
                f"the faces are not a {kind}: fit RMS {last_rms:.3g} m exceeds "
                f"{tol:.3g} m ({tol_rel:g} of their {size:.4g} m size)"
            )
        f = cls.freeform(sub)
        return cls("freeform", f.group, f.origin, f.axis, source="mesh faces", index=f.index)

    # ------------------------------------------------------------ properties
    @property
    def info(self) -> FeatureInfo:
        """The feature's row of the table."""
        return FEATURE_TABLE[self.kind]

    @property
    def planar(self) -> bool:
        """True for the 2D features (plane z = 0, ambient group SE(2))."""
        return self.group.planar

    # ------------------------------------------------------------ geometry
    def closest(self, points: ArrayLike) -> FeatureProjection:
        """Closest points on the feature to ``points`` (N, 3) [m], workpiece frame.

        For the 2D features (N, 2) points are accepted (z = 0 is implied).
        """
        Y = _points(points, self.planar)
        k = self.kind
        c, a = self.origin, self.axis
        n_pts = len(Y)
        if self.index is not None:
            cp = self.index.query(Y)
            d = np.einsum("ij,ij->i", Y - cp.foot, cp.normal)
            return FeatureProjection(cp.foot, cp.normal[:, None, :], d)
        w = Y - c
        if k in ("plane", "line2d"):
            n = a if k == "plane" else np.array([-a[1], a[0], 0.0])
            s = w @ n
            foot = Y - s[:, None] * n
            return FeatureProjection(foot, np.broadcast_to(n, (n_pts, 1, 3)).copy(), s)
        if k == "sphere":
            r = np.linalg.norm(w, axis=1)
            u = _safe_dirs(w, r, np.array([0.0, 0.0, 1.0]))
            return FeatureProjection(c + self.radius * u, u[:, None, :], r - self.radius)
        if k in ("cylinder", "circle2d", "line3d", "cone"):
            h = w @ a
            radial = w - h[:, None] * a
            rho = np.linalg.norm(radial, axis=1)
            e1, e2 = perp_basis(a)
            u = _safe_dirs(radial, rho, e1)
            if k in ("cylinder", "circle2d"):
                foot = c + h[:, None] * a + self.radius * u
                return FeatureProjection(foot, u[:, None, :], rho - self.radius)
            if k == "line3d":
                foot = c + h[:, None] * a
                nrm = np.broadcast_to(np.stack([e1, e2]), (n_pts, 2, 3)).copy()
                return FeatureProjection(foot, nrm, rho)
            # cone: work in the half-plane through the axis and the point
            ca, sa = np.cos(self.half_angle), np.sin(self.half_angle)
            gen = ca * a + sa * u
            nrm = -sa * a + ca * u
            t = h * ca + rho * sa
            foot = c + np.maximum(t, 0.0)[:, None] * gen
            d = h * (-sa) + rho * ca
            behind = t < 0  # closest point is the apex
            if behind.any():
                r_apex = np.linalg.norm(w[behind], axis=1)
                nrm[behind] = _safe_dirs(w[behind], r_apex, -a)
                d[behind] = r_apex
            return FeatureProjection(foot, nrm[:, None, :], d)
        if k == "extruded":
            return _closest_on_profile(self, Y)
        raise AlgorithmError(f"a {k} feature needs a mesh for closest points")  # pragma: no cover


class _SimpleMesh:
    """Minimal mesh (vertices, faces) for MeshIndex."""

    def __init__(self, vertices: FloatArray, faces: IntArray) -> None:
        self.vertices = vertices
        self.faces = faces


def _index(mesh: TriangleMesh | MeshIndex) -> MeshIndex:
    if isinstance(mesh, MeshIndex):
        return mesh
    return MeshIndex(mesh)


def _positive(x: float, name: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise AlgorithmError(f"{name} must be a positive length [m], got {x!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise AlgorithmError(f"{name} must be a positive length [m], got {x!r}")
    return v


def _points(points: ArrayLike, planar: bool) -> FloatArray:
    Y = np.asarray(points, dtype=np.float64)
    if planar and Y.ndim == 2 and Y.shape[1] == 2:
        Y = np.hstack([Y, np.zeros((len(Y), 1))])
    if Y.ndim != 2 or Y.shape[1] != 3:
        raise AlgorithmError(f"points must be (N, 3){' or (N, 2)' if planar else ''}, got {Y.shape}")
    return Y


def _safe_dirs(w: FloatArray, r: FloatArray, fallback: FloatArray) -> FloatArray:
    out = np.empty_like(w)
    good = r > 1e-300
    out[good] = w[good] / r[good, None]
    out[~good] = fallback
    return out


def _closest_on_profile(feat: Feature, Y: FloatArray) -> FeatureProjection:
    """Closest points on an extruded polyline profile (exact, all segments)."""
    a = feat.axis
    e1, e2 = perp_basis(a)
    w = Y - feat.origin
    h = w @ a
    q = np.column_stack([w @ e1, w @ e2])
    P = feat.profile
    if P is None:
        raise AlgorithmError("an extruded feature needs a profile or a mesh for closest points")
    if feat.closed:
        A, B = P, np.roll(P, -1, axis=0)
    else:
        A, B = P[:-1], P[1:]
    AB = B - A
    L2 = np.einsum("ij,ij->i", AB, AB)
    L2 = np.where(L2 > 0, L2, 1.0)
    best_d2 = np.full(len(Y), np.inf)
    best_f = np.zeros((len(Y), 2))
    best_seg = np.zeros(len(Y), dtype=np.int64)
    chunk = max(1, 2_000_000 // max(len(A), 1))
    for s in range(0, len(Y), chunk):
        qq = q[s:s + chunk]
        t = np.clip(((qq[:, None, :] - A[None]) * AB[None]).sum(axis=2) / L2[None], 0.0, 1.0)
        f = A[None] + t[..., None] * AB[None]
        d2 = ((qq[:, None, :] - f) ** 2).sum(axis=2)
        j = np.argmin(d2, axis=1)
        rows = np.arange(len(qq))
        best_d2[s:s + chunk] = d2[rows, j]
        best_f[s:s + chunk] = f[rows, j]
        best_seg[s:s + chunk] = j
    diff = q - best_f
    dist = np.sqrt(best_d2)
    seg_dir = AB[best_seg] / np.sqrt(L2[best_seg])[:, None]
    seg_n = np.column_stack([seg_dir[:, 1], -seg_dir[:, 0]])
    n2 = np.where((dist > 1e-300)[:, None], diff / np.maximum(dist, 1e-300)[:, None], seg_n)
    foot = feat.origin + h[:, None] * a + best_f[:, :1] * e1 + best_f[:, 1:] * e2
    normal = n2[:, :1] * e1 + n2[:, 1:] * e2
    signed = np.einsum("ij,ij->i", diff, seg_n)
    d = np.where(signed >= 0, dist, -dist)
    return FeatureProjection(foot, normal[:, None, :], d)


def _fit(kind: str, V: FloatArray, N: FloatArray, area: FloatArray, tri: FloatArray) -> tuple[Feature | None, float]:
    """Fit ``kind`` to vertices V with face normals N (area weights); returns (feature, rms)."""
    w = area / max(area.sum(), 1e-300)
    try:
        if kind == "plane":
            c = V.mean(axis=0)
            _, vecs = np.linalg.eigh((V - c).T @ (V - c))
            n = vecs[:, 0]
            if np.dot(n, w @ N) < 0:
                n = -n
            rms = float(np.sqrt(np.mean(((V - c) @ n) ** 2)))
            return Feature.plane(c, n), rms
        if kind == "sphere":
            A = np.hstack([2.0 * V, np.ones((len(V), 1))])
            b = np.einsum("ij,ij->i", V, V)
            sol, *_ = np.linalg.lstsq(A, b, rcond=None)
            c = sol[:3]
            r2 = sol[3] + c @ c
            if not r2 > 0:
                return None, np.inf
            r = float(np.sqrt(r2))
            rms = float(np.sqrt(np.mean((np.linalg.norm(V - c, axis=1) - r) ** 2)))
            return Feature.sphere(c, r), rms
        if kind == "cylinder":
            M = (N * w[:, None]).T @ N
            _, vecs = np.linalg.eigh(M)
            a = vecs[:, 0]
            e1, e2 = perp_basis(a)
            p2 = np.column_stack([V @ e1, V @ e2])
            A = np.hstack([2.0 * p2, np.ones((len(V), 1))])
            b = np.einsum("ij,ij->i", p2, p2)
            sol, *_ = np.linalg.lstsq(A, b, rcond=None)
            r2 = sol[2] + sol[:2] @ sol[:2]
            if not r2 > 0:
                return None, np.inf
            r = float(np.sqrt(r2))
            c = sol[0] * e1 + sol[1] * e2 + (V.mean(axis=0) @ a) * a
            rho = np.linalg.norm(p2 - sol[:2], axis=1)
            rms = float(np.sqrt(np.mean((rho - r) ** 2)))
            return Feature.cylinder(c, a, r), rms
        if kind == "cone":
            nm = w @ N
            C = ((N - nm) * w[:, None]).T @ (N - nm)
            _, vecs = np.linalg.eigh(C)
            a = vecs[:, 0]
            # apex: every face plane passes through it
            cen = tri.mean(axis=1)
            M = (N * w[:, None]).T @ N
            rhs = (N * w[:, None]).T @ np.einsum("ij,ij->i", N, cen)
            if np.linalg.cond(M) > 1e12:
                return None, np.inf
            apex = np.linalg.solve(M, rhs)
            h = (V - apex) @ a
            if h.mean() < 0:
                a, h = -a, -h
            rho = np.linalg.norm((V - apex) - h[:, None] * a, axis=1)
            ha = float(np.arctan2(np.sum(rho * h), np.sum(h * h)))
            if not 0 < ha < np.pi / 2:
                return None, np.inf
            feat = Feature.cone(apex, a, ha)
            rms = float(np.sqrt(np.mean(feat.closest(V).distance ** 2)))
            return feat, rms
        if kind == "extruded":
            M = (N * w[:, None]).T @ N
            _, vecs = np.linalg.eigh(M)
            d = vecs[:, 0]
            tilt = float(np.max(np.abs(N[area > 0] @ d)))
            g = Feature("extruded", symmetry_group("extruded", V.mean(axis=0), d), V.mean(axis=0), d)
            # report the tilt as a length: sin(tilt) times the size, comparable with tol
            size = float(np.linalg.norm(np.ptp(V, axis=0)))
            return g, (0.0 if tilt <= EXTRUDED_TOL_RAD else tilt * size)
    except np.linalg.LinAlgError:
        return None, np.inf
    return None, np.inf  # pragma: no cover


def make_feature(kind: str, **params: object) -> Feature:
    """A feature by name: ``make_feature("cylinder", point=..., axis=..., radius=...)``.

    Parameters per kind: circle2d (center, radius), line2d (point, direction), sphere
    (center, radius), plane (point, normal), line3d (point, direction), cylinder (point,
    axis, radius), cone (apex, axis, half_angle), extruded (direction, profile | mesh,
    origin, closed), freeform (mesh).

    Raises:
        AlgorithmError: unknown kind (lists the valid ones) or wrong parameters.
    """
    check_feature_type(kind)
    ctor = getattr(Feature, kind)
    try:
        return ctor(**params)
    except TypeError as exc:
        raise AlgorithmError(f"bad parameters for a {kind}: {exc}") from None
