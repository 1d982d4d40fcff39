"""Document 002's workflow on the CMM: a teach file checked against the CAD model (touches on
the part, the operator's moves clear of it), then planned by the three planners of
:mod:`algorithms.probing.cmm_planning` (the safe-plane baseline, the document's algorithm and
the full-check variant). The programs run on the machine of :mod:`twin.cmm_machine`; a DMIS
program from elsewhere runs there too (:func:`run_dmis`), its tolerances evaluated on the
measured points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithms.errors import AlgorithmError
from algorithms.probing.cmm_planning import PLANNERS, Plan, plan, taught_path_collisions
from algorithms.probing.dmis.evaluation import Evaluation, evaluate
from algorithms.probing.dmis.model import DmisModel, Lowered, lower
from algorithms.probing.safety_plane import SafetyPlane, Station, Teach, penetrations, taught_path
from twin.cmm_machine import CmmRun, CmmSetup, execute
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



@dataclass(frozen=True)
class DmisRun:
    """A DMIS program run in the twin: the program the machine ran, its run, the results."""

    lowered: Lowered
    run: CmmRun
    evaluation: Evaluation


def run_dmis(model: DmisModel, setup: CmmSetup, rng: np.random.Generator,
             stylus_names: dict[str, str] | None = None) -> DmisRun:
    """Run a DMIS program read by :func:`algorithms.probing.dmis.reader.read_program` on the CMM
    and evaluate its features and tolerances on the measured points (part frame at the nominal
    pose, where the program's base coordinate system is).

    Raises:
        TwinError: a stylus the machine lacks (``stylus_names`` maps a program's stylus labels to
            the machine's), a program with nothing to run, or a move past the machine's range.
    """
    names = {k.upper(): v for k, v in (stylus_names or {}).items()}
    unknown = [s for s in model.styli if names.get(s.upper(), s) not in setup.styli]
    if unknown:
        raise TwinError(f"program {model.name!r} selects stylus {unknown[0]}, which the machine lacks (it has "
                        f"{', '.join(sorted(setup.styli))}): map it with --stylus {unknown[0]}=NAME")
    default = sorted(setup.styli)[0] if len(setup.styli) == 1 else None
    try:
        lowered = lower(model, names, default)
    except AlgorithmError as exc:
        raise TwinError(str(exc) + (f"; the machine has styli {', '.join(sorted(setup.styli))}: select one with "
                                    "SNSLCT" if default is None else "")) from None
    run = execute(lowered.program, setup, rng)
    by_label = {h.label: h.measured_m for h in run.hits}
    measured = [by_label.get(label) for label in lowered.touch_labels]
    return DmisRun(lowered, run, evaluate(model, measured))
