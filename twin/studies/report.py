"""The study's report: ``report.md`` (a summary table and a table per grid cell) and PNG plots.

Per grid cell: the factor values, the trials, the success rate (status ``ok``), the rate within
the study's tolerance (``[success]``: rotation and translation error both within it), the
median localization time, the Cramer-Rao ratio ``sqrt(mean(xi^T C^-1 xi) / 6)`` over the
trials with status ``ok`` (1.00 attains the bound; C is the bound of the trial's own point set
at the truth), and for each pose-error component (the twist ``[omega, v]`` in the workpiece
frame, in urad and um), the rotation and translation errors and the rmse: the mean, the
standard deviation and the 95 % coverage interval (the 2.5 and 97.5 percentiles) over the
trials with status ``ok``. Components are given only where the trials' points fix all six
directions (a bound exists for every trial); elsewhere only the error magnitudes. Full trials
add the compensated CAD path's largest error (``path_error_max_um``).

Plots, each where the grid has the factor it needs (series: the other factors' values):

* ``translation_error.png``: the translation error against the first numeric factor;
* ``crlb.png``: RMS translation and rotation error against the noise sigma (``sensor.sigma_m``
  or ``points.noise_sigma_m``) with the Cramer-Rao bound's RMS (root of the trace) beside it;
* ``success_vs_angle.png``: the rate within tolerance against ``localize.init_angle_deg``;
* ``time_per_method.png``: the median localization time per ``localize.method``;
* ``subsampling.png``: per ``localize.subsample`` rule, the accuracy kept (RMS translation
  error without subsampling / with it) against the time saved (1 - time with / time without).
"""

from __future__ import annotations

import math
import subprocess
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import ScalarFormatter

from twin.studies.inputs import describe
from twin.studies.jcgm101 import BATCHES, INDICATIVE_BELOW, MIN_BATCH, decimals, fmt, fmt_se, summarize
from twin.studies.report_plots import cell_plots as _cell_plots
from twin.studies.report_plots import figure as _figure
from twin.studies.report_plots import save as _save
from twin.studies.spec import GUIDE_BATCH, PEER_METHODS, STAGE_METHODS, Study
from twin.studies.trials import TWIST_COLUMNS

REPORT = "report.md"
PLOT = "translation_error.png"
STAT_COLUMNS = TWIST_COLUMNS + ("rotation_error_deg", "translation_error_um", "rmse_um")
MAGNITUDE_COLUMNS = ("rotation_error_deg", "translation_error_um", "rmse_um")
#: Cells that get a histogram and a convergence plot (a grid of tens of cells would fill the
#: folder with figures; the tables hold every cell).
MAX_CELL_PLOTS = 6
#: What a study's results depend on besides its own inputs (which its manifest hashes).
CODE_PATHS = ("algorithms", "twin", "models", "pyproject.toml")
SIGMA_FACTORS = ("sensor.sigma_m", "points.noise_sigma_m")


def _fmt(v: float) -> str:
    return "n/a" if not math.isfinite(v) else f"{v:.4g}"


def _col(table: pa.Table, name: str, dtype=np.float64) -> np.ndarray:
    return np.asarray(table.column(name).to_pylist(), dtype=dtype)


def summary_stats(x: np.ndarray) -> tuple[float, float, float, float]:
    """(mean, standard deviation, 2.5 % and 97.5 % percentiles) of ``x``; NaN where undefined."""
    if len(x) == 0:
        return (float("nan"),) * 4
    std = float(np.std(x, ddof=1)) if len(x) > 1 else float("nan")
    lo, hi = np.percentile(x, [2.5, 97.5])
    return float(np.mean(x)), std, float(lo), float(hi)


