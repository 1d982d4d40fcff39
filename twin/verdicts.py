"""The verdict of a finished command: every check of what the user asked for, from the report
and the scenario's ``[tolerances]`` (:class:`twin.scenario.ToleranceSpec`).

A check either decides the exit status or informs. The deciding checks cover what was asked:
the run finished, its localization can be trusted, each process path was kept at the
scenario's coverage, replayed within its deviation and penetration tolerances, without an
unintended contact (``twin run``); the fine pose was measured at every planned point, trusted,
within its uncertainty tolerance (``twin locate``). A failed deciding check makes the command
exit 3, and the check is named on stdout and in ``report.json`` (``checks``, ``passed``).

The informing checks compare the result with the simulator's truth at a stated coverage (the
error within 3 standard deviations, the CAD path within its 3-sigma bound): a sound run fails
them at about their nominal rate, so they are shown, not decided on.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from twin.scenario import ToleranceSpec

MM, UM = 1e3, 1e6
PATHS = ("scan_path", "cad_path")


@dataclass(frozen=True)
class Check:
    """One check: its name, whether it passed, what was measured against what, and whether it
    decides the exit status."""

    name: str
    passed: bool
    detail: str
    decides: bool = True

    def to_dict(self) -> dict:
        return asdict(self)


def passed(checks: list[Check]) -> bool:
    """Whether every deciding check passed."""
    return all(c.passed for c in checks if c.decides)


def failed_names(checks: list[Check]) -> list[str]:
    return [c.name for c in checks if c.decides and not c.passed]


def _path_checks(name: str, block: dict, tol: ToleranceSpec) -> list[Check]:
    v = block["verification"]
    cov = block["coverage"]
    dropped = len(block["dropped"])
    out = [Check(f"{name}: coverage", cov >= tol.min_process_coverage,
                 f"{block['kept_points']} of {block['planned_points']} planned contact points kept ({cov:.1%}; "
                 f"{dropped} stretch(es) dropped); at least {tol.min_process_coverage:.0%} required")]
    dev = v["max_deviation_mm"]
    if dev is not None:
        out.append(Check(f"{name}: replay deviation", dev <= tol.max_replay_deviation_m * MM,
                         f"max {dev * 1e3:.1f} um from the planned path; at most "
                         f"{tol.max_replay_deviation_m * UM:.1f} um allowed"))
    pen = v.get("tip_penetration_max_mm")
    if pen is not None:
        out.append(Check(f"{name}: tip penetration", pen <= tol.max_tip_penetration_m * MM,
                         f"max {pen * 1e3:.1f} um into the part; at most {tol.max_tip_penetration_m * UM:.1f} um "
                         "allowed"))
    out.append(Check(f"{name}: no unintended contact", v["unintended_contacts"] == 0,
                     f"{v['unintended_contacts']} contact(s)"))
    return out


def run_checks(report: dict, tol: ToleranceSpec) -> list[Check]:
    """The checks of a ``twin run`` report."""
    loc = report.get("localization", {})
    out = [Check("complete", bool(report.get("complete")), report.get("failure", "every stage finished")),
           Check("trusted", bool(report.get("trusted")), loc.get("message", "no localization"))]
    for name in PATHS:
        if "verification" in report.get(name, {}):
            out += _path_checks(name, report[name], tol)
    if loc.get("max_error_sigmas") is not None:
        out.append(Check("localization error within 3 sigma (truth)", loc["max_error_sigmas"] <= 3.0,
                         f"max {loc['max_error_sigmas']} sigma along the determined directions", decides=False))
    cad = report.get("cad_path", {})
    if "max_surface_error_mm" in cad and "surface_error_bound_mm" in cad:
        out.append(Check("CAD path on the true surface (truth)",
                         cad["max_surface_error_mm"] <= cad["surface_error_bound_mm"],
                         f"{cad['max_surface_error_mm'] * 1e3:.2f} um against a bound of "
                         f"{cad['surface_error_bound_mm'] * 1e3:.2f} um", decides=False))
    return out


def locate_checks(report: dict, tol: ToleranceSpec) -> list[Check]:
    """The checks of a ``twin locate`` report."""
    fine = report.get("fine", {})
    out = [Check("complete", bool(report.get("complete")), report.get("failure", "every stage finished")),
           Check("trusted", bool(report.get("trusted")), fine.get("message", "no fine pose"))]
    if "probing" in report:
        p = report["probing"]
        out.append(Check("every planned point hit", not p["misses"], f"{p['hits']} of {p['points']}"))
        out.append(Check("no unintended contact", p["unintended_contacts"] == 0,
                         f"{p['unintended_contacts']} contact(s)"))
    if "std_translation_um" in fine:
        u_pos_um = 2.0 * max(fine["std_translation_um"])
        u_rot_rad = math.radians(2.0 * max(fine["std_rotation_deg"]))
        out.append(Check("final position uncertainty", u_pos_um <= tol.max_position_uncertainty_m * UM,
                         f"U (k = 2) {u_pos_um:.2f} um along the worst axis; at most "
                         f"{tol.max_position_uncertainty_m * UM:.2f} um allowed"))
        out.append(Check("final rotation uncertainty", u_rot_rad <= tol.max_rotation_uncertainty_rad,
                         f"U (k = 2) {u_rot_rad * UM:.1f} urad about the worst axis; at most "
                         f"{tol.max_rotation_uncertainty_rad * UM:.1f} urad allowed"))
    if "coarse" in report:
        c = report["coarse"]
        out.append(Check("coarse within 1 mm and 1 deg (truth)", c["within_1mm_1deg"],
                         f"{c['rotation_error_deg']:.4f} deg, {c['translation_error_mm']:.4f} mm", decides=False))
    if "qualification" in report:
        e = report["qualification"]["effective_radius_error_um"]
        out.append(Check("effective radius within 0.1 um (truth)", abs(e) <= 0.1, f"{e:+.3f} um", decides=False))
    if "max_error_sigmas" in fine:
        out.append(Check("final error within 3 sigma (truth)", fine["max_error_sigmas"] <= 3.0,
                         f"max {fine['max_error_sigmas']} sigma (Mahalanobis {fine['mahalanobis']})", decides=False))
    return out


def add_verdict(report: dict, checks: list[Check]) -> dict:
    """``report`` with its ``checks`` and ``passed`` (every deciding check passed)."""
    report["checks"] = [c.to_dict() for c in checks]
    report["passed"] = passed(checks)
    return report
