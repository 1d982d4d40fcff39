"""PNG figures of a scan, a run and a locate (matplotlib, no display needed), and the report
page that shows them (``report.html``) with the headline table and pass/fail.

Every figure states its units on its axes. The deviation map uses the recording's colour
scale (:mod:`twin.deviation`: the scenario's surface tolerance and the sensor's uncertainty).
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse

from algorithms.geometry.se3 import inv_pose, transform_points
from twin import evaluate
from twin.deviation import (
    OFF_PART_M,
    DeviationScale,
    cad_deviation_m,
    deviation_colours,
    deviation_scale,
    draw_colour_bar,
)
from twin.pose_table import free_components, table_rows, twist_covariance

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


def _arcsine_convolved(x_um: np.ndarray, white_um: float, amplitude_um: float) -> np.ndarray:
    """Density [1/um] of white Gaussian noise plus a sine of amplitude ``amplitude_um`` at a
    uniformly random phase (the arcsine law), by numerical convolution."""
    phase = np.linspace(0.0, np.pi, 721)[:-1] + np.pi / 1440.0
    offsets = amplitude_um * np.cos(phase)
    s = max(white_um, 1e-6)
    return np.mean(np.exp(-0.5 * ((x_um[:, None] - offsets[None, :]) / s) ** 2), axis=1) / (s * np.sqrt(2 * np.pi))


def residual_histogram(residual_m: np.ndarray, white_m: float, linearity_m: float, path: Path, title: str) -> Path:
    """Histogram of point residuals [um] against the sensor's error model: the white noise
    alone, N(0, white), and the white noise plus the linearity band (a sine of amplitude
    ``linearity_m`` at an unknown phase: the model's distribution over sensor units)."""
    r = np.asarray(residual_m, dtype=np.float64) * 1e6
    fig, ax = _figure(5.8, 3.9)
    w_um, l_um = white_m * 1e6, linearity_m * 1e6
    lim = max(4 * w_um + l_um, np.percentile(np.abs(r), 99.5) if len(r) else 1.0, 1e-3)
    if np.any(np.abs(r) <= lim):
        ax.hist(r, bins=80, range=(-lim, lim), density=True, color="#4c78a8", alpha=0.8, label=f"points (n = {len(r)})")
    else:  # nothing measured on the part: say so instead of an empty (0/0) density
        ax.text(0.5, 0.5, "no point on the part", transform=ax.transAxes, ha="center", va="center")
    x = np.linspace(-lim, lim, 400)
    if w_um > 0:
        ax.plot(x, np.exp(-0.5 * (x / w_um) ** 2) / (w_um * np.sqrt(2 * np.pi)), color="#54a24b",
                label=f"white noise N(0, {w_um:.2f} um)")
    if l_um > 0:
        ax.plot(x, _arcsine_convolved(x, w_um, l_um), color="#e45756",
                label=f"white + linearity band +-{l_um:.3g} um (over sensor units)")
    ax.set_xlabel("signed distance to the true surface [um]")
    ax.set_ylabel("density [1/um]")
    ax.set_title(title + "\n(one sensor unit: its linearity is ONE fixed curve, so the histogram\n"
                 "is that curve's spread plus the white noise, reduced by the incidence angle)", fontsize=8)
    ax.legend(fontsize=7)
    return _save(fig, path)


def deviation_map(points_wp: np.ndarray, deviation_m: np.ndarray, outline_wp: list, scale: DeviationScale, path: Path,
                  title: str) -> Path:
    """Top view (workpiece x-y [mm]) of points coloured by signed deviation [um] on ``scale``
    (the recording's colours, band and saturation marks; grey off the part)."""
    fig = Figure(figsize=(6.2, 5.4))
    ax = fig.add_axes((0.12, 0.26, 0.84, 0.64))
    cax = fig.add_axes((0.12, 0.09, 0.84, 0.035))
    for seg in outline_wp:
        ax.plot(seg[:, 0] * 1e3, seg[:, 1] * 1e3, color="0.6", lw=0.4)
    d_um = np.asarray(deviation_m, dtype=np.float64) * 1e6
    order = np.argsort(np.nan_to_num(np.abs(d_um), nan=-1.0))  # the largest deviations drawn last
    ax.scatter(points_wp[order, 0] * 1e3, points_wp[order, 1] * 1e3, c=deviation_colours(deviation_m[order], scale)
               / 255.0, s=1.5)
    draw_colour_bar(fig, cax, scale, f"signed deviation [um]: green within +-{scale.tolerance_m * 1e6:.3g} um; "
                    "magenta / violet beyond the scale", fontsize=8)
    ax.set_aspect("equal")
    ax.set_xlabel("workpiece x [mm]")
    ax.set_ylabel("workpiece y [mm]")
    ax.set_title(title, fontsize=9)
    fig.savefig(path, dpi=DPI)
    return path


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


PAIRS = ((0, 1), (0, 2), (1, 2), (3, 4), (3, 5), (4, 5))
LABELS = ("rx [urad]", "ry [urad]", "rz [urad]", "x [um]", "y [um]", "z [um]")


def pose_figure(errors: dict, path: Path, title: str) -> Path:
    """Every component of one or more estimates' error twists against the truth (workpiece frame;
    rotations [urad], translations [um]) in the six planes of pairs, each with its 1 and 3
    standard-deviation ellipses from its (6, 6) covariance [urad, um]; ``errors``: name ->
    (xi (6,), covariance or None, free (6,) bool: components the points leave free, not drawn)."""
    fig = Figure(figsize=(10.5, 6.6))
    axes = fig.subplots(2, 3)
    colours = ["#4c78a8", "#f58518", "#54a24b"]
    for ax, (a, b) in zip(axes.ravel(), PAIRS, strict=True):
        span = 1e-3
        for (name, (xi, C, free)), col in zip(errors.items(), colours, strict=False):
            if free[a] or free[b]:
                ax.text(0.5, 0.5, f"{name}: free", transform=ax.transAxes, ha="center", color=col, fontsize=8)
                continue
            ax.plot(xi[a], xi[b], "o", color=col, label=name, ms=4)
            span = max(span, abs(float(xi[a])), abs(float(xi[b])))
            if C is not None:
                w, V = np.linalg.eigh(np.asarray(C)[np.ix_([a, b], [a, b])])
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
        ax.set_xlabel(LABELS[a], fontsize=8)
        ax.set_ylabel(LABELS[b], fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(title + " (workpiece frame; 1 sigma solid, 3 sigma dashed; the truth at 0)", fontsize=9)
    return _save(fig, path)


def _outline(mesh) -> list:
    edges = mesh.face_adjacency_edges[mesh.face_adjacency_angles > np.radians(30)]
    return [mesh.vertices[e] for e in edges]


def white_and_linearity_m(scenario) -> tuple[float, float]:
    """The sensor's white reading noise (repeatability and quantisation) and its linearity
    amplitude [m], for the switched-on sources."""
    s, n = scenario.sensor, scenario.noise
    white = np.hypot(s.sigma_m if n.gaussian else 0.0, s.resolution_m / np.sqrt(12) if n.quantization else 0.0)
    return float(white), float(s.linearity_m if n.linearity else 0.0)


def scan_figures(scan, realized, sigma_m: float, folder: Path, T_estimate: np.ndarray | None = None) -> list[Path]:
    """Residual histogram against the true surface, and the deviation map: against the CAD model
    at ``T_estimate`` (the metrology map, the scenario's surface tolerance) when there is one,
    else against the true surface (green within the expanded uncertainty of a point)."""
    pts = scan.valid_points_base
    truth = evaluate.Evaluation(realized)
    dev = truth.surface_error_m(pts)
    on = np.abs(dev) < OFF_PART_M
    white, lin = white_and_linearity_m(realized.scenario)
    out = [residual_histogram(dev[on], white, lin, folder / "scan_residuals.png",
                              "scan points against the true surface")]
    outline = _outline(realized.workpiece.mesh)
    if T_estimate is not None:
        cad = cad_deviation_m(pts, T_estimate, realized.workpiece.index)
        scale = deviation_scale(realized.scenario.tolerances.max_surface_deviation_m, sigma_m)
        p_wp = transform_points(inv_pose(T_estimate), pts)
        out.append(deviation_map(p_wp, cad, outline, scale, folder / "scan_deviation_map.png",
                                 "scan points against the CAD at the estimated pose (top view)"))
    else:
        out.append(deviation_map(truth.in_true_workpiece(pts[on]), dev[on], outline,
                                 deviation_scale(2 * sigma_m, sigma_m), folder / "scan_deviation_map.png",
                                 "scan points against the TRUE surface (top view)"))
    return out


def run_figures(result, sigma_m: float, folder: Path) -> list[Path]:
    """The figures of ``twin run``: the scan's, the paths' deviation and tracking, the pose errors."""
    out: list[Path] = []
    loc = result.localization
    if result.scan is not None:
        out += scan_figures(result.scan, result.realized, sigma_m, folder,
                            None if loc is None else loc.T_world_workpiece)
    if result.runs:
        dev = {r.name: (r.log.t + r.t_offset_s, r.log.deviation_m * 1e6) for r in result.runs}
        out.append(series(dev, "deviation from the planned path [um]", folder / "path_deviation.png",
                          "replayed tool centre against its path"))
        trk = {r.name: (r.log.t + r.t_offset_s, r.log.tracking_error_m * 1e6) for r in result.runs}
        out.append(series(trk, "servo tracking error [um]", folder / "tracking_error.png",
                          "TCP: true against commanded joints"))
    if loc is not None:
        C = twist_covariance(loc.determined_directions, result.pose_covariance)
        xi = evaluate.Evaluation(result.realized).full_pose_errors(loc.T_world_workpiece)["twist"]
        free = free_components(loc.free_directions)
        out.append(pose_figure({"estimate": (xi * 1e6, None if C is None else C * 1e12, free)},
                               folder / "pose_error.png", "localization error against the truth"))
    return out


def locate_figures(result, sigma_m: float, folder: Path) -> list[Path]:
    """The figures of ``twin locate``: the coarse pass's residuals and map, and the errors of the
    coarse and final poses with the final pose's ellipses."""
    out: list[Path] = []
    realized = result.realized
    if result.scan is not None:
        out += scan_figures(result.scan, realized, sigma_m, folder,
                            result.T_final if result.T_final is not None else result.T_coarse)
    truth = evaluate.Evaluation(realized)
    errs: dict = {}
    none_free = np.zeros(6, dtype=bool)
    if result.T_coarse is not None:
        errs["coarse"] = (truth.full_pose_errors(result.T_coarse)["twist"] * 1e6, None, none_free)
    if result.T_final is not None:
        errs["final"] = (truth.full_pose_errors(result.T_final)["twist"] * 1e6, np.asarray(result.covariance) * 1e12,
                         none_free)
    if errs:
        out.append(pose_figure(errs, folder / "pose_error.png", "locate: pose errors against the truth"))
    return out


def _value(key: str, v) -> str:
    """A headline value for a reader: floats to 4 significant digits, paths by their name."""
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, str) and ("/" in v or "\\" in v) and key in ("scenario", "recording", "report", "out"):
        return Path(v).name
    return str(v)


def _pose_html(table: dict) -> str:
    rows = table_rows(table)
    head = "".join(f"<th>{html.escape(c)}</th>" for c in rows[0])
    body = "\n".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows[1:])
    free = ("<p>free (not determined by the points): " + html.escape("; ".join(table["free_directions"])) + "</p>"
            if table["free_directions"] else "")
    return (f"<table class=grid><tr>{head}</tr>\n{body}</table><p class=note>nominal, estimate, truth: "
            f"{html.escape(table['units']['nominal/estimate/truth'])}; error and sigma: "
            f"{html.escape(table['units']['error/std'])}</p>{free}")