def cell_stats(table: pa.Table, cell: int, success: dict | None = None) -> dict:
    """Statistics of one cell (module docstring): ``n``, ``success_rate``, ``within_rate``,
    ``median_time_s``, ``mean_time_s``, ``crlb_ratio``, ``determined`` and per column of
    ``STAT_COLUMNS`` (mean, std, p2.5, p97.5) over the trials with status ``ok``."""
    success = success or {"angle_deg": 1.0, "distance_m": 0.001}
    sel = _col(table, "cell", np.int64) == cell
    ok = (_col(table, "status", object) == "ok")[sel]
    rot, tra = _col(table, "rotation_error_deg")[sel], _col(table, "translation_error_um")[sel]
    within = (rot <= success["angle_deg"]) & (tra <= success["distance_m"] * 1e6)
    time_s = _col(table, "time_s")[sel]
    m2 = _col(table, "mahalanobis2")[sel][ok] if "mahalanobis2" in table.column_names else np.array([])
    n = int(sel.sum())
    status = _col(table, "status", object)[sel]
    posed = np.isfinite(rot) & np.isfinite(tra)
    out: dict = {"n": n, "n_ok": int(ok.sum()), "n_within": int(within.sum()), "n_posed": int(posed.sum()),
                 "n_ok_outside": int((ok & ~within).sum()),
                 "statuses": {k: int(v) for k, v in sorted(Counter(status.tolist()).items(),
                                                             key=lambda kv: (kv[0] != "ok", kv[0]))},
                 "all_translation_error_um": float(np.mean(tra[posed])) if posed.any() else float("nan"),
                 "all_rotation_error_deg": float(np.mean(rot[posed])) if posed.any() else float("nan"),
                 "success_rate": float(ok.mean()) if n else float("nan"),
                 "within_rate": float(within.mean()) if n else float("nan"),
                 "mean_time_s": float(np.mean(time_s)) if n else float("nan"),
                 "median_time_s": float(np.median(time_s)) if n else float("nan"),
                 "determined": bool(len(m2)) and bool(np.all(np.isfinite(m2))),
                 "crlb_ratio": float(np.sqrt(np.mean(m2) / 6.0)) if len(m2) and np.all(np.isfinite(m2))
                 else float("nan")}
    order = np.argsort(_col(table, "trial", np.int64)[sel], kind="stable") if "trial" in table.column_names \
        else np.arange(n)
    for prefix in ("u_crlb_", "u_lpu_"):  # root mean square over the ok trials (the mean variance)
        out[prefix] = {c: _rms(_col(table, prefix + c)[sel][ok]) if prefix + c in table.column_names
                       else float("nan") for c in TWIST_COLUMNS}
    out["outputs"] = {}
    for c in STAT_COLUMNS + ("path_error_max_um",):
        if c in table.column_names:
            x = _col(table, c)[sel]
            out[c] = summary_stats(x[ok])
            out["outputs"][c] = summarize(x[order][ok[order]])
    return out


def write_report(study: Study, table: pa.Table, out: Path, adaptive: list[dict] | None = None) -> list[Path]:
    """Write ``report.md`` and the plots into ``out``; returns their paths (report first).
    ``adaptive``: per cell, the trials the adaptive rule ran and whether it was met."""
    out = Path(out)
    if study.kind == "normals":
        return _write_normals_report(study, table, out)
    stats = [cell_stats(table, i, study.success) for i in range(study.n_cells)]
    plots = _plots(study, table, stats, out)
    lines = _head(study) + [f"![{p.stem}]({p.name})" for p in plots] + [""] + _summary_table(study, table, stats)
    cell_plots = []
    for i in range(study.n_cells):
        section, pngs = _cell_section(study, table, stats[i], i, out, None if adaptive is None else adaptive[i])
        lines += section
        cell_plots += pngs
    report = out / REPORT
    _write_atomic_text(report, "\n".join(lines) + "\n")
    return [report, *plots, *cell_plots]


