"""The study's report: ``report.md`` (a table per grid cell) and a PNG plot.

Per grid cell: the factor values, the trials, and for each pose-error component (the twist
``[omega, v]`` in the workpiece frame, in urad and um) and the rmse: the mean, the standard
deviation and the 95 % coverage interval (the 2.5 and 97.5 percentiles over the cell's
successful trials), the success rate (status ``ok``) and the mean localization time. The plot
shows the translation error against the first numeric grid factor (one marker per trial, the
cell means joined), or against the cell index when no factor is numeric.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow as pa
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from twin.studies.spec import Study
from twin.studies.trials import TWIST_COLUMNS

REPORT = "report.md"
PLOT = "translation_error.png"
STAT_COLUMNS = TWIST_COLUMNS + ("rotation_error_deg", "translation_error_um", "rmse_um")


def _fmt(v: float) -> str:
    return "n/a" if not math.isfinite(v) else f"{v:.4g}"


def cell_stats(table: pa.Table, cell: int) -> dict:
    """Statistics of one cell: ``n``, ``success_rate``, ``mean_time_s`` and per column of
    ``STAT_COLUMNS`` (mean, std, p2.5, p97.5) over the trials with status ``ok``."""
    cells = np.asarray(table.column("cell").to_pylist())
    sel = cells == cell
    status = np.asarray(table.column("status").to_pylist(), dtype=object)[sel]
    ok = status == "ok"
    out: dict = {"n": int(sel.sum()), "success_rate": float(ok.mean()) if len(ok) else float("nan"),
                 "mean_time_s": float(np.mean(np.asarray(table.column("time_s").to_pylist())[sel]))}
    for c in STAT_COLUMNS:
        x = np.asarray(table.column(c).to_pylist(), dtype=np.float64)[sel][ok]
        if len(x) == 0:
            out[c] = (float("nan"),) * 4
            continue
        std = float(np.std(x, ddof=1)) if len(x) > 1 else float("nan")
        lo, hi = np.percentile(x, [2.5, 97.5])
        out[c] = (float(np.mean(x)), std, float(lo), float(hi))
    return out


def write_report(study: Study, table: pa.Table, out: Path) -> list[Path]:
    """Write ``report.md`` and the plot into ``out``; returns their paths (report first)."""
    out = Path(out)
    cells = study.cells
    lines = [f"# Study `{study.name}`", "",
             f"Base scenario `{study.scenario_path.name}`, {study.kind} trials, seed {study.seed}, "
             f"{study.n_cells} cell(s) x {study.trials} trial(s). Localization: "
             + ", ".join(f"{k} = {v}" for k, v in study.localize.items()) + ".", "",
             "Pose error: the twist `[omega, v]` with `T_est = T_true exp(xi)`, workpiece frame "
             "(omega in urad, v in um). Statistics over the trials with status `ok`; the 95 % "
             "coverage interval is the 2.5 and 97.5 percentiles.", "", f"![translation error]({PLOT})", ""]
    for i, values in enumerate(cells):
        s = cell_stats(table, i)
        factors = ", ".join(f"`{k}` = {v}" for k, v in values.items()) or "(no factor)"
        lines += [f"## Cell {i}: {factors}", "",
                  f"{s['n']} trials, success rate {s['success_rate'] * 100:.1f} %, "
                  f"mean localization time {s['mean_time_s'] * 1e3:.1f} ms.", "",
                  "| quantity | mean | std | 2.5 % | 97.5 % |", "|---|---|---|---|---|"]
        for c in STAT_COLUMNS:
            m, sd, lo, hi = s[c]
            lines.append(f"| {c} | {_fmt(m)} | {_fmt(sd)} | {_fmt(lo)} | {_fmt(hi)} |")
        lines.append("")
    plot = out / PLOT
    _plot(study, table, plot)
    report = out / REPORT
    tmp = out / f".{REPORT}.partial"
    tmp.write_text("\n".join(lines))
    tmp.replace(report)
    return [report, plot]


def _numeric_factor(study: Study) -> str | None:
    for f, levels in zip(study.factors, study.levels, strict=True):
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in levels):
            return f
    return None


def _plot(study: Study, table: pa.Table, path: Path) -> None:
    factor = _numeric_factor(study)
    fig = Figure(figsize=(6.4, 4.0), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    col = "cell" if factor is None else factor
    x = np.asarray(table.column(col).to_pylist(), dtype=np.float64)
    y = np.asarray(table.column("translation_error_um").to_pylist(), dtype=np.float64)
    ok = np.asarray(table.column("status").to_pylist(), dtype=object) == "ok"
    ax.plot(x[ok], y[ok], ".", alpha=0.4, label="trials (status ok)")
    xs = np.unique(x[ok])
    ax.plot(xs, [np.mean(y[ok][x[ok] == v]) for v in xs], "-o", label="mean per level")
    ax.set_xlabel("grid cell" if factor is None else factor)
    ax.set_ylabel("translation error [um]")
    ax.set_title(f"study {study.name}")
    ax.grid(True, alpha=0.3)
    ax.legend()
    tmp = path.with_name(f".{path.name}.partial.png")
    fig.savefig(tmp)
    tmp.replace(path)
