"""The exact surfaces of the generated parts that have them, for document 000's Newton foot
points and for points on the true (not tessellated) surface.

* ``hemisphere_punch``: the hemisphere (a sphere above the plate), the four pins (cylinders and
  their flat tops) and the plate's top (with their footprints as holes) and four side faces;
* ``bottle_punch``: the bottle (the surface of revolution of :func:`bottle_profile_bezier`'s
  eight cubic Bezier segments, its flat base and mouth) and the plate's top and four side faces.

The bottom faces are left out (document 000 measures the hemisphere and two side faces of A
and the bottle of B), and the bottle's footprint on the plate's top is not cut out of it.
Other parts have none (None).
"""

from __future__ import annotations

import inspect

from algorithms.geometry.parametric import BezierRevolution, Cylinder, Plane, Sphere
from twin.parts.punches import _pin_centres, bottle_profile_bezier, bottle_punch, hemisphere_punch


def _with_defaults(generator, params: dict) -> dict:
    out = {k: p.default for k, p in inspect.signature(generator).parameters.items()}
    out.update(params)
    return out


def _plate(length: float, width: float, thick: float, holes: tuple = ()) -> list[Plane]:
    """The plate's top face (with ``holes``: (centre, radius) disks where other features stand)
    and its four sides (outward normals)."""
    return [Plane((0.0, 0.0, thick), (0.0, 0.0, 1.0), holes=holes),
            Plane((length / 2, 0.0, 0.0), (1.0, 0.0, 0.0)), Plane((-length / 2, 0.0, 0.0), (-1.0, 0.0, 0.0)),
            Plane((0.0, width / 2, 0.0), (0.0, 1.0, 0.0)), Plane((0.0, -width / 2, 0.0), (0.0, -1.0, 0.0))]


def exact_surfaces(name: str, **params: object) -> list | None:
    """The exact surfaces of workpiece ``name`` built with ``params`` (module docstring), or None."""
    if name == "hemisphere_punch":
        p = _with_defaults(hemisphere_punch, params)
        length, width, thick = float(p["plate_length_m"]), float(p["plate_width_m"]), float(p["plate_thickness_m"])
        radius, offset = float(p["hemisphere_radius_m"]), float(p["hemisphere_offset_x_m"])
        pin_r, pin_h, inset = float(p["pin_radius_m"]), float(p["pin_height_m"]), float(p["pin_inset_m"])
        pins = _pin_centres(length, width, radius, offset, pin_r, inset)
        holes = (((offset, 0.0, thick), radius), *(((px, py, thick), pin_r) for px, py in pins))
        pin_surfaces = [s for px, py in pins for s in (
            Cylinder((px, py), pin_r, (thick, thick + pin_h)),
            Plane((px, py, thick + pin_h), (0.0, 0.0, 1.0), within=((px, py, thick + pin_h), pin_r)))]
        return [Sphere((offset, 0.0, thick), radius, z_min=thick), *pin_surfaces,
                *_plate(length, width, thick, holes)]
    if name == "bottle_punch":
        p = _with_defaults(bottle_punch, params)
        p.pop("resolution_m"), p.pop("chord_tolerance_m")
        thick = float(p["plate_thickness_m"])
        ctrl = bottle_profile_bezier(**p)
        (a0, r0), (a1, r1) = ctrl[0, 0], ctrl[-1, -1]
        ends = [Plane((a0, 0.0, thick), (-1.0, 0.0, 0.0), within=((a0, 0.0, thick), r0)),
                Plane((a1, 0.0, thick), (1.0, 0.0, 0.0), within=((a1, 0.0, thick), r1))]
        return [BezierRevolution((0.0, 0.0, thick), (1.0, 0.0, 0.0), ctrl), *ends,
                *_plate(float(p["plate_length_m"]), float(p["plate_width_m"]), thick)]
    return None
