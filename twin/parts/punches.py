"""Document 000's two punches: workpiece A (hemisphere punch) and workpiece B (bottle punch).

* :func:`hemisphere_punch`: a plate carrying a hemisphere and four small cylinders (pins).
* :func:`bottle_punch`: a plate carrying half a plastic bottle whose profile is eight cubic
  Bezier segments (:func:`bottle_profile_bezier`), i.e. 16 Bezier patches over the half turn.

Both are built to have no proper rigid symmetry with their default parameters, so that they
can be localised in all six degrees of freedom.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from algorithms.arraytypes import FloatArray, IntArray
from twin.parts.kernel import (
    CHORD_TOL_M,
    assemble,
    box_features,
    box_patches,
    check_finite,
    check_positive,
    check_resolution,
    cubic_bezier,
    format_mm,
    line_segment,
    require,
    revolve,
    sample_profile,
)
from twin.parts.planar import PLANAR_MAX_EDGE_M

__all__ = ["hemisphere_punch", "bottle_punch", "bottle_profile_bezier"]


# --------------------------------------------------------------------------------------------
# 000 workpiece A: hemisphere punch
# --------------------------------------------------------------------------------------------


def _pin_centres(length: float, width: float, radius: float, offset: float, pin_r: float,
                 inset: float) -> list[tuple[float, float]]:
    """(x, y) [m] of the four pins of :func:`hemisphere_punch`, after checking that the
    hemisphere and the pins fit on the plate.

    Raises:
        TwinError: they do not fit with at least 1 mm between them and to the plate edges.
    """
    gap = 0.001
    require(
        abs(offset) + radius + gap <= length / 2 and radius + gap <= width / 2,
        f"the hemisphere (radius {format_mm(radius)} at x = {format_mm(offset)}) must lie on the "
        f"{format_mm(length)} x {format_mm(width)} plate with >= 1 mm to its edges",
    )
    require(
        inset >= pin_r + gap and 2 * inset + 2 * pin_r + gap <= min(length, width),
        f"pin_inset_m must be >= pin_radius_m + 1 mm and leave the pins apart, got inset "
        f"{format_mm(inset)} with pin radius {format_mm(pin_r)}",
    )
    pins = [(sx * (length / 2 - inset), sy * (width / 2 - inset)) for sx in (-1, 1)
            for sy in (-1, 1)]
    for px, py in pins:
        require(
            math.hypot(px - offset, py) >= radius + pin_r + gap,
            f"a pin at ({format_mm(px)}, {format_mm(py)}) overlaps the hemisphere; move the pins out "
            "(pin_inset_m) or shrink the hemisphere (>= 1 mm clearance needed)",
        )
    return pins


def _hemisphere_surface(radius: float, offset: float, thick: float, res: float,
                        tol: float) -> tuple[FloatArray, IntArray, list[IntArray]]:
    """The hemisphere on the plate's top face, centred at (offset, 0, thick) [m]
    (:func:`~twin.parts.kernel.revolve`'s vertices, triangles and rings; ring 0 its foot)."""
    hemi_profile, hemi_edges = sample_profile(
        [lambda t: np.column_stack([radius * np.cos(0.5 * np.pi * t),
                                    thick + radius * np.sin(0.5 * np.pi * t)])],
        res, tol,
    )
    hemi_profile[-1] = (0.0, thick + radius)
    return revolve(hemi_profile, hemi_edges, origin=(offset, 0.0, 0.0))


def _pin_surface(px: float, py: float, pin_r: float, pin_h: float, thick: float, res: float,
                 tol: float) -> tuple[FloatArray, IntArray, list[IntArray]]:
    """A pin standing on the plate's top face at (px, py) [m]: its side and its flat top
    (:func:`~twin.parts.kernel.revolve`'s vertices, triangles and rings; ring 0 its foot)."""
    profile, edges = sample_profile(
        [line_segment((pin_r, thick), (pin_r, thick + pin_h)),
         line_segment((pin_r, thick + pin_h), (0.0, thick + pin_h))],
        res, tol,
    )
    return revolve(profile, edges, origin=(px, py, 0.0))


def hemisphere_punch(
    plate_length_m: float = 0.12,
    plate_width_m: float = 0.10,
    plate_thickness_m: float = 0.02,
    hemisphere_radius_m: float = 0.035,
    hemisphere_offset_x_m: float = 0.01,
    pin_radius_m: float = 0.006,
    pin_height_m: float = 0.015,
    pin_inset_m: float = 0.012,
    resolution_m: float = 0.001,
    chord_tolerance_m: float = CHORD_TOL_M,
) -> trimesh.Trimesh:
    """Document 000's workpiece A, the hemisphere punch: plate + hemisphere + four pins.

    A rectangular plate [-L/2, L/2] x [-W/2, W/2] x [0, T], a hemisphere of radius R standing
    on its top face with its centre at (offset_x, 0, T), and four small cylinders (pins) on the
    top face, one near each corner, their axes ``pin_inset_m`` from the two nearest plate
    edges. Document 000 gives no dimensions; these are plausible for a small punch.

    Symmetry: with ``hemisphere_offset_x_m != 0`` (the default) and a non-square plate, no
    rigid motion other than the identity maps the part onto itself. With offset 0 the part
    has the 180 degree rotation about z (and the 90 degree ones if the plate is square).

    Args:
        plate_length_m: plate size along x [m].
        plate_width_m: plate size along y [m].
        plate_thickness_m: plate thickness [m].
        hemisphere_radius_m: hemisphere radius [m].
        hemisphere_offset_x_m: x of the hemisphere centre [m].
        pin_radius_m: pin (cylinder) radius [m].
        pin_height_m: pin height above the plate [m].
        pin_inset_m: distance of each pin axis from the two nearest plate edges [m].
        resolution_m: largest edge on the curved surfaces [m] (planar faces grade to 5 mm).
        chord_tolerance_m: largest deviation of the curved surfaces' triangles from the
            exact surface [m] (edges are also capped at ``resolution_m``).

    Returns:
        Watertight mesh [m], workpiece frame, bottom face at z = 0.

    Raises:
        TwinError: a size is not positive or the hemisphere and pins do not fit on the plate
            with at least 1 mm between them and to the plate edges.
    """
    length = check_positive("plate_length_m", plate_length_m)
    width = check_positive("plate_width_m", plate_width_m)
    thick = check_positive("plate_thickness_m", plate_thickness_m)
    radius = check_positive("hemisphere_radius_m", hemisphere_radius_m)
    offset = check_finite("hemisphere_offset_x_m", hemisphere_offset_x_m)
    pin_r = check_positive("pin_radius_m", pin_radius_m)
    pin_h = check_positive("pin_height_m", pin_height_m)
    inset = check_positive("pin_inset_m", pin_inset_m)
    res, tol = check_resolution(resolution_m, chord_tolerance_m)
    pins = _pin_centres(length, width, radius, offset, pin_r, inset)
    v, f, rings = _hemisphere_surface(radius, offset, thick, res, tol)
    patches = [(v, f)]
    holes = [v[rings[0]]]
    for px, py in pins:
        v, f, rings = _pin_surface(px, py, pin_r, pin_h, thick, res, tol)
        patches.append((v, f))
        holes.append(v[rings[0]])
    patches.extend(
        box_patches((-length / 2, -width / 2, 0.0), (length / 2, width / 2, thick),
                     max(res, PLANAR_MAX_EDGE_M), top_holes=holes)
    )
    features = ["hemisphere"] + [f"pin_{i + 1}" for i in range(len(pins))] + box_features("plate")
    return assemble(patches, "hemisphere_punch", features)


# --------------------------------------------------------------------------------------------
# 000 workpiece B: bottle punch
# --------------------------------------------------------------------------------------------


def _bottle_checks(
    plate_length_m: float,
    plate_width_m: float,
    plate_thickness_m: float,
    bottle_length_m: float,
    body_radius_m: float,
    neck_radius_m: float,
    bottle_offset_x_m: float,
) -> tuple[float, ...]:
    length = check_positive("plate_length_m", plate_length_m)
    width = check_positive("plate_width_m", plate_width_m)
    thick = check_positive("plate_thickness_m", plate_thickness_m)
    b_len = check_positive("bottle_length_m", bottle_length_m)
    body = check_positive("body_radius_m", body_radius_m)
    neck = check_positive("neck_radius_m", neck_radius_m)
    offset = check_finite("bottle_offset_x_m", bottle_offset_x_m)
    require(
        neck * 1.2 <= 0.9 * body,
        f"neck_radius_m must be at most 0.75 x body_radius_m (the bead on the neck is 1.2 x "
        f"the neck radius), got neck {format_mm(neck)} and body {format_mm(body)}",
    )
    require(
        b_len >= 2.0 * body,
        f"bottle_length_m must be at least 2 x body_radius_m, got {format_mm(b_len)} and body "
        f"radius {format_mm(body)}",
    )
    require(
        abs(offset) + b_len / 2 + 0.001 <= length / 2 and body + 0.001 <= width / 2,
        f"the bottle ({format_mm(b_len)} long, radius {format_mm(body)}, at x = {format_mm(offset)}) must lie "
        f"on the {format_mm(length)} x {format_mm(width)} plate with >= 1 mm to its edges",
    )
    return length, width, thick, b_len, body, neck, offset


def bottle_profile_bezier(
    plate_length_m: float = 0.15,
    plate_width_m: float = 0.08,
    plate_thickness_m: float = 0.015,
    bottle_length_m: float = 0.11,
    body_radius_m: float = 0.025,
    neck_radius_m: float = 0.011,
    bottle_offset_x_m: float = 0.0,
    resolution_m: float | None = None,
    chord_tolerance_m: float | None = None,
) -> np.ndarray:
    """Control points of the bottle's profile: eight cubic Bezier segments.

    Each segment is (x, r): x along the bottle axis (the workpiece x axis) and r the radius.
    The bottle surface is ``(x(t), r(t) cos(phi), T + r(t) sin(phi))`` for phi in [0, pi]
    (T the plate thickness); split at phi = pi / 2 it is 16 Bezier patches (the angular
    direction being an exact circle, i.e. a rational Bezier). Flat half-disks close the
    bottle's base (x = x_start, r <= first control point's r) and mouth (x = x_end).
    The segments are: heel fillet, two body segments with a grip waist, shoulder, neck,
    two bead segments, mouth; consecutive segments join with a continuous tangent.

    Args:
        As :func:`bottle_punch` (``resolution_m`` and ``chord_tolerance_m`` are accepted and
        have no effect).

    Returns:
        (8, 4, 2) control points [m].
    """
    del resolution_m, chord_tolerance_m
    _, _, _, b_len, body, neck, offset = _bottle_checks(
        plate_length_m, plate_width_m, plate_thickness_m, bottle_length_m, body_radius_m,
        neck_radius_m, bottle_offset_x_m,
    )
    a0 = offset - b_len / 2
    big_l, big_r, n = b_len, body, neck
    fillet = 0.12 * big_r
    waist = 0.08 * big_r
    bead = 0.2 * n

    def ax(u: float) -> float:
        return a0 + u * big_l

    segs = [
        # heel fillet: from the base disk's rim (vertical tangent) onto the body
        [(a0, big_r - fillet), (a0, big_r - 0.45 * fillet), (a0 + 0.45 * fillet, big_r),
         (a0 + fillet, big_r)],
        # body into the grip waist
        [(a0 + fillet, big_r), (ax(0.14), big_r), (ax(0.2), big_r - waist),
         (ax(0.3), big_r - waist)],
        # out of the waist
        [(ax(0.3), big_r - waist), (ax(0.37), big_r - waist), (ax(0.43), big_r),
         (ax(0.5), big_r)],
        # shoulder
        [(ax(0.5), big_r), (ax(0.62), big_r), (ax(0.62), n), (ax(0.72), n)],
        # neck
        [(ax(0.72), n), (ax(0.7467), n), (ax(0.7733), n), (ax(0.8), n)],
        # bead up
        [(ax(0.8), n), (ax(0.82), n), (ax(0.82), n + bead), (ax(0.84), n + bead)],
        # bead down
        [(ax(0.84), n + bead), (ax(0.86), n + bead), (ax(0.86), n), (ax(0.88), n)],
        # mouth
        [(ax(0.88), n), (ax(0.92), n), (ax(0.96), n), (ax(1.0), n)],
    ]
    return np.asarray(segs, dtype=np.float64)


def bottle_punch(
    plate_length_m: float = 0.15,
    plate_width_m: float = 0.08,
    plate_thickness_m: float = 0.015,
    bottle_length_m: float = 0.11,
    body_radius_m: float = 0.025,
    neck_radius_m: float = 0.011,
    bottle_offset_x_m: float = 0.0,
    resolution_m: float = 0.001,
    chord_tolerance_m: float = CHORD_TOL_M,
) -> trimesh.Trimesh:
    """Document 000's workpiece B, the plastic-bottle punch: a plate and half a bottle.

    The bottle (axis along x at y = 0, z = T) is cut along its axis; the upper half lies on
    the plate's top face. Its surface is the profile of :func:`bottle_profile_bezier`
    (eight cubic Bezier segments, 16 patches over the half turn, evaluated exactly) closed
    by flat half-disks at the base and the mouth. Document 000 gives no dimensions ("a dozen
    Bezier patches"); these are plausible for a small bottle mould.

    Symmetry: the mirror y -> -y maps the part onto itself, but it is not a rigid motion
    (it reverses orientation). The bottle's two ends differ, so no proper rigid motion other
    than the identity maps the part onto itself.

    Args:
        plate_length_m: plate size along x [m].
        plate_width_m: plate size along y [m].
        plate_thickness_m: plate thickness T [m].
        bottle_length_m: bottle length, base to mouth [m].
        body_radius_m: body radius [m].
        neck_radius_m: neck radius [m].
        bottle_offset_x_m: x of the bottle's middle [m] (the base is toward -x).
        resolution_m: largest edge on the curved surfaces [m] (planar faces grade to 5 mm).
        chord_tolerance_m: largest deviation of the bottle's triangles from its Bezier
            surface [m] (edges are also capped at ``resolution_m``).

    Returns:
        Watertight mesh [m], workpiece frame, bottom face at z = 0.

    Raises:
        TwinError: a size is not positive, the neck is too wide for the body, or the bottle
            does not fit on the plate with >= 1 mm margin.
    """
    length, width, thick, b_len, body, neck, offset = _bottle_checks(
        plate_length_m, plate_width_m, plate_thickness_m, bottle_length_m, body_radius_m,
        neck_radius_m, bottle_offset_x_m,
    )
    res, tol = check_resolution(resolution_m, chord_tolerance_m)
    ctrl = bottle_profile_bezier(
        plate_length_m=length, plate_width_m=width, plate_thickness_m=thick,
        bottle_length_m=b_len, body_radius_m=body, neck_radius_m=neck,
        bottle_offset_x_m=offset,
    )
    a0, a1 = ctrl[0, 0, 0], ctrl[-1, -1, 0]
    # Profile as (r, a): base disk, the Bezier segments, mouth disk.
    segments = [line_segment((0.0, a0), (ctrl[0, 0, 1], a0))]
    segments += [cubic_bezier(c[:, ::-1]) for c in ctrl]
    segments += [line_segment((ctrl[-1, -1, 1], a1), (0.0, a1))]
    profile, edges = sample_profile(segments, res, tol)
    # Local frame: axis along +x, phi = 0 toward +y, phi = pi/2 toward +z.
    rot = np.column_stack([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    v, f, rings = revolve(profile, edges, half=True, rotation=rot, origin=(0.0, 0.0, thick))
    # Footprint on the plate: the phi = pi ends (y < 0) base to mouth, then phi = 0 back.
    minus = [v[r[-1]] for r in rings]
    plus = [v[r[0]] for r in rings[1:-1]][::-1]
    footprint = np.asarray(minus + plus)
    patches = [(v, f)]
    patches.extend(
        box_patches((-length / 2, -width / 2, 0.0), (length / 2, width / 2, thick),
                     max(res, PLANAR_MAX_EDGE_M), top_holes=[footprint])
    )
    return assemble(patches, "bottle_punch", ["bottle", *box_features("plate")])