def _head(study: Study) -> list[str]:
    """The report's title and what was run, measured and how the statistics are made."""
    tol = study.success
    head = [f"# Study `{study.name}`", "", f"Made with {provenance()}.", "",
            f"Base scenario `{study.scenario_path.name}`, {study.kind} trials, seed {study.seed}, "
            f"{study.n_cells} cell(s), " + (f"adaptive (JCGM 101, 7.9: {study.adaptive['digits']} significant "
                                           f"digit(s), M = {study.adaptive['batch']} trials per batch, at most "
                                           f"{study.trials} trials per cell)" if study.adaptive
                                           else f"{study.trials} trial(s) per cell") + ". Localization: "
            + ", ".join(f"{k} = {v}" for k, v in study.localize.items()) + ".", ""]
    if study.adaptive and study.adaptive["batch"] < GUIDE_BATCH:
        head += [f"**Warning**: {study.adaptive['batch']} trials per batch, fewer than the {GUIDE_BATCH} JCGM 101 "
                 "(7.9.4 a) asks for a 95 % interval: the batches' interval ends scatter more, and the rule can "
                 "stop on an interval that is not yet stable to the digits asked.", ""]
    head += _inputs(study)
    if study.kind == "points":
        head += ["Point sets: " + ", ".join(f"{k} = {v}" for k, v in study.points.items()) + ".", ""]
    head += ["Pose error: the twist `[omega, v]` with `T_est = T_true exp(xi)`, workpiece frame "
             "(omega in urad, v in um). `ok`: the localization's own verdict; `within`: rotation error "
             f"<= {tol['angle_deg']} deg and translation error <= {tol['distance_m'] * 1e3:g} mm. CRLB ratio: "
             "`sqrt(mean(xi^T C^-1 xi) / 6)` over the `ok` trials, C the Cramer-Rao bound of the trial's "
             "points at the truth with the white reading noise (1.00 attains the bound).", "",
             "Per cell and output quantity, as JCGM 101 (GUM Supplement 1) states a Monte Carlo result, over "
             "the trials with status `ok`: the estimate (the average) and its standard uncertainty `u` (the "
             "standard deviation) to two significant digits, the other values to the same decimal place; the "
             "95 % coverage intervals, probabilistically symmetric (7.7.1) and shortest (7.7.2); the Monte "
             f"Carlo standard error of each, from {BATCHES} batches of the trials in trial order (fewer below "
             f"{BATCHES * MIN_BATCH} trials, each of {MIN_BATCH} at least; 7.9.4), and "
             "whether twice each is within the numerical tolerance of `u`'s two digits (`stable`). Intervals "
             f"from fewer than {INDICATIVE_BELOW} trials are marked indicative. Every trial that is not `ok` "
             "is counted by its status; the error magnitudes are also given over every trial that returned "
             "a pose.", ""]
    return head


def _inputs(study: Study) -> list[str]:
    """How each error source of the base scenario enters the trials (``[inputs]``,
    :mod:`twin.studies.inputs`): random per reading, drawn per trial from its distribution, or
    held fixed -- so that a reader knows what the coverage intervals cover. Cell 0 in a table,
    then what differs in each other cell."""
    if study.kind not in ("fast", "full"):
        return []
    cells = []
    for c in range(study.n_cells):
        sc = study.cell_scenario(c)
        cells.append({r.label: (r, describe(r, sc)) for r in study.cell_inputs(c, sc).values()})
    lines = ["Uncertain inputs of cell 0's scenario and how the trials treat them (`[inputs]`):", "",
             "| input | in the trials |", "|---|---|"]
    lines += [f"| {label} | {how} |" for label, (r, how) in cells[0].items() if r.treatment != "off"] + [""]
    off = [label for label, (r, _) in cells[0].items() if r.treatment == "off"]
    if off:
        lines += ["Off: " + ", ".join(off) + ".", ""]
    for c, inputs in enumerate(cells[1:], start=1):
        changed = [f"{label}: {how}" for label, (_, how) in inputs.items() if how != cells[0][label][1]]
        if changed:
            lines += [f"Cell {c}: " + "; ".join(changed) + ".", ""]
    fixed = sorted({label for inputs in cells for label, (r, _) in inputs.items()
                    if r.treatment == "fixed" and r.name != "part_pose"})
    if fixed:
        lines += ["Held fixed: " + ", ".join(fixed) + ". Their effect is in each quantity's estimate (the mean "
                  "error), a bias, not in the intervals: the correction is minus the estimate.", ""]
    else:
        lines += ["No systematic effect is held fixed: each quantity's estimate (the mean error) should be zero "
                  "within 3 of its Monte Carlo standard errors; each cell says where it is not.", ""]
    return lines


