"""A CAM program's cutter locations moved to where the part is (document 003, step 5).

The CAM program is written in the CAD (programming) frame for the part at its nominal place;
the located pose ``T_machine_workpiece`` maps CAD coordinates to machine coordinates. For a
ball-end tool of radius ``r`` on a 3-axis machine (tool axis ``+z`` in both frames) the ball's
centre ``c = tip + r z`` is what touches the surface the same way wherever the part is: the
centre moves rigidly, ``c' = T c``, and the new tip is ``c' - r z``. The shank stays vertical,
so its clearance changes by the part's rotation (a few degrees at most after localization);
a flat or bull-nose tool would need the part's rotation in the tool axis (5 axes).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike

from algorithms.geometry.se3 import as_pose, transform_points
from algorithms.nc.gcode import Move


def relocate_tool_tips(tips_mm: ArrayLike, tool_radius_mm: float, T_machine_workpiece: ArrayLike) -> np.ndarray:
    """The tool tips [mm] that machine the CAD-frame program ``tips_mm`` (N, 3) on the part at
    ``T_machine_workpiece`` (a rigid (4, 4) pose in metres) with a ball-end tool."""
    if not tool_radius_mm > 0:
        raise ValueError(f"tool_radius_mm must be > 0, got {tool_radius_mm}")
    T = as_pose(T_machine_workpiece)
    up = np.array([0.0, 0.0, float(tool_radius_mm)])
    centres_m = (np.asarray(tips_mm, dtype=np.float64).reshape(-1, 3) + up) * 1e-3
    return transform_points(T, centres_m) * 1e3 - up


def relocate_program(moves: Sequence[Move], tool_radius_mm: float, T_machine_workpiece: ArrayLike) -> list[Move]:
    """Every move of a CAD-frame program (:func:`algorithms.nc.read_gcode`) relocated by
    :func:`relocate_tool_tips`; the moves made before X, Y and Z are all known (a program's
    opening retract, ``G0 Z50``) are kept as written: their end point is not a cutter location."""
    done = [m for m in moves if m.complete]
    tips = (relocate_tool_tips([m.xyz_mm for m in done], tool_radius_mm, T_machine_workpiece) if done
            else np.zeros((0, 3)))
    moved = iter(tips)
    out = []
    for m in moves:
        if m.complete:
            x, y, z = next(moved)
            m = replace(m, xyz_mm=(float(x), float(y), float(z)))
        out.append(m)
    return out
