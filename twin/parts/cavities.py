"""Document 002's parts for probe path planning, whose measured features lie inside the block.

* :func:`inner_sphere`: the "inner sphere containing a cylinder": a spherical cavity opened
  at the top face of a block, with a cylindrical post standing inside it.
* :func:`through_hole`: a block with a horizontal through hole, measured from both ends.

In both, the block's top face is the safety plane the probe crosses between measurements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from algorithms.arraytypes import FloatArray, IntArray
from twin.parts.kernel import (
    CHORD_TOL_M,
    assemble,
    box_features,
    box_patches,
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

__all__ = ["inner_sphere", "through_hole"]


@dataclass(frozen=True)
class _Bowl:
    """The cavity and post of :func:`inner_sphere` [m], workpiece frame (axis: the z axis).

    Attributes:
        height: the block's height (the top face's z).
        radius: the cavity's radius; depth, zc: the depth of its centre below the top face
            and its height.
        opening: radius of the cavity's circle in the top face.
        post_r: the post's radius; z_foot, z_post: heights of its foot (on the cavity floor)
            and of its top.
    """

    height: float
    radius: float
    depth: float
    zc: float
    opening: float
    post_r: float
    z_foot: float
    z_post: float


def _bowl_geometry(length: float, width: float, height: float, radius: float, depth: float, post_r: float,
                   post_depth: float) -> _Bowl:
    """Check that :func:`inner_sphere`'s cavity and post fit the block, and place them.

    Raises:
        TwinError: the cavity would not open in the top face, break through a side or the
            bottom (2 mm minimum wall), or not contain the post.
    """
    wall = 0.002
    require(
        depth <= 0.9 * radius,
        f"sphere_center_depth_m must be at most 0.9 x sphere_radius_m so the cavity opens in "
        f"the top face, got {format_mm(depth)} with radius {format_mm(radius)}",
    )
    require(
        radius + wall <= min(length, width) / 2,
        f"sphere_radius_m {format_mm(radius)} leaves less than a 2 mm wall in the "
        f"{format_mm(length)} x {format_mm(width)} block",
    )
    zc = height - depth
    require(
        zc - radius >= wall,
        f"block_height_m {format_mm(height)} leaves less than a 2 mm floor under the cavity "
        f"(radius {format_mm(radius)}, centre {format_mm(depth)} below the top)",
    )
    opening = math.sqrt(radius**2 - depth**2)
    require(
        post_r + 0.001 <= opening,
        f"post_radius_m must be at least 1 mm smaller than the opening radius "
        f"{format_mm(opening)}, got {format_mm(post_r)}",
    )
    z_foot = zc - math.sqrt(radius**2 - post_r**2)
    z_post = height - post_depth
    require(
        z_post - z_foot >= 0.001,
        f"post_top_depth_m {format_mm(post_depth)} puts the post's top below the cavity floor",
    )
    return _Bowl(height, radius, depth, zc, opening, post_r, z_foot, z_post)


def _bowl_surface(bowl: _Bowl, res: float, tol: float) -> tuple[FloatArray, IntArray, list[IntArray]]:
    """The cavity's sphere from the top-face rim down to the post's foot, the post's side and
    its top, revolved about the z axis (:func:`~twin.parts.kernel.revolve`'s vertices,
    triangles and rings; ring 0 is the rim in the top face)."""
    radius, zc, post_r = bowl.radius, bowl.zc, bowl.post_r
    theta_open = math.atan2(bowl.depth, bowl.opening)  # angle of the rim above the equator
    theta_foot = -math.atan2(math.sqrt(radius**2 - post_r**2), post_r)

    def sphere_arc(t: FloatArray) -> FloatArray:
        th = theta_open + (theta_foot - theta_open) * t
        return np.column_stack([radius * np.cos(th), zc + radius * np.sin(th)])

    profile, edges = sample_profile(
        [sphere_arc, line_segment((post_r, bowl.z_foot), (post_r, bowl.z_post)),
         line_segment((post_r, bowl.z_post), (0.0, bowl.z_post))],
        res, tol,
    )
    profile[0] = (bowl.opening, bowl.height)
    return revolve(profile, edges)


def inner_sphere(
    block_length_m: float = 0.10,
    block_width_m: float = 0.10,
    block_height_m: float = 0.06,
    sphere_radius_m: float = 0.04,
    sphere_center_depth_m: float = 0.01,
    post_radius_m: float = 0.01,
    post_top_depth_m: float = 0.0,
    resolution_m: float = 0.001,
    chord_tolerance_m: float = CHORD_TOL_M,
) -> trimesh.Trimesh:
    """Document 002's "inner sphere containing a cylinder" (內(nèi)部包含柱體的內(nèi)球).

    A block [-L/2, L/2] x [-W/2, W/2] x [0, H] with a spherical cavity of radius R, centred on
    the z axis ``sphere_center_depth_m`` below the top face, so that the cavity opens in the
    top face through a circle slightly smaller than its equator (the inner sphere is measured
    from inside). A cylindrical post of radius ``post_radius_m`` stands on the cavity floor
    on the axis, up to ``post_top_depth_m`` below the top face: a probe moving between
    points on opposite sides of the sphere must go over it, across the safety plane (the
    top face), as in the document's experiment (safety distance 30 mm). Document 002 gives
    no dimensions; these are plausible. Reading: 內(nèi)球 is a concave sphere measured from
    inside, 柱體 the obstacle within it that the probe must go around ("繞過柱體"), and the
    safety plane is the part's top face (上表面), which a free-standing sphere would not have.

    Symmetry: rotations about the z axis by multiples of 90 degrees (180 if L != W) map the
    part onto itself (irrelevant to path planning, which is what document 002 uses it for).

    Args:
        block_length_m: block size along x [m].
        block_width_m: block size along y [m].
        block_height_m: block height H [m].
        sphere_radius_m: cavity radius R [m].
        sphere_center_depth_m: depth of the sphere centre below the top face [m].
        post_radius_m: post radius [m].
        post_top_depth_m: depth of the post's top below the top face [m] (0: flush).
        resolution_m: largest edge on the curved surfaces [m] (planar faces grade to 5 mm).
        chord_tolerance_m: largest deviation of the curved surfaces' triangles from the
            exact surface [m] (edges are also capped at ``resolution_m``).

    Returns:
        Watertight mesh [m], workpiece frame, bottom face at z = 0.

    Raises:
        TwinError: a size is not positive, or the cavity would not open in the top face,
            break through a side or the bottom (2 mm minimum wall), or not contain the post.
    """
    length = check_positive("block_length_m", block_length_m)
    width = check_positive("block_width_m", block_width_m)
    height = check_positive("block_height_m", block_height_m)
    radius = check_positive("sphere_radius_m", sphere_radius_m)
    depth = check_nonnegative("sphere_center_depth_m", sphere_center_depth_m)
    post_r = check_positive("post_radius_m", post_radius_m)
    post_depth = check_nonnegative("post_top_depth_m", post_top_depth_m)
    res, tol = check_resolution(resolution_m, chord_tolerance_m)
    bowl = _bowl_geometry(length, width, height, radius, depth, post_r, post_depth)
    v, f, rings = _bowl_surface(bowl, res, tol)
    patches = [(v, f)]
    patches.extend(
        box_patches((-length / 2, -width / 2, 0.0), (length / 2, width / 2, height),
                     max(res, PLANAR_MAX_EDGE_M), top_holes=[v[rings[0]]])
    )
    return assemble(patches, "inner_sphere", ["bowl", *box_features("block")])


def through_hole(
    block_length_m: float = 0.08,
    block_width_m: float = 0.06,
    block_height_m: float = 0.04,
    hole_diameter_m: float = 0.02,
    hole_center_height_m: float = 0.02,
    resolution_m: float = 0.001,
    chord_tolerance_m: float = CHORD_TOL_M,
) -> trimesh.Trimesh:
    """Document 002's block with a through hole, measured from both ends.

    A block [-L/2, L/2] x [-W/2, W/2] x [0, H] with a horizontal cylindrical hole along x
    (axis y = 0, z = ``hole_center_height_m``) from end face to end face. The hole is
    horizontal because the document measures its two ends and moves the probe over the top
    face (the safety plane) between them. No dimensions are given; these are plausible.

    Symmetry: with the hole at mid-height the block has the three 180 degree rotations about
    the axes through its centre; the hole's ends are indistinguishable.

    Args:
        block_length_m: block size along x, the hole's length [m].
        block_width_m: block size along y [m].
        block_height_m: block height H [m].
        hole_diameter_m: hole diameter [m].
        hole_center_height_m: height of the hole axis above the bottom [m].
        resolution_m: largest edge on the hole surface [m] (planar faces grade to 5 mm).
        chord_tolerance_m: largest deviation of the curved surfaces' triangles from the
            exact surface [m] (edges are also capped at ``resolution_m``).

    Returns:
        Watertight mesh [m] of genus 1, workpiece frame, bottom face at z = 0.

    Raises:
        TwinError: a size is not positive or the hole leaves less than a 2 mm wall.
    """
    length = check_positive("block_length_m", block_length_m)
    width = check_positive("block_width_m", block_width_m)
    height = check_positive("block_height_m", block_height_m)
    radius = check_positive("hole_diameter_m", hole_diameter_m) / 2.0
    zh = check_positive("hole_center_height_m", hole_center_height_m)
    res, tol = check_resolution(resolution_m, chord_tolerance_m)
    wall = 0.002
    require(
        radius + wall <= width / 2 and zh - radius >= wall and zh + radius + wall <= height,
        f"the hole (diameter {format_mm(2 * radius)} at height {format_mm(zh)}) must leave >= 2 mm walls "
        f"in the {format_mm(width)} wide, {format_mm(height)} high block",
    )
    # Run the profile from +x to -x so the triangles face the axis (out of the material).
    profile, edges = sample_profile(
        [line_segment((radius, length / 2), (radius, -length / 2))], res, tol
    )
    rot = np.column_stack([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    v, f, rings = revolve(profile, edges, rotation=rot, origin=(0.0, 0.0, zh))
    patches = [(v, f)]
    patches.extend(
        box_patches((-length / 2, -width / 2, 0.0), (length / 2, width / 2, height),
                     max(res, PLANAR_MAX_EDGE_M),
                     end_holes={1: [v[rings[0]]], -1: [v[rings[-1]]]})
    )
    return assemble(patches, "through_hole", ["hole", *box_features("block")])
