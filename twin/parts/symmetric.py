"""Generated parts for symmetric and hybrid localization (document 000, sections 4 and 5).

Each generator returns one watertight, outward-wound ``trimesh.Trimesh`` in the workpiece
frame (metres, z up, resting on z = 0, centred in x and y), built with the meshing kernel
(:mod:`twin.parts.kernel`) like the other parts; :mod:`twin.parts` lists them in its
registry so that scenarios can name them (``workpiece.shape``):

* ``bore_and_face``: a plate with a blind cylindrical bore; measured on the bore and the top
  face, the points leave only the rotation about the bore axis free (G_0 = SO(2)).
* ``sphere``: a reference sphere on a stem and a base plate (a calibration artefact); points
  on the sphere leave the three rotations about its centre free (G_0 = SO(3)).
* ``cube``: a cube; three measured faces fix the pose up to its 24 rotations.
* ``cast_blank``: the physical cast blank of the hybrid problem: a plate whose top face is
  already machined (the finished datum) carrying two cast domes, the stock around two
  cylindrical bosses still to be machined. The domes' cores are shifted (a real casting's
  core shift), so the stock is uneven.
* ``cast_blank_finished``: the finished part (the CAD model of the hybrid problem): the same
  plate with the two cylindrical bosses.

:func:`cast_blank_rough_points` samples the blank's rough (cast) surfaces and
:func:`classify_cast_blank_points` tells finished-datum points from rough ones, for scans.
The source document gives no dimensions; the defaults are plausible choices.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import trimesh

from algorithms.arraytypes import ArrayLike
from twin.errors import TwinError
from twin.parts.kernel import (
    CHORD_TOL_M,
    assemble,
    box_features,
    box_patches,
    check_finite,
    check_nonnegative,
    check_positive,
    check_resolution,
    format_mm,
    line_segment,
    require,
    revolve,
    sample_profile,
)
from twin.parts.planar import PLANAR_MAX_EDGE_M

__all__ = [
    "bore_and_face",
    "sphere",
    "cube",
    "cast_blank",
    "cast_blank_finished",
    "cast_blank_geometry",
    "cast_blank_rough_points",
    "classify_cast_blank_points",
]

_GAP = 0.001


def bore_and_face(
    plate_length_m: float = 0.10,
    plate_width_m: float = 0.08,
    plate_thickness_m: float = 0.025,
    bore_diameter_m: float = 0.030,
    bore_depth_m: float = 0.015,
    bore_x_m: float = 0.012,
    bore_y_m: float = 0.006,
    resolution_m: float = 0.001,
    chord_tolerance_m: float = CHORD_TOL_M,
) -> trimesh.Trimesh:
    """A plate [-L/2, L/2] x [-W/2, W/2] x [0, T] with a blind bore from the top face.

    The bore (axis along z through (bore_x, bore_y)) is the symmetric feature; with the top
    face it fixes five of six directions, the rotation about the bore axis stays free.

    Raises:
        TwinError: a size is not positive, or the bore leaves less than 2 mm of wall or floor.
    """
    length = check_positive("plate_length_m", plate_length_m)
    width = check_positive("plate_width_m", plate_width_m)
    thick = check_positive("plate_thickness_m", plate_thickness_m)
    radius = check_positive("bore_diameter_m", bore_diameter_m) / 2.0
    depth = check_positive("bore_depth_m", bore_depth_m)
    bx = check_finite("bore_x_m", bore_x_m)
    by = check_finite("bore_y_m", bore_y_m)
    res, tol = check_resolution(resolution_m, chord_tolerance_m)
    require(
        abs(bx) + radius + 0.002 <= length / 2 and abs(by) + radius + 0.002 <= width / 2
        and depth + 0.002 <= thick,
        f"the bore (diameter {format_mm(2 * radius)}, depth {format_mm(depth)} at "
        f"({format_mm(bx)}, {format_mm(by)})) must leave >= 2 mm of wall and floor in the "
        f"{format_mm(length)} x {format_mm(width)} x {format_mm(thick)} plate",
    )
    # Down the wall, then across the floor to the axis: triangles face out of the material.
    profile, edges = sample_profile(
        [line_segment((radius, thick), (radius, thick - depth)),
         line_segment((radius, thick - depth), (0.0, thick - depth))],
        res, tol,
    )
    v, f, rings = revolve(profile, edges, origin=(bx, by, 0.0))
    patches = [(v, f)]
    patches.extend(box_patches((-length / 2, -width / 2, 0.0), (length / 2, width / 2, thick),
                               max(res, PLANAR_MAX_EDGE_M), top_holes=[v[rings[0]]]))
    return assemble(patches, "bore_and_face", ["bore", *box_features("plate")])


def sphere(
    sphere_radius_m: float = 0.025,
    stem_radius_m: float = 0.006,
    stem_length_m: float = 0.012,
    base_size_m: float = 0.07,
    base_thickness_m: float = 0.010,
    resolution_m: float = 0.001,
    chord_tolerance_m: float = CHORD_TOL_M,
) -> trimesh.Trimesh:
    """A reference sphere on a cylindrical stem standing on a square base plate.

    The sphere's centre is at (0, 0, T + stem_length + R); the stem (radius r) runs from the
    base's top face into the sphere.

    Raises:
        TwinError: a size is not positive, the stem is not thinner than the sphere, or the
            base does not reach beyond the sphere by 1 mm.
    """
    R = check_positive("sphere_radius_m", sphere_radius_m)
    rs = check_positive("stem_radius_m", stem_radius_m)
    ls = check_positive("stem_length_m", stem_length_m)
    base = check_positive("base_size_m", base_size_m)
    thick = check_positive("base_thickness_m", base_thickness_m)
    res, tol = check_resolution(resolution_m, chord_tolerance_m)
    require(rs <= 0.5 * R, f"stem_radius_m ({format_mm(rs)}) must be at most half the sphere radius")
    require(base / 2 >= R + _GAP, f"base_size_m ({format_mm(base)}) must exceed the sphere's diameter by 2 mm")
    zc = thick + ls + R
    z_join = zc - math.sqrt(R * R - rs * rs)
    a0 = math.atan2(z_join - zc, rs)  # angle of the stem-sphere circle (below the equator)

    def arc(t: np.ndarray) -> np.ndarray:
        ang = a0 + (0.5 * math.pi - a0) * t
        return np.column_stack([R * np.cos(ang), zc + R * np.sin(ang)])

    profile, edges = sample_profile(
        [line_segment((rs, thick), (rs, z_join)), arc], res, tol)
    profile[-1] = (0.0, zc + R)
    v, f, rings = revolve(profile, edges)
    patches = [(v, f)]
    patches.extend(box_patches((-base / 2, -base / 2, 0.0), (base / 2, base / 2, thick),
                               max(res, PLANAR_MAX_EDGE_M), top_holes=[v[rings[0]]]))
    return assemble(patches, "sphere", ["sphere", *box_features("base")])


def cube(side_m: float = 0.04, resolution_m: float = 0.001,
         chord_tolerance_m: float = CHORD_TOL_M) -> trimesh.Trimesh:
    """A cube [-a/2, a/2]^2 x [0, a]: the 24 rotations of the cube map it onto itself.

    ``resolution_m`` and ``chord_tolerance_m`` are accepted for a uniform interface (the
    faces are planar, meshed at 5 mm or ``resolution_m`` when coarser).
    """
    a = check_positive("side_m", side_m)
    res, _ = check_resolution(resolution_m, chord_tolerance_m)
    require(0.005 <= a <= 0.5, f"side_m must be between 5 mm and 500 mm, got {format_mm(a)}")
    patches = box_patches((-a / 2, -a / 2, 0.0), (a / 2, a / 2, a), max(res, PLANAR_MAX_EDGE_M))
    return assemble(patches, "cube", box_features("cube"))


# ------------------------------------------------------------------------------ cast blank
def cast_blank_geometry(
    plate_length_m: float = 0.13,
    plate_width_m: float = 0.08,
    plate_thickness_m: float = 0.015,
    boss_a_radius_m: float = 0.016,
    boss_a_height_m: float = 0.018,
    boss_a_x_m: float = -0.025,
    boss_b_radius_m: float = 0.007,
    boss_b_height_m: float = 0.012,
    boss_b_x_m: float = 0.035,
    stock_m: float = 0.003,
    core_shift_m: float = 0.0008,
    dome_depth_m: float = 0.004,
) -> dict:
    """The numbers of the cast blank and its finished part (workpiece frame, metres).

    Each boss (a cylinder of radius r and height h on the plate's top face z = T) is covered
    by a cast dome: a spherical cap whose centre lies ``dome_depth_m`` below the top face and
    whose radius leaves exactly ``stock_m`` over the boss's top edge when the dome is
    centred. The cores are shifted by ``core_shift_m``: dome A toward +x, dome B toward +y,
    so the least stock is ``stock_m - core_shift_m`` (about) when the finished part sits at
    the blank's nominal frame, and a placement inside the blank that balances the stock
    exists.

    Returns:
        dict with ``plate`` (L, W, T) and ``bosses``: a list of dicts with ``name``,
        ``axis_xy`` (boss axis), ``radius``, ``height``, ``dome_center`` (3,), ``dome_radius``,
        ``dome_base_radius`` (radius of the dome's circle on the top face).

    Raises:
        TwinError: a size is not positive, the stock is not positive, the core shift exceeds
            the stock, or the domes do not fit on the plate 1 mm apart.
    """
    L = check_positive("plate_length_m", plate_length_m)
    W = check_positive("plate_width_m", plate_width_m)
    T = check_positive("plate_thickness_m", plate_thickness_m)
    s = check_positive("stock_m", stock_m)
    e = check_nonnegative("core_shift_m", core_shift_m)
    dd = check_nonnegative("dome_depth_m", dome_depth_m)
    require(e < s, f"core_shift_m ({format_mm(e)}) must be smaller than stock_m ({format_mm(s)})")
    bosses: list[dict[str, Any]] = []
    for name, r, h, x, shift in (
        ("boss_a", boss_a_radius_m, boss_a_height_m, boss_a_x_m, (e, 0.0)),
        ("boss_b", boss_b_radius_m, boss_b_height_m, boss_b_x_m, (0.0, e)),
    ):
        r = check_positive(f"{name}_radius_m", r)
        h = check_positive(f"{name}_height_m", h)
        x = check_finite(f"{name}_x_m", x)
        rho = s + math.hypot(r, h + dd)
        base = math.sqrt(rho * rho - dd * dd)
        center = np.array([x + shift[0], shift[1], T - dd])
        bosses.append({"name": name, "axis_xy": np.array([x, 0.0]), "radius": r, "height": h,
                       "dome_center": center, "dome_radius": rho, "dome_base_radius": base})
    for b in bosses:
        cx, cy = b["dome_center"][:2]
        require(abs(cx) + b["dome_base_radius"] + _GAP <= L / 2
                and abs(cy) + b["dome_base_radius"] + _GAP <= W / 2,
                f"the dome over {b['name']} (base radius {format_mm(b['dome_base_radius'])}) "
                f"does not fit on the {format_mm(L)} x {format_mm(W)} plate with 1 mm to spare")
    ca, cb = bosses[0]["dome_center"][:2], bosses[1]["dome_center"][:2]
    require(np.linalg.norm(ca - cb) >= bosses[0]["dome_base_radius"] + bosses[1]["dome_base_radius"] + _GAP,
            "the two domes overlap: move the bosses apart (boss_a_x_m, boss_b_x_m)")
    return {"plate": (L, W, T), "bosses": bosses, "stock_m": s, "core_shift_m": e}


_GEOMETRY_KEYS = (
    "plate_length_m", "plate_width_m", "plate_thickness_m", "boss_a_radius_m", "boss_a_height_m",
    "boss_a_x_m", "boss_b_radius_m", "boss_b_height_m", "boss_b_x_m", "stock_m",
    "core_shift_m", "dome_depth_m",
)


def _geometry(params: dict[str, Any]) -> dict[str, Any]:
    unknown = set(params) - set(_GEOMETRY_KEYS)
    if unknown:
        raise TwinError(f"unknown cast blank parameter(s) {sorted(unknown)}; valid: {', '.join(_GEOMETRY_KEYS)}")
    return cast_blank_geometry(**params)


def cast_blank(
    plate_length_m: float = 0.13,
    plate_width_m: float = 0.08,
    plate_thickness_m: float = 0.015,
    boss_a_radius_m: float = 0.016,
    boss_a_height_m: float = 0.018,
    boss_a_x_m: float = -0.025,
    boss_b_radius_m: float = 0.007,
    boss_b_height_m: float = 0.012,
    boss_b_x_m: float = 0.035,
    stock_m: float = 0.003,
    core_shift_m: float = 0.0008,
    dome_depth_m: float = 0.004,
    resolution_m: float = 0.001,
    chord_tolerance_m: float = CHORD_TOL_M,
) -> trimesh.Trimesh:
    """The physical cast blank: the machined plate with a cast dome over each boss.

    Keyword parameters are those of :func:`cast_blank_geometry` (plate, bosses, stock, core
    shift, dome depth) plus the tessellation ``resolution_m`` and ``chord_tolerance_m``.
    """
    g = _geometry({k: v for k, v in locals().items() if k in _GEOMETRY_KEYS})
    res, tol = check_resolution(resolution_m, chord_tolerance_m)
    L, W, T = g["plate"]
    patches, holes = [], []
    for b in g["bosses"]:
        rho, base = b["dome_radius"], b["dome_base_radius"]
        cz = b["dome_center"][2]
        a0 = math.atan2(T - cz, base)

        def arc(t: np.ndarray, rho=rho, cz=cz, a0=a0) -> np.ndarray:
            ang = a0 + (0.5 * math.pi - a0) * t
            return np.column_stack([rho * np.cos(ang), cz + rho * np.sin(ang)])

        profile, edges = sample_profile([arc], res, tol)
        profile[0] = (base, T)
        profile[-1] = (0.0, cz + rho)
        v, f, rings = revolve(profile, edges, origin=(b["dome_center"][0], b["dome_center"][1], 0.0))
        patches.append((v, f))
        holes.append(v[rings[0]])
    patches.extend(box_patches((-L / 2, -W / 2, 0.0), (L / 2, W / 2, T),
                               max(res, PLANAR_MAX_EDGE_M), top_holes=holes))
    bosses = [f"boss_{i + 1}" for i in range(len(g["bosses"]))]
    return assemble(patches, "cast_blank", bosses + box_features("plate"))


def cast_blank_finished(
    plate_length_m: float = 0.13,
    plate_width_m: float = 0.08,
    plate_thickness_m: float = 0.015,
    boss_a_radius_m: float = 0.016,
    boss_a_height_m: float = 0.018,
    boss_a_x_m: float = -0.025,
    boss_b_radius_m: float = 0.007,
    boss_b_height_m: float = 0.012,
    boss_b_x_m: float = 0.035,
    stock_m: float = 0.003,
    core_shift_m: float = 0.0008,
    dome_depth_m: float = 0.004,
    resolution_m: float = 0.001,
    chord_tolerance_m: float = CHORD_TOL_M,
) -> trimesh.Trimesh:
    """The finished part (CAD model of the hybrid problem): the plate with two bosses.

    Same keyword parameters as :func:`cast_blank` (the stock and core shift do not change it).
    """
    g = _geometry({k: v for k, v in locals().items() if k in _GEOMETRY_KEYS})
    res, tol = check_resolution(resolution_m, chord_tolerance_m)
    L, W, T = g["plate"]
    patches, holes = [], []
    for b in g["bosses"]:
        r, h = b["radius"], b["height"]
        profile, edges = sample_profile(
            [line_segment((r, T), (r, T + h)), line_segment((r, T + h), (0.0, T + h))], res, tol)
        v, f, rings = revolve(profile, edges, origin=(b["axis_xy"][0], b["axis_xy"][1], 0.0))
        patches.append((v, f))
        holes.append(v[rings[0]])
    patches.extend(box_patches((-L / 2, -W / 2, 0.0), (L / 2, W / 2, T),
                               max(res, PLANAR_MAX_EDGE_M), top_holes=holes))
    bosses = [f"boss_{i + 1}" for i in range(len(g["bosses"]))]
    return assemble(patches, "cast_blank_finished", bosses + box_features("plate"))


def cast_blank_rough_points(n: int, rng: np.random.Generator, max_slope_deg: float = 60.0,
                            **params: object) -> tuple[np.ndarray, np.ndarray]:
    """Points on the blank's cast domes (the rough surfaces), workpiece frame [m].

    Area-uniform on each dome where its slope is at most ``max_slope_deg`` (what a vertical
    beam with a 60 degree incidence limit sees), split between the domes by area.

    Returns:
        points (n, 3) [m] and group labels (n,) ("boss_a" or "boss_b").
    """
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise TwinError(f"n must be a positive integer, got {n!r}")
    g = _geometry(params)
    T = g["plate"][2]
    caps = []
    for b in g["bosses"]:
        rho, cz = b["dome_radius"], b["dome_center"][2]
        # polar angle from the top: up to the slope limit and above the plate
        th_max = min(math.radians(max_slope_deg), math.acos(max(-1.0, min(1.0, (T - cz) / rho))))
        area = 2 * math.pi * rho * rho * (1 - math.cos(th_max))
        caps.append((b, th_max, area))
    total = sum(c[2] for c in caps)
    counts = [int(round(n * c[2] / total)) for c in caps]
    counts[-1] = n - sum(counts[:-1])
    pts, labels = [], []
    for (b, th_max, _), k in zip(caps, counts, strict=True):
        cos_t = rng.uniform(math.cos(th_max), 1.0, k)
        phi = rng.uniform(0.0, 2 * math.pi, k)
        sin_t = np.sqrt(1 - cos_t**2)
        d = np.column_stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t])
        pts.append(b["dome_center"] + b["dome_radius"] * d)
        labels.append(np.full(k, b["name"]))
    return np.concatenate(pts), np.concatenate(labels)


def classify_cast_blank_points(points_wp: ArrayLike, guard_m: float = 0.001, **params: object) -> np.ndarray:
    """Label scan points of the cast blank: "finished" (plate top), "rough" (domes), "other".

    For a real cell: map the scan into the workpiece frame with the nominal pose, then label
    by the nominal geometry. Points within ``guard_m`` of a dome's base circle (where the
    datum meets the casting, and where the nominal pose's error could mislabel them) and
    points off both surfaces are "other".

    Args:
        points_wp: (N, 3) [m] points in the workpiece frame (nominal pose).
        guard_m: guard band [m] around the dome bases and the top face.

    Returns:
        (N,) array of labels.
    """
    P = np.asarray(points_wp, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise TwinError(f"points must be (N, 3), got {P.shape}")
    g = _geometry(params)
    L, W, T = g["plate"]
    out = np.full(len(P), "other", dtype=object)
    near_base = np.zeros(len(P), dtype=bool)
    on_dome = np.zeros(len(P), dtype=bool)
    for b in g["bosses"]:
        r_xy = np.linalg.norm(P[:, :2] - b["dome_center"][:2], axis=1)
        near_base |= np.abs(r_xy - b["dome_base_radius"]) < 3 * guard_m
        on_dome |= (r_xy < b["dome_base_radius"] - 3 * guard_m) & (P[:, 2] > T + guard_m)
    on_top = (np.abs(P[:, 2] - T) < guard_m) & (np.abs(P[:, 0]) < L / 2 - guard_m) & (np.abs(P[:, 1]) < W / 2 - guard_m)
    out[on_top & ~near_base & ~on_dome] = "finished"
    out[on_dome & ~near_base] = "rough"
    return out.astype(str)

