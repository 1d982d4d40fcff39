"""Document 002's workflow on the CMM: a teach file checked against the CAD model (touches on
the part, the operator's moves clear of it), then planned by the three planners of
:mod:`algorithms.probing.cmm_planning` (the safe-plane baseline, the document's algorithm and
the full-check variant). The programs run on the machine of :mod:`twin.cmm_machine`.
"""

from __future__ import annotations

import numpy as np

from algorithms.errors import AlgorithmError
from algorithms.probing.cmm_planning import PLANNERS, Plan, plan, taught_path_collisions
from algorithms.probing.safety_plane import SafetyPlane, Station, Teach, penetrations, taught_path
from twin.cmm_machine import CmmSetup
from twin.errors import TwinError

#: A taught touch must lie this close to the CAD surface [m].
TOUCH_ON_PART_M = 1e-4
#: ... and its normal within this angle of the surface's [deg].
TOUCH_NORMAL_DEG = 30.0


def check_teach(teach: Teach, setup: CmmSetup) -> list[Station]:
    """The teach's path, after checking it against the CAD model.

    Raises:
        TwinError: a stylus the machine lacks, a touch off the part or with a wrong normal, or
            a taught move that passes through the part (an operator cannot have made it).
    """
    try:
        stations = taught_path(teach, {k: (v.direction, v.reach_m) for k, v in setup.styli.items()},
                               {k: v.ball_radius_m for k, v in setup.styli.items()})
    except AlgorithmError as exc:
        raise TwinError(f"teach {teach.name!r}: {exc}") from None
    touches = teach.touches
    pts = np.array([t.point_m for t in touches])
    cp = setup.index.query(pts)
    sd = setup.index.signed_distance(pts)
    normals = setup.index.smooth_normals(cp.face, cp.foot)
    for t, d, n in zip(touches, sd, normals, strict=True):
        if abs(d) > TOUCH_ON_PART_M:
            raise TwinError(f"teach {teach.name!r}: touch {t.label} at {_mm(t.point_m)} does not lie on the part "
                            f"({1e3 * d:+.3f} mm from its surface; allowed {1e3 * TOUCH_ON_PART_M:.1f} mm)")
        tn = np.asarray(t.measure().normal)
        if float(tn @ n) < np.cos(np.radians(TOUCH_NORMAL_DEG)):
            ang = np.degrees(np.arccos(np.clip(tn @ n, -1, 1)))
            raise TwinError(f"teach {teach.name!r}: touch {t.label}'s normal is {ang:.0f} deg from the surface "
                            f"normal there (allowed {TOUCH_NORMAL_DEG:.0f} deg): the probe would not approach "
                            "the surface from outside")
    try:
        plane = teach.plane if teach.plane is not None else SafetyPlane.through_highest_point(setup.mesh.vertices)
        penetrations(stations, plane)
    except AlgorithmError as exc:
        raise TwinError(f"teach {teach.name!r}: {exc}") from None
    bad = taught_path_collisions(stations, setup.check)
    if bad:
        raise TwinError(f"teach {teach.name!r}: {bad[0]}" + (f" (and {len(bad) - 1} more)" if len(bad) > 1 else "")
                        + f"; the operator's moves must keep {1e3 * setup.sweep.clearance_m:.1f} mm from the part")
    return stations


def plan_programs(teach: Teach, setup: CmmSetup, methods: tuple[str, ...] = PLANNERS) -> dict[str, Plan]:
    """The teach planned by each method."""
    stations = check_teach(teach, setup)
    try:
        return {m: plan(m, teach, stations, setup.mesh.vertices, setup.styli, setup.check) for m in methods}
    except AlgorithmError as exc:
        raise TwinError(f"teach {teach.name!r}: {exc}") from None


def _mm(p) -> str:
    return "(" + ", ".join(f"{1e3 * float(x):.2f}" for x in p) + ") mm"

