"""What ``twin cmm`` writes: plan and run reports (JSON-ready dicts), the hits as CSV, and the
side-by-side table of the three planners (Markdown). Part frame, metres and seconds in the
files; millimetres in the table for a reader."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from algorithms.probing.cmm_planning import Plan
from algorithms.probing.program import Goto
from twin.cmm_machine import CmmRun

#: Columns of hits.csv (part frame, metres, seconds).
HIT_COLUMNS = ("label", "x_m", "y_m", "z_m", "i", "j", "k", "measured_x_m", "measured_y_m", "measured_z_m",
               "deviation_m", "trigger_t_s", "miss")


def _r(v, digits: int = 9):
    if v is None:
        return None
    return [round(float(x), digits) for x in np.asarray(v).reshape(-1)]


def plan_report(p: Plan) -> dict:
    """A planner's result: its GOTOs with their reasons, the penetrations, predicted collisions."""
    gotos = [{"statement": k + 1, "xyz_m": _r(st.xyz_m), "reason": reason}
             for k, (st, reason) in enumerate(zip(p.program.statements, p.reasons, strict=True))
             if isinstance(st, Goto)]
    return {
        "method": p.method,
        "statements": len(p.program.statements),
        "measured_points": len(p.program.measurements),
        "gotos": gotos,
        "safety_plane": {"point_m": _r(p.plane.point_m), "normal": _r(p.plane.normal)},
        "penetrations": [{"entry_m": _r(pen.entry_m), "exit_m": _r(pen.exit_m), "effective": pen.effective,
                          "touches": len(pen.touches), "stylus": pen.stylus} for pen in p.penetrations],
        "predicted_collisions": [{"statement": c.statement + 1, "move": c.kind, "solid": c.check.part,
                                  "ball_centre_m": _r(c.check.ball_centre_m)} for c in p.collisions],
        "unresolved": list(p.unresolved),
    }


def run_report(run: CmmRun) -> dict:
    """A program's run in the twin: contacts (located), hits, path length, cycle time."""
    devs = [h.deviation_m for h in run.hits if h.deviation_m is not None]
    return {
        "program": run.program.name,
        "cycle_time_s": round(run.cycle_time_s, 3),
        "path_length_m": round(run.path_length_m, 6),
        "measured_points": len(run.hits),
        "misses": run.misses,
        "max_abs_deviation_m": round(max(map(abs, devs)), 9) if devs else None,
        "contacts": len(run.contacts),
        "contact_list": [{"solid": c.solid, "statement": c.statement + 1, "move": c.kind,
                          "first_t_s": round(c.first_t_s, 4), "last_t_s": round(c.last_t_s, 4),
                          "ball_centre_m": _r(c.ball_centre_m), "part_point_m": _r(c.part_point_m)}
                         for c in run.contacts],
        "hits": [{"label": h.label, "point_m": _r(h.point_m), "normal": _r(h.normal),
                  "measured_m": _r(h.measured_m), "deviation_m": None if h.deviation_m is None else
                  round(h.deviation_m, 9), "trigger_t_s": None if h.trigger_t_s is None else round(h.trigger_t_s, 4)}
                 for h in run.hits],
    }


def write_hits_csv(path: Path, run: CmmRun) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(HIT_COLUMNS)
        for h in run.hits:
            m = [None] * 3 if h.measured_m is None else list(h.measured_m)
            w.writerow([h.label, *h.point_m, *h.normal, *m, h.deviation_m, h.trigger_t_s, int(h.measured_m is None)])


def comparison_table(rows: list[dict]) -> str:
    """The planners side by side (Markdown): one row per program."""
    head = ("| program | GOTOs | predicted collisions | contact events in the twin | where (first) | path [mm] | "
            "cycle [s] | misses |\n|---|---|---|---|---|---|---|---|\n")
    lines = []
    for r in rows:
        first = r["run"]["contact_list"][0] if r["run"]["contact_list"] else None
        where = "" if first is None else (f"{first['solid']}, statement {first['statement']} ({first['move']}), "
                                          "part at (" + ", ".join(f"{1e3 * x:.1f}" for x in first["part_point_m"])
                                          + ") mm")
        lines.append(f"| {r['method']} | {len(r['plan']['gotos'])} | {len(r['plan']['predicted_collisions'])} | "
                     f"{r['run']['contacts']} | {where} | {1e3 * r['run']['path_length_m']:.0f} | "
                     f"{r['run']['cycle_time_s']:.1f} | {r['run']['misses']} |")
    return head + "\n".join(lines) + "\n"