def provenance() -> str:
    """What made the report: the package's version and, in a git checkout, its commit (with a
    note when the code differs from it: the packages, the models, the project file; reports and
    study files being written are not code)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        made = f"scan-twin {version('scan-twin')}"
    except PackageNotFoundError:
        made = "scan-twin"
    root = Path(__file__).resolve().parents[2]
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                             timeout=10, check=False)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", *CODE_PATHS],
                               cwd=root, capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return made
    if rev.returncode != 0 or not rev.stdout.strip():
        return made
    return f"{made} at commit {rev.stdout.strip()}" + (" with uncommitted changes" if dirty.stdout.strip() else "")


def _summary_table(study: Study, table: pa.Table, stats: list[dict]) -> list[str]:
    """One row per cell: factors, trials, ok and within counts, the trials ok outside the
    tolerance (a wrong answer called good; n/a for a stage or a peer), mean errors, CRLB ratio, time."""
    factors = list(study.factors)
    path = study.kind == "full"  # the compensated CAD path's error is known
    head = (["cell"] + [f"`{f}`" for f in factors]
            + ["trials", "ok", "within", "ok outside the tolerance", "translation error mean [um]",
               "rotation error mean [deg]", "CRLB ratio"]
            + (["compensated path error, max, mean [um]"] if path else []) + ["median time [ms]"])
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for i, values in enumerate(study.cells):
        s = stats[i]
        cells = ([str(i)] + [str(values[f]) for f in factors]
                 + [str(s["n"]), _count(s["n_ok"], s["n"]), _count(s["n_within"], s["n"]), _ok_outside(study, i, s),
                    _fmt(s["translation_error_um"][0]), _fmt(s["rotation_error_deg"][0]), _fmt(s["crlb_ratio"])]
                 + ([_fmt(s["path_error_max_um"][0])] if path else []) + [f"{s['median_time_s'] * 1e3:.3g}"])
        rows.append("| " + " | ".join(cells) + " |")
    return rows + [""]


def _ok_outside(study: Study, cell: int, s: dict) -> str:
    """The trials called ok outside the tolerance; "n/a" for a stage or a peer, whose ``ok``
    only says that it returned a pose (no verdict of its own)."""
    method = study.cell_settings(cell).localize["method"]
    return "n/a" if method in STAGE_METHODS + PEER_METHODS else str(s["n_ok_outside"])


def _count(k: int, n: int) -> str:
    """``k of n`` with the share, never rounded up to 100 % or down to 0 %."""
    if n == 0:
        return "0 of 0"
    share = 100.0 * k / n
    text = f"{share:.0f}" if k in (0, n) or 1 <= share <= 99 else f"{share:.1f}"
    return f"{k} of {n} ({text} %)"


def _cell_section(study: Study, table: pa.Table, s: dict, i: int, out: Path,
                  adaptive: dict | None) -> tuple[list[str], list[Path]]:
    """One cell: its trials by status, the JCGM 101 outputs of each quantity, its plots."""
    values = study.cells[i]
    factors_txt = ", ".join(f"`{k}` = {v}" for k, v in values.items()) or "(no factor)"
    extra = ""
    if adaptive is not None:
        met = "was met" if adaptive["stable"] else "was NOT met"
        extra = f" The adaptive rule {met} after {adaptive['trials']} trials."
        if not adaptive["stable"] and adaptive.get("unstable"):
            extra += " Not stable: " + ", ".join(f"`{q}`" for q in adaptive["unstable"]) + "."
    statuses = ", ".join(f"{k} {v}" for k, v in s["statuses"].items())
    lines = [f"## Cell {i}: {factors_txt}", "",
             f"{s['n']} trials ({statuses}), within tolerance {_count(s['n_within'], s['n'])}, median "
             f"localization time {s['median_time_s'] * 1e3:.3g} ms, CRLB ratio {_fmt(s['crlb_ratio'])}.{extra}", ""]
    path = study.kind == "full"
    columns = (STAT_COLUMNS if s["determined"] else MAGNITUDE_COLUMNS) + (("path_error_max_um",) if path else ())
    if not s["determined"]:
        lines += ["The points of some trials leave a direction free or weak: no component is reported.", ""]
    lines += _outputs_table(s, columns)
    if s["determined"]:
        lines += _bias_line(s) + _propagation_table(s)
    lines += [f"Over every trial that returned a pose ({s['n_posed']}): translation error mean "
              f"{_fmt(s['all_translation_error_um'])} um, rotation error mean {_fmt(s['all_rotation_error_deg'])} "
              "deg" + (" (the same trials as above)." if s["n_posed"] == s["n_ok"] else
                       f" ({s['n_posed'] - s['n_ok']} trial(s) not `ok` included)."), ""]
    pngs = _cell_plots(study, table, i, columns, out) if i < MAX_CELL_PLOTS else []
    if pngs:
        lines += [f"![{p.stem}]({p.name})" for p in pngs] + [""]
    elif i == MAX_CELL_PLOTS:
        lines += [f"Histograms and convergence plots are drawn for the first {MAX_CELL_PLOTS} cells; the tables "
                  "above and below hold every cell.", ""]
    return lines, pngs


def _bias_line(s: dict) -> list[str]:
    """The twist components whose mean error is more than 3 Monte Carlo standard errors from zero
    (nothing is claimed where there are too few trials for the standard errors)."""
    if not all(np.isfinite(s["outputs"][c].mc_se[0]) for c in TWIST_COLUMNS):
        return [f"Too few trials for the Monte Carlo standard errors ({2 * MIN_BATCH} at least): whether the mean "
                "error is zero is not tested.", ""]
    far = []
    for c in TWIST_COLUMNS:
        o = s["outputs"][c]
        if abs(o.values[0]) > 3.0 * o.mc_se[0]:
            far.append(f"`{c}` ({fmt(o.values[0], decimals(o.values[1]))}, standard error {fmt_se(o.mc_se[0])})")
    if not far:
        return ["Every component's mean error is within 3 Monte Carlo standard errors of zero.", ""]
    return ["Mean error beyond 3 Monte Carlo standard errors of zero (a bias: a fixed input, or an effect the "
            "trials do not average out): " + ", ".join(far) + ".", ""]


def _propagation_table(s: dict) -> list[str]:
    """Each twist component's Monte Carlo ``u`` beside the law of propagation's and the white
    noise's Cramer-Rao bound, and JCGM 101 section 8's check of the GUM's interval (the nominal
    zero error +- 1.96 u_LPU) against the Monte Carlo's symmetric one."""
    crlb, lpu = s["u_crlb_"], s["u_lpu_"]
    if not any(math.isfinite(v) for v in crlb.values()):
        return []
    has_lpu = any(math.isfinite(v) for v in lpu.values())
    head = ["component", "MC u", "Cramer-Rao (white noise)"]
    if has_lpu:
        head += ["LPU u", "of it: linearity curve", "GUM interval against MC: d_low, d_high", "GUM validated (8)"]
    lines = ["Monte Carlo against the Cramer-Rao bound of the white reading noise"
             + (" and the GUM law of propagation (LPU: that bound and the linearity curve, a Type B effect, "
                "propagated at the truth; root mean square over the trials)" if has_lpu else "") + ":", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for c in TWIST_COLUMNS:
        o = s["outputs"][c]
        places = decimals(o.values[1])
        row = [c, fmt(o.values[1], places), fmt(crlb[c], places)]
        if has_lpu:
            lin = math.sqrt(max(lpu[c] ** 2 - crlb[c] ** 2, 0.0)) if math.isfinite(lpu[c]) else float("nan")
            d_low, d_high = abs(-1.96 * lpu[c] - o.values[2]), abs(1.96 * lpu[c] - o.values[3])
            row += [fmt(lpu[c], places), fmt(lin, places), f"{fmt(d_low, places)}, {fmt(d_high, places)}",
                    gum_validation(d_low, d_high, o) + f" (tolerance {fmt_se(o.tolerance)})"]
        lines.append("| " + " | ".join(row) + " |")
    return lines + [""]


def gum_validation(d_low: float, d_high: float, o) -> str:
    """JCGM 101 clause 8's verdict on the GUM's interval: "yes" when both ends are within the
    numerical tolerance of the Monte Carlo's; "no" when an end is beyond it by more than twice the
    Monte Carlo's standard error of that end (decided whatever more trials would give);
    "undecided" otherwise (the Monte Carlo's ends are not known to the tolerance: more trials)."""
    if d_low <= o.tolerance and d_high <= o.tolerance:
        return "yes"
    se_low, se_high = o.mc_se[2], o.mc_se[3]
    if (np.isfinite(se_low) and d_low > o.tolerance + 2.0 * se_low) or \
            (np.isfinite(se_high) and d_high > o.tolerance + 2.0 * se_high):
        return "no"
    return "undecided (more trials)"


def _outputs_table(s: dict, columns: tuple[str, ...]) -> list[str]:
    """The JCGM 101 outputs of the cell's quantities (module docstring of :mod:`twin.studies.jcgm101`)."""
    note = " (indicative)" if s["n_ok"] < INDICATIVE_BELOW else ""
    lines = ["| quantity | trials | estimate | u | 95 % interval, symmetric" + note + " | 95 % interval, shortest"
             + note + " | MC standard error: estimate, u, ends (symmetric; shortest) | stable |",
             "|---|---|---|---|---|---|---|---|"]
    for c in columns:
        o = s["outputs"][c]
        v, e = o.values, o.mc_se
        places = decimals(v[1])
        se = (f"{fmt_se(e[0])}, {fmt_se(e[1])}, {fmt_se(e[2])} / {fmt_se(e[3])}; {fmt_se(e[4])} / {fmt_se(e[5])}"
              if np.all(np.isfinite(e)) else f"too few trials ({2 * MIN_BATCH} at least)")
        stable = "yes" if o.stable else ("n/a" if not np.all(np.isfinite(e)) else "no")
        lines.append(f"| {c} | {o.n} | {fmt(v[0], places)} | {fmt(v[1], places)} | [{fmt(v[2], places)}, "
                     f"{fmt(v[3], places)}] | [{fmt(v[4], places)}, {fmt(v[5], places)}] | {se} | {stable} |")
    return lines + [""]


def _write_atomic_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.partial")
    tmp.write_text(text)
    tmp.replace(path)


NORMALS_STATS = ("angle_rms_deg", "angle_p95_deg", "angle_max_deg", "over_5deg_share")


def _write_normals_report(study: Study, table: pa.Table, out: Path) -> list[Path]:
    """``kind = "normals"``: per cell the mean (and standard deviation) over the trials of each
    angle statistic, and a plot of the RMS angle per cell."""
    cell = _col(table, "cell", np.int64)
    ok = _col(table, "status", object) == "ok"
    factors = list(study.factors)
    lines = [f"# Study `{study.name}`", "", f"Made with {provenance()}.", "",
             f"Base scenario `{study.scenario_path.name}`, normals trials (document 004), seed {study.seed}, "
             f"{study.n_cells} cell(s), {study.trials} trial(s) per cell. Normals: "
             + ", ".join(f"{k} = {v}" for k, v in study.normals.items()) + ".", "",
             "Angles between the estimated normals and the model's smooth normals at the true pose, per "
             "trial over every point of the cloud (PCA unsigned); the table gives the mean and the standard "
             "deviation over the trials with status `ok`.", "", "![normals](normals.png)", "",
             "| " + " | ".join(["cell"] + [f"`{f}`" for f in factors] + [
                 "trials", "ok", "points", "RMS angle [deg]", "95 % angle [deg]", "max angle [deg]", "share > 5 deg",
                 "median time [ms]"]) + " |",
             "|---" * (len(factors) + 9) + "|"]
    labels, rms = [], []
    for i, values in enumerate(study.cells):
        sel = (cell == i) & ok
        st = {c: summary_stats(_col(table, c)[sel]) for c in NORMALS_STATS}
        n_pts = _col(table, "n_points")[cell == i]
        t_ms = float(np.median(_col(table, "time_s")[cell == i])) * 1e3
        lines.append("| " + " | ".join([str(i)] + [str(values[f]) for f in factors]) + f" | {int((cell == i).sum())} | "
                     f"{ok[cell == i].mean() * 100:.0f} % | {np.mean(n_pts):.0f} | "
                     + " | ".join(f"{_fmt(st[c][0])} ± {_fmt(st[c][1])}" for c in NORMALS_STATS[:3])
                     + f" | {st['over_5deg_share'][0] * 100:.2f} % | {t_ms:.3g} |")
        labels.append(", ".join(str(values[f]) for f in factors) or "all")
        rms.append(st["angle_rms_deg"][0])
    fig, ax = _figure(f"study {study.name}: RMS angle of the normals")
    ax.barh(np.arange(len(rms)), rms)
    ax.set_yticks(np.arange(len(rms)), labels, fontsize=7)
    ax.set_xscale("log")
    ax.set_xlabel("RMS angle to the true normals [deg]")
    fig.tight_layout()
    plot = _save(fig, out / "normals.png")
    report = out / REPORT
    _write_atomic_text(report, "\n".join(lines) + "\n")
    return [report, plot]


# ------------------------------------------------------------------ plots
def _series(study: Study, x_factor: str, skip: tuple[str, ...] = ()) -> dict[str, list[int]]:
    """Cells grouped by the values of the factors other than ``x_factor`` (and ``skip``)."""
    groups: dict[str, list[int]] = {}
    for i, values in enumerate(study.cells):
        label = ", ".join(f"{k.split('.')[-1]}={v}" for k, v in values.items() if k != x_factor and k not in skip)
        groups.setdefault(label or "all", []).append(i)
    return groups


def _plots(study: Study, table: pa.Table, stats: list[dict], out: Path) -> list[Path]:
    makers: list[tuple[str, Callable[[], Figure | None]]] = [
        (PLOT, lambda: _plot_translation(study, table)),
        ("crlb.png", lambda: _plot_crlb(study, table)),
        ("success_vs_angle.png", lambda: _plot_success(study, stats)),
        ("time_per_method.png", lambda: _plot_time(study, stats)),
        ("subsampling.png", lambda: _plot_subsampling(study, stats)),
    ]
    paths = []
    for name, make in makers:
        fig = make()
        if fig is not None:
            paths.append(_save(fig, out / name))
        else:
            (out / name).unlink(missing_ok=True)
    return paths


def _numeric_factor(study: Study) -> str | None:
    for f, levels in zip(study.factors, study.levels, strict=True):
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in levels):
            return f
    return None