def _deviation_html(dev: dict) -> str:
    if dev.get("within_tolerance_share") is None:
        return ""
    return (f"<h2>Surface against the CAD at the estimate</h2><p>{dev['within_tolerance']} of "
            f"{dev['points_on_part']} points ({dev['within_tolerance_share']:.1%}) within the surface tolerance "
            f"+-{dev['tolerance_um']:.3g} um; rms {dev['rms_um']:.2f} um, range {dev['min_um']:+.1f} to "
            f"{dev['max_um']:+.1f} um ({dev['points_off_part']} points off the part)</p>")


def report_page(report: dict, figures: list[Path], path: Path, title: str) -> Path:
    """``report.html``: the verdict and its checks (:mod:`twin.verdicts`: the deciding ones
    first, then those against the truth, shown only), the pose table, the surface against the
    CAD, the headline numbers and the figures."""
    checks = sorted(report.get("checks", []), key=lambda c: not c["decides"])
    rows = "\n".join(f"<tr><td>{html.escape(c['name'])}</td><td class={'pass' if c['passed'] else 'fail'}>"
                     f"{'pass' if c['passed'] else 'FAIL'}</td><td>{html.escape(c['detail'])}</td>"
                     f"<td>{'decides' if c['decides'] else 'shown only'}</td></tr>" for c in checks)
    verdict = "PASS" if report.get("passed") else "FAIL"
    imgs = "\n".join(f'<figure><img src="{html.escape(p.name)}" alt="{html.escape(p.stem)}"></figure>'
                     for p in figures)
    head = "\n".join(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(_value(k, v))}</td></tr>"
                     for k, v in report.items() if not isinstance(v, (dict, list)))
    table = report.get("localization", report.get("fine", {})).get("pose_table")
    pose = "" if table is None else "<h2>Pose</h2>" + _pose_html(table)
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}} td,th{{padding:2px 10px}}
.pass{{color:#1a7f37;font-weight:bold}} .fail{{color:#c62828;font-weight:bold}}
table.grid{{border-collapse:collapse}} table.grid td,table.grid th{{border:1px solid #ccc;text-align:right}}
.note{{color:#555;font-size:90%}} figure{{display:inline-block;margin:6px}} img{{max-width:520px}}</style></head>
<body><h1>{html.escape(title)}</h1>
<h2>Verdict: <span class={verdict.lower()}>{verdict}</span></h2><table>{rows}</table>
{pose}
{_deviation_html(report.get("deviation_vs_cad", {}))}
<h2>Headline</h2><table>{head}</table>
<h2>Figures</h2>{imgs}
<p>All numbers in <code>report.json</code>; units are in the field names.</p></body></html>
"""
    path.write_text(page)
    return path
