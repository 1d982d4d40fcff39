"""PNG figures of a scan, a run and a locate (matplotlib, no display needed), and the report
page that shows them (``report.html``) with the headline table and pass/fail.

Every figure states its units on its axes. The deviation colour scale is fixed
(:data:`DEVIATION_SCALE_UM`, the recording's), so figures of different runs compare.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse

from twin import evaluate

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
    if np.any(np.abs(r) <= lim):
        ax.hist(r, bins=80, range=(-lim, lim), density=True, color="#4c78a8", alpha=0.8, label=f"points (n = {len(r)})")
    else:  # nothing measured on the part: say so instead of an empty (0/0) density
        ax.text(0.5, 0.5, "no point on the part", transform=ax.transAxes, ha="center", va="center")
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


def scan_figures(scan, realized, sigma_m: float, folder: Path) -> list[Path]:
    """Residual histogram and deviation map of a scan."""
    pts = scan.valid_points_base
    truth = evaluate.Evaluation(realized)
    dev = truth.surface_error_m(pts)
    on = np.abs(dev) < 1e-3
    p_wp = truth.in_true_workpiece(pts[on])
    out = [residual_histogram(dev[on], sigma_m, folder / "scan_residuals.png", "scan points against the true surface"),
           deviation_map(p_wp, dev[on], _outline(realized.workpiece.mesh), folder / "scan_deviation_map.png",
                         "scan points: signed deviation (top view)")]
    return out


def run_figures(result, sigma_m: float, folder: Path) -> list[Path]:
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
        xi = evaluate.Evaluation(result.realized).full_pose_errors(loc.T_world_workpiece)["twist"]
        if C is not None:
            out.append(error_ellipse({"estimate": (xi[3:5] * 1e6, C[3:5, 3:5] * 1e12)}, folder / "pose_error.png",
                                     "localization error against the truth"))
    return out


def locate_figures(result, sigma_m: float, folder: Path) -> list[Path]:
    """The figures of ``twin locate``: the coarse pass's residuals and map, and the error
    ellipses of the coarse and final poses."""
    out: list[Path] = []
    realized = result.realized
    if result.scan is not None:
        out += scan_figures(result.scan, realized, sigma_m, folder)
    truth = evaluate.Evaluation(realized)
    errs: dict[str, tuple[np.ndarray, np.ndarray | None]] = {}
    if result.T_coarse is not None:
        xi = truth.full_pose_errors(result.T_coarse)["twist"]
        errs["coarse"] = (xi[3:5] * 1e6, None)
    if result.T_final is not None:
        xi = truth.full_pose_errors(result.T_final)["twist"]
        errs["final"] = (xi[3:5] * 1e6, np.asarray(result.covariance)[3:5, 3:5] * 1e12)
    if errs:
        out.append(error_ellipse(errs, folder / "pose_error.png", "locate: pose errors against the truth"))
    return out


def report_page(report: dict, figures: list[Path], path: Path, title: str) -> Path:
    """``report.html``: the verdict and its checks (:mod:`twin.verdicts`: the deciding ones
    first, then those against the truth, shown only), the headline numbers and the figures."""
    checks = sorted(report.get("checks", []), key=lambda c: not c["decides"])
    rows = "\n".join(f"<tr><td>{html.escape(c['name'])}</td><td class={'pass' if c['passed'] else 'fail'}>"
                     f"{'pass' if c['passed'] else 'FAIL'}</td><td>{html.escape(c['detail'])}</td>"
                     f"<td>{'decides' if c['decides'] else 'shown only'}</td></tr>" for c in checks)
    verdict = "PASS" if report.get("passed") else "FAIL"
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
<h2>Verdict: <span class={verdict.lower()}>{verdict}</span></h2><table>{rows}</table>
<h2>Headline</h2><table>{head}</table>
<h2>Figures</h2>{imgs}
<p>All numbers in <code>report.json</code>; units are in the field names.</p></body></html>
"""
    path.write_text(page)
    return path
