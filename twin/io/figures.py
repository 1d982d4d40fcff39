"""PNG figures of a scan, a run and a locate (matplotlib, no display needed), and the report
page that shows them (``report.html``) with the headline table and pass/fail.

Every figure states its units on its axes. The deviation colour scale is fixed
(:data:`DEVIATION_SCALE_UM`, the recording's), so figures of different runs compare.
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse

from algorithms.geometry.se3 import inv_pose, transform_points
from twin import evaluate

if TYPE_CHECKING:
    from twin.realize import Realized
    from twin.replay import ReplayLog
    from twin.scan import Scan

DEVIATION_SCALE_UM = 10.0
DPI = 110


def _figure(width: float, height: float):
    """A figure and its axes, without pyplot: nothing global changes (a notebook's backend
    stays as it is) and nothing is left open."""
    fig = Figure(figsize=(width, height))
    return fig, fig.subplots()


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    return path


def residual_histogram(residual_m: np.ndarray, sigma_m: float, path: Path, title: str) -> Path:
    """Histogram of point residuals [um] against the noise model N(0, sigma)."""
    r = np.asarray(residual_m, dtype=np.float64) * 1e6
    fig, ax = _figure(5.5, 3.6)
    lim = max(4 * sigma_m * 1e6, np.percentile(np.abs(r), 99.5) if len(r) else 1.0, 1e-3)
    ax.hist(r, bins=80, range=(-lim, lim), density=True, color="#4c78a8", alpha=0.8, label=f"points (n = {len(r)})")
    # the sensor's combined standard uncertainty as a normal law (its linearity part is in
    # truth a smooth systematic curve, so the histogram need not be normal)
    s = sigma_m * 1e6
    if s > 0:
        x = np.linspace(-lim, lim, 400)
        ax.plot(x, np.exp(-0.5 * (x / s) ** 2) / (s * np.sqrt(2 * np.pi)), color="#e45756",
                label=f"combined uncertainty N(0, {s:.2f} um)")
    ax.set_xlabel("signed distance to the true surface [um]")
    ax.set_ylabel("density [1/um]")
    ax.set_title(title)
    ax.legend(fontsize=8)
    return _save(fig, path)


def deviation_map(points_wp: np.ndarray, deviation_m: np.ndarray, outline_wp: list, path: Path, title: str) -> Path:
    """Top view (workpiece x-y [mm]) of points coloured by signed deviation [um] on the fixed scale."""
    fig, ax = _figure(6.0, 4.6)
    for seg in outline_wp:
        ax.plot(seg[:, 0] * 1e3, seg[:, 1] * 1e3, color="0.6", lw=0.4)
    sc = ax.scatter(points_wp[:, 0] * 1e3, points_wp[:, 1] * 1e3, c=deviation_m * 1e6, s=1.5, cmap="coolwarm",
                    vmin=-DEVIATION_SCALE_UM, vmax=DEVIATION_SCALE_UM)
    fig.colorbar(sc, ax=ax, label="signed deviation [um]")
    ax.set_aspect("equal")
    ax.set_xlabel("workpiece x [mm]")
    ax.set_ylabel("workpiece y [mm]")
    ax.set_title(title)
    return _save(fig, path)


def series(values: dict, ylabel: str, path: Path, title: str) -> Path:
    """Time series (name -> (t [s], values)) on the recording's timeline."""
    fig, ax = _figure(6.0, 3.4)
    for name, (t, v) in values.items():
        ax.plot(t, v, lw=0.8, label=name)
    ax.set_xlabel("recording time sim_time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    if len(values) > 1:
        ax.legend(fontsize=8)
    return _save(fig, path)


def error_ellipse(errors: dict, path: Path, title: str) -> Path:
    """Translation errors (x, y of the workpiece frame [um]) of one or more estimates against the
    truth, each with its 1 and 3 standard-deviation ellipses from its covariance."""
    fig, ax = _figure(4.8, 4.4)
    colours = ["#4c78a8", "#f58518", "#54a24b"]
    span = 1.0
    for (name, (xy_um, C_um2)), col in zip(errors.items(), colours, strict=False):
        ax.plot(*xy_um, "o", color=col, label=name)
        span = max(span, float(np.abs(xy_um).max()))
        if C_um2 is not None:
            w, V = np.linalg.eigh(C_um2)
            angle = float(np.degrees(np.arctan2(V[1, 1], V[0, 1])))
            for k, ls in ((1, "-"), (3, "--")):
                ax.add_patch(Ellipse((0, 0), 2 * k * np.sqrt(max(w[1], 0)), 2 * k * np.sqrt(max(w[0], 0)),
                                     angle=angle, fill=False, color=col, ls=ls, lw=0.9))
            span = max(span, 3 * float(np.sqrt(max(w.max(), 0))))
    ax.axhline(0, color="0.7", lw=0.5)
    ax.axvline(0, color="0.7", lw=0.5)
    ax.set_xlim(-1.2 * span, 1.2 * span)
    ax.set_ylim(-1.2 * span, 1.2 * span)
    ax.set_aspect("equal")
    ax.set_xlabel("translation error x [um] (workpiece frame)")
    ax.set_ylabel("translation error y [um]")
    ax.set_title(title + "\n(1 sigma solid, 3 sigma dashed)", fontsize=9)
    ax.legend(fontsize=8)
    return _save(fig, path)


def _outline(mesh) -> list:
    edges = mesh.face_adjacency_edges[mesh.face_adjacency_angles > np.radians(30)]
    return [mesh.vertices[e] for e in edges]


def _twist_covariance(localization, covariance) -> np.ndarray | None:
    """The (6, 6) covariance of the twist [omega, v] when every direction is determined."""
    D = np.asarray(localization.determined_directions, dtype=np.float64).reshape(-1, 6)
    if len(D) != 6 or covariance is None:
        return None
    return D.T @ np.asarray(covariance, dtype=np.float64) @ D


class PathReplay(Protocol):
    """A replayed process path as the figures read it (:class:`twin.pipeline.PathRun`)."""

    @property
    def name(self) -> str: ...

    @property
    def log(self) -> ReplayLog: ...

    @property
    def t_offset_s(self) -> float: ...


class RunOutcome(Protocol):
    """A run as the figures read it (:class:`twin.pipeline.RunResult`: io sits beside the
    pipeline in the layers and does not import it)."""

    @property
    def realized(self) -> Realized: ...

    @property
    def scan(self) -> Scan | None: ...

    @property
    def runs(self) -> Sequence[PathReplay]: ...

    @property
    def localization(self) -> Any: ...  # a RegistrationResult, or None (RunResult types it as object)

    @property
    def pose_covariance(self) -> np.ndarray | None: ...


class LocateOutcome(Protocol):
    """A locate run as the figures read it (:class:`twin.locate.LocateResult`, a layer above io)."""

    @property
    def realized(self) -> Realized: ...

    @property
    def scan(self) -> Scan | None: ...

    @property
    def T_coarse(self) -> np.ndarray | None: ...

    @property
    def T_final(self) -> np.ndarray | None: ...

    @property
    def covariance(self) -> np.ndarray | None: ...


def scan_figures(scan: Scan, realized: Realized, sigma_m: float, folder: Path) -> list[Path]:
    """Residual histogram and deviation map of a scan."""
    pts = scan.valid_points_base
    T_true = realized.T_base_workpiece_true
    dev = evaluate.surface_error_m(pts, T_true, realized.workpiece.index)
    on = np.abs(dev) < 1e-3
    p_wp = transform_points(inv_pose(T_true), pts[on])
    out = [residual_histogram(dev[on], sigma_m, folder / "scan_residuals.png", "scan points against the true surface"),
           deviation_map(p_wp, dev[on], _outline(realized.workpiece.mesh), folder / "scan_deviation_map.png",
                         "scan points: signed deviation (top view)")]
    return out


def run_figures(result: RunOutcome, sigma_m: float, folder: Path) -> list[Path]:
    """The figures of ``twin run``: the scan's, the paths' deviation and tracking, the error ellipse."""
    out: list[Path] = []
    if result.scan is not None:
        out += scan_figures(result.scan, result.realized, sigma_m, folder)
    if result.runs:
        dev = {r.name: (r.log.t + r.t_offset_s, r.log.deviation_m * 1e6) for r in result.runs}
        out.append(series(dev, "deviation from the planned path [um]", folder / "path_deviation.png",
                          "replayed tool centre against its path"))
        trk = {r.name: (r.log.t + r.t_offset_s, r.log.tracking_error_m * 1e6) for r in result.runs}
        out.append(series(trk, "servo tracking error [um]", folder / "tracking_error.png",
                          "TCP: true against commanded joints"))
    loc = result.localization
    if loc is not None:
        C = _twist_covariance(loc, result.pose_covariance)
        xi = evaluate.full_pose_errors(loc.T_world_workpiece, result.realized.T_base_workpiece_true, None)["twist"]
        if C is not None:
            out.append(error_ellipse({"estimate": (xi[3:5] * 1e6, C[3:5, 3:5] * 1e12)}, folder / "pose_error.png",
                                     "localization error against the truth"))
    return out


def locate_figures(result: LocateOutcome, sigma_m: float, folder: Path) -> list[Path]:
    """The figures of ``twin locate``: the coarse pass's residuals and map, and the error
    ellipses of the coarse and final poses."""
    out: list[Path] = []
    realized = result.realized
    if result.scan is not None:
        out += scan_figures(result.scan, realized, sigma_m, folder)
    T_true = realized.T_base_workpiece_true
    errs: dict[str, tuple[np.ndarray, np.ndarray | None]] = {}
    if result.T_coarse is not None:
        xi = evaluate.full_pose_errors(result.T_coarse, T_true, None)["twist"]
        errs["coarse"] = (xi[3:5] * 1e6, None)
    if result.T_final is not None:
        xi = evaluate.full_pose_errors(result.T_final, T_true, None)["twist"]
        errs["final"] = (xi[3:5] * 1e6, np.asarray(result.covariance)[3:5, 3:5] * 1e12)
    if errs:
        out.append(error_ellipse(errs, folder / "pose_error.png", "locate: pose errors against the truth"))
    return out


def report_page(report: dict, figures: list[Path], checks: list[tuple[str, bool, str]], path: Path,
                title: str) -> Path:
    """``report.html``: the pass/fail table, the headline numbers and the figures (relative links)."""
    rows = "\n".join(f"<tr><td>{html.escape(name)}</td><td class={'pass' if ok else 'fail'}>"
                     f"{'pass' if ok else 'FAIL'}</td><td>{html.escape(detail)}</td></tr>"
                     for name, ok, detail in checks)
    imgs = "\n".join(f'<figure><img src="{html.escape(p.name)}" alt="{html.escape(p.stem)}"></figure>'
                     for p in figures)
    head = "\n".join(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(str(v))}</td></tr>"
                     for k, v in report.items() if not isinstance(v, (dict, list)))
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}} td{{padding:2px 10px}}
.pass{{color:#1a7f37;font-weight:bold}} .fail{{color:#c62828;font-weight:bold}}
figure{{display:inline-block;margin:6px}} img{{max-width:520px}}</style></head>
<body><h1>{html.escape(title)}</h1>
<h2>Checks</h2><table>{rows}</table>
<h2>Headline</h2><table>{head}</table>
<h2>Figures</h2>{imgs}
<p>All numbers in <code>report.json</code>; units are in the field names.</p></body></html>
"""
    path.write_text(page)
    return path


def run_checks(report: dict) -> list[tuple[str, bool, str]]:
    """Pass/fail of a run's report: complete, trusted, errors within 3 reported standard
    deviations, no unintended contact, the CAD path's surface error within its bound."""
    loc = report.get("localization", {})
    pv = report.get("path_verification", {})
    cad = report.get("cad_path", {})
    out = [("complete", bool(report.get("complete")), report.get("failure", "")),
           ("trusted", bool(report.get("trusted")), loc.get("message", ""))]
    if loc.get("max_error_sigmas") is not None:
        out.append(("localization error within 3 sigma", loc["max_error_sigmas"] <= 3.0,
                    f"max {loc['max_error_sigmas']} sigma along the determined directions"))
    if pv:
        out.append(("no unintended contact", pv["unintended_contacts"] == 0, f"{pv['unintended_contacts']} contact(s)"))
    if "max_surface_error_mm" in cad and "surface_error_bound_mm" in cad:
        out.append(("CAD path on the true surface", cad["max_surface_error_mm"] <= cad["surface_error_bound_mm"],
                    f"{cad['max_surface_error_mm'] * 1e3:.2f} um against a bound of "
                    f"{cad['surface_error_bound_mm'] * 1e3:.2f} um"))
    return out


def locate_checks(report: dict) -> list[tuple[str, bool, str]]:
    """Pass/fail of a locate report against issue's bar: coarse within 1 mm and 1 deg, the
    qualified radius within 0.1 um of its truth, the final error within 3 standard deviations,
    every planned point hit, no unintended contact."""
    out = [("complete", bool(report.get("complete")), report.get("failure", "")),
           ("trusted", bool(report.get("trusted")), "")]
    if "coarse" in report:
        c = report["coarse"]
        out.append(("coarse within 1 mm and 1 deg", c["within_1mm_1deg"],
                    f"{c['rotation_error_deg']:.4f} deg, {c['translation_error_mm']:.4f} mm"))
    if "qualification" in report:
        e = report["qualification"]["effective_radius_error_um"]
        out.append(("effective radius within 0.1 um", abs(e) <= 0.1, f"{e:+.3f} um"))
    if "probing" in report:
        p = report["probing"]
        out.append(("every planned point hit", not p["misses"], f"{p['hits']} of {p['points']}"))
        out.append(("no unintended contact", p["unintended_contacts"] == 0, f"{p['unintended_contacts']} contact(s)"))
    if "fine" in report:
        f = report["fine"]
        out.append(("final error within 3 sigma", f["max_error_sigmas"] <= 3.0,
                    f"max {f['max_error_sigmas']} sigma (Mahalanobis {f['mahalanobis']})"))
    return out
