"""Scan planning: scan lines over the workpiece, seen on the CAD model at the NOMINAL pose.

One pass (the ``[scan]`` table's own keys): lines run along the workpiece's x (or y) axis,
``line_spacing_m`` apart, alternating direction. Each line is found by casting rays at the
nominal CAD model (1 mm apart, along -z of the workpiece, or along the fixed beam direction);
the sensor sits at the stand-off along the (smoothed) surface normal or the fixed direction,
its +z on the beam and its +x along the line axis.

Several passes (``[[scan.passes]]``, or ``passes = "auto"``): each pass has a view direction
(the fixed beam, or the planning direction of a beam along the normal). Its lines lie on a
plane normal to the view, ``line_spacing_m`` apart, along the pass's line axis; planning rays
1 mm apart are cast along the view at the nominal CAD model, and a line is each run of
consecutive hits that lies in the pass's region, is seen within the sensor's incidence limit,
and crosses no sharp edge (a jump in the face normal) and no step (a jump in the hit point):
a line never bridges a step. The automatic planner (:func:`~twin.plan.auto.plan_auto_passes`) picks views
from straight down and tilted cones until the predicted points fix all six pose directions
(:func:`algorithms.registration.uncertainty.observability`) and checks each with the scan's IK.

Between lines the sensor retracts along the beam, moves over and approaches; between passes it
climbs to a safe height above the part, moves over and comes down. Each segment follows a
trapezoidal speed profile; poses come out every 1 ms.

Layout: :mod:`twin.plan.lines` holds the plan's types, the lines of a pass, the motion and the
predicted observability; :mod:`twin.plan.auto` the automatic planner; this module
:func:`plan_scan`, which puts them together, and the package's public names.
"""

from __future__ import annotations

import mujoco
import mujoco.batch
import numpy as np

from algorithms.arraytypes import FloatArray
from algorithms.registration.uncertainty import OBSERVABILITY_TOL
from twin.cell import Cell
from twin.errors import TwinError
from twin.plan.auto import (
    NEW_FRACTION,
    NEW_NORMAL_DEG,
    REACH_ITERATIONS,
    REACH_STEP_M,
    REACH_STEP_RAD,
    AutoPlan,
    candidate_views,
    plan_auto_passes,
)
from twin.plan.lines import (
    ACCELERATION_M_S2,
    ANGULAR_SPEED_RAD_S,
    COORDINATE_NAMES,
    FIXED_WEAK_FRACTION,
    INCIDENCE_MARGIN_DEG,
    MIN_LINE_M,
    NORMAL_SMOOTHING_M,
    PLAN_STEP_M,
    RAY_START_M,
    SHARP_EDGE_DEG,
    STEP_JUMP_FACTOR,
    PassInfo,
    ScanPlan,
    _assemble,
    _Line,
    _pass_lines,
    _plan_single_pass,
    _predicted,
    _view3,
    pass_runs,
    plan_level_raster,
    scan_region,
    straight_poses,
)
from twin.scenario import PassSpec

__all__ = [
    "ACCELERATION_M_S2",
    "ANGULAR_SPEED_RAD_S",
    "COORDINATE_NAMES",
    "FIXED_WEAK_FRACTION",
    "INCIDENCE_MARGIN_DEG",
    "MIN_LINE_M",
    "NEW_FRACTION",
    "NEW_NORMAL_DEG",
    "NORMAL_SMOOTHING_M",
    "PLAN_STEP_M",
    "RAY_START_M",
    "REACH_ITERATIONS",
    "REACH_STEP_M",
    "REACH_STEP_RAD",
    "SHARP_EDGE_DEG",
    "STEP_JUMP_FACTOR",
    "AutoPlan",
    "PassInfo",
    "ScanPlan",
    "candidate_views",
    "pass_runs",
    "plan_auto_passes",
    "plan_level_raster",
    "plan_scan",
    "scan_region",
    "straight_poses",
]


def plan_scan(cell: Cell, dt: float = 0.001) -> ScanPlan:
    """Plan the scan on the nominal cell (poses in the world frame): the ``[scan]`` table's one
    pass, its explicit passes, or passes planned automatically."""
    if cell.which != "nominal":
        raise TwinError("scan planning uses the nominal cell (what the planner believes)")
    spec = cell.scenario.scan
    if spec.auto is not None:
        planned = plan_auto_passes(cell, spec, spec.auto)
        return _plan_passes(cell, planned.passes, dt, planned)
    if spec.passes is not None:
        return _plan_passes(cell, spec.passes, dt)
    return _plan_single_pass(cell, spec, dt)


def _plan_passes(cell: Cell, passes: tuple[PassSpec, ...], dt: float, planned: AutoPlan | None = None) -> ScanPlan:
    """Lines and motion of a list of passes (``planned``: the auto planner's lines and records)."""
    batch = mujoco.batch.Batch(cell.model, 1, nthread=1)
    index = cell.index
    lines: list[_Line] = []
    made: list[PassInfo] = []
    pts: list[FloatArray] = []
    nrm: list[FloatArray] = []
    for i, p in enumerate(passes):
        runs = pass_runs(cell, batch, p, index) if planned is None else planned.runs[i]
        if not runs:
            raise TwinError(
                f"scan pass {p.name!r}: no planning ray hits the part in its region within the sensor's "
                f"incidence limit (view {np.round(p.view, 3).tolist()}, workpiece frame)")
        new = _pass_lines(cell, p, i, runs, len(lines))
        pts.extend(r.points_wp for r in runs)
        nrm.extend(r.smooth_normals_wp for r in runs)
        rel, fixed = _predicted(np.concatenate(pts), np.concatenate(nrm), OBSERVABILITY_TOL)
        made.append(PassInfo(p.name, p.beam, _view3(p.view), len(new), len(lines),
                             "explicit pass of the scenario" + (f" (passes so far fix {', '.join(fixed)})"
                                                                if fixed else ""), rel, fixed))
        lines.extend(new)
    if planned is None:
        return _assemble(cell, lines, dt, tuple(made), ())
    # The auto planner's records, with the line counts as planned here.
    infos = tuple(PassInfo(a.name, a.beam, a.beam_wp, b.lines, b.first_line, a.reason,
                           a.predicted_min_relative_eigenvalue, a.fixed)
                  for a, b in zip(planned.infos, made, strict=True))
    return _assemble(cell, lines, dt, infos, planned.notes)