def _plot_translation(study: Study, table: pa.Table) -> Figure:
    factor = _numeric_factor(study)
    fig, ax = _figure(f"study {study.name}: translation error")
    col = "cell" if factor is None else factor
    x = _col(table, col)
    y = _col(table, "translation_error_um")
    ok = _col(table, "status", object) == "ok"
    ax.plot(x[ok], y[ok], ".", alpha=0.4, label="trials (status ok)")
    xs = np.unique(x[ok])
    ax.plot(xs, [np.mean(y[ok][x[ok] == v]) for v in xs], "-o", label="mean per level")
    ax.set_xlabel("grid cell" if factor is None else factor)
    ax.set_ylabel("translation error [um]")
    ax.legend(fontsize=8)
    return fig


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def _plot_crlb(study: Study, table: pa.Table) -> Figure | None:
    factor = next((f for f in SIGMA_FACTORS if f in study.factors), None)
    if factor is None:
        return None
    fig = Figure(figsize=(9.6, 4.0), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    cell = _col(table, "cell", np.int64)
    ok = _col(table, "status", object) == "ok"
    v = np.column_stack([_col(table, c) for c in TWIST_COLUMNS[3:]])
    w = np.column_stack([_col(table, c) for c in TWIST_COLUMNS[:3]])
    for label, cells in _series(study, factor).items():
        xs = np.array([study.cells[i][factor] for i in cells], dtype=np.float64) * 1e6
        for ax, err, bound_col in ((axes[0], v, "crlb_translation_um"), (axes[1], w, "crlb_rotation_urad")):
            rms = [_rms(np.linalg.norm(err[(cell == i) & ok], axis=1)) for i in cells]
            bnd = [_rms(_col(table, bound_col)[(cell == i) & ok]) for i in cells]
            line, = ax.plot(xs, rms, "o-", label=f"{label}: RMS error")
            ax.plot(xs, bnd, "--", color=line.get_color(), label=f"{label}: Cramer-Rao")
    for ax, what in ((axes[0], "translation error [um]"), (axes[1], "rotation error [urad]")):
        ax.set_xlabel(f"{factor} [um]")
        ax.set_ylabel(what)
        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_formatter(ScalarFormatter())
            axis.set_minor_formatter(ScalarFormatter())
        ax.grid(True, alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.suptitle(f"study {study.name}: pose error against sigma, with the Cramer-Rao bound", fontsize=10)
    fig.tight_layout()
    return fig


def _plot_success(study: Study, stats: list[dict]) -> Figure | None:
    factor = "localize.init_angle_deg"
    if factor not in study.factors:
        return None
    fig, ax = _figure(f"study {study.name}: rate within tolerance against the initial angle")
    for label, cells in _series(study, factor).items():
        xs = [study.cells[i][factor] for i in cells]
        ax.plot(xs, [stats[i]["within_rate"] * 100 for i in cells], "o-", label=label)
    ax.set_xlabel("initial rotation error [deg]")
    ax.set_ylabel(f"within {study.success['angle_deg']} deg / {study.success['distance_m'] * 1e3:g} mm [%]")
    ax.set_ylim(-5, 105)
    ax.legend(fontsize=7)
    return fig


def _plot_time(study: Study, stats: list[dict]) -> Figure | None:
    factor = "localize.method"
    if factor not in study.factors:
        return None
    fig, ax = _figure(f"study {study.name}: median localization time per method")
    groups = _series(study, factor)
    width = 0.8 / max(len(groups), 1)
    methods = list(dict.fromkeys(study.cells[i][factor] for i in range(study.n_cells)))
    for k, (label, cells) in enumerate(groups.items()):
        t = {study.cells[i][factor]: stats[i]["median_time_s"] * 1e3 for i in cells}
        ax.bar(np.arange(len(methods)) + k * width, [t.get(m, np.nan) for m in methods], width, label=label)
    ax.set_xticks(np.arange(len(methods)) + 0.4 - width / 2, methods, rotation=20, fontsize=8)
    ax.set_ylabel("median time [ms]")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    return fig


def _plot_subsampling(study: Study, stats: list[dict]) -> Figure | None:
    factor = "localize.subsample"
    if factor not in study.factors or "none" not in study.levels[study.factors.index(factor)]:
        return None
    fig = Figure(figsize=(8.0, 5.0), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.set_title(f"study {study.name}: accuracy kept against time saved", fontsize=10)
    ax.grid(True, alpha=0.3)
    rules = [r for r in study.levels[study.factors.index(factor)] if r != "none"]
    colours = {r: f"C{k}" for k, r in enumerate(rules)}
    for label, cells in _series(study, factor).items():
        by_rule = {study.cells[i][factor]: stats[i] for i in cells}
        ref = by_rule.get("none")
        if ref is None:
            continue
        for rule in rules:
            s = by_rule.get(rule)
            if s is None:
                continue
            kept = _rms_of(ref) / _rms_of(s) * 100
            saved = (1.0 - s["median_time_s"] / ref["median_time_s"]) * 100
            ax.plot(saved, kept, "o", color=colours[rule])
            ax.annotate(", ".join(p.split("=", 1)[-1] for p in label.split(", ")), (saved, kept), fontsize=6,
                        xytext=(3, 2), textcoords="offset points", color=colours[rule])
    for rule in rules:
        ax.plot([], [], "o", color=colours[rule], label=rule)
    ax.axhline(90, color="grey", lw=0.8, ls="--", label="90 % of the accuracy")
    ax.set_xlabel("time saved [%] (median time, against no subsampling)")
    ax.set_ylabel("accuracy kept [%] (RMS translation error, all / subset)")
    ax.legend(fontsize=8, title=", ".join(f.split(".")[-1] for f in study.factors if f != factor), title_fontsize=7)
    return fig


def _rms_of(s: dict) -> float:
    """RMS translation error of a cell from its mean and standard deviation."""
    m, sd = s["translation_error_um"][0], s["translation_error_um"][1]
    return float(np.sqrt(m**2 + (sd if math.isfinite(sd) else 0.0) ** 2))
