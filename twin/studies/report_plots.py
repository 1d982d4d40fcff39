"""The figures of a study's report that show each cell's Monte Carlo result (JCGM 101, 7.5-7.9).

- ``histogram_cell<i>.png``: per output quantity, the histogram of the ``ok`` trials' values
  (the approximation of the quantity's PDF), the Gaussian with the same estimate and standard
  uncertainty over it, and the ends of the 95 % probabilistically symmetric coverage interval;
- ``convergence_cell<i>.png``: per output quantity, how the estimate, the estimate +- u and the
  interval's ends move as trials are added (trial order), so one sees whether more trials would
  change the digits reported.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pyarrow as pa
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter, ScalarFormatter
from PIL import Image

from twin.studies.jcgm101 import symmetric_interval
from twin.studies.spec import Study

#: Points along the trial count at which the convergence curves are evaluated.
CONVERGENCE_POINTS = 60
#: Colours of a report's PNG.
PALETTE_COLOURS = 64


def figure(title: str, size: tuple[float, float] = (6.4, 4.0)) -> tuple[Figure, Axes]:
    """A figure with one axis, titled, with a light grid."""
    fig = Figure(figsize=size, dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    return fig, ax


def save(fig: Figure, path: Path) -> Path:
    """Write the figure under a hidden name, as a palette PNG (reports are committed: a plot in
    64 colours is a third of its size and reads the same), then move it into place."""
    tmp = path.with_name(f".{path.name}.partial.png")
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    buffer.seek(0)
    with Image.open(buffer) as image:
        image.convert("RGB").quantize(colors=PALETTE_COLOURS).save(tmp, format="PNG", optimize=True)
    tmp.replace(path)
    return path


def _grid(n: int, title: str) -> tuple[Figure, list[Axes]]:
    cols = min(3, n)
    rows = math.ceil(n / cols)
    fig = Figure(figsize=(3.6 * cols, 2.6 * rows + 0.4), dpi=80)
    FigureCanvasAgg(fig)
    axes = list(np.atleast_1d(fig.subplots(rows, cols)).ravel())
    for ax in axes[n:]:
        ax.set_visible(False)
    fig.suptitle(title, fontsize=10)
    return fig, axes[:n]


def _values(table: pa.Table, cell: int, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The ``ok`` trials' finite values of each column, in trial order."""
    c = np.asarray(table.column("cell").to_pylist())
    order = np.argsort(np.asarray(table.column("trial").to_pylist()), kind="stable")
    sel = order[(c[order] == cell) & (np.asarray(table.column("status").to_pylist(), dtype=object)[order] == "ok")]
    out = {}
    for name in columns:
        y = np.asarray(table.column(name).to_pylist(), dtype=np.float64)[sel]
        out[name] = y[np.isfinite(y)]
    return out


def _histogram(ax: Axes, name: str, y: np.ndarray) -> None:
    ax.set_title(name, fontsize=8)
    ax.tick_params(labelsize=7)
    if len(y) < 2:
        ax.text(0.5, 0.5, "fewer than 2 trials", ha="center", va="center", transform=ax.transAxes, fontsize=8)
        return
    ax.hist(y, bins=int(np.clip(np.sqrt(len(y)), 5, 40)), density=True, alpha=0.6, label="trials")
    mean, u = float(np.mean(y)), float(np.std(y, ddof=1))
    if u > 0:
        x = np.linspace(y.min() - u, y.max() + u, 200)
        ax.plot(x, np.exp(-0.5 * ((x - mean) / u) ** 2) / (u * math.sqrt(2 * math.pi)), "-", lw=1.2,
                label="Gaussian, same mean and u")
    lo, hi = symmetric_interval(y)
    for end in (lo, hi):
        if math.isfinite(end):
            ax.axvline(end, color="k", ls=":", lw=0.9)
    ax.set_ylabel("density", fontsize=7)


def _convergence(ax: Axes, name: str, y: np.ndarray) -> None:
    ax.set_title(name, fontsize=8)
    ax.tick_params(labelsize=7)
    if len(y) < 3:
        ax.text(0.5, 0.5, "fewer than 3 trials", ha="center", va="center", transform=ax.transAxes, fontsize=8)
        return
    m = np.unique(np.geomspace(2, len(y), min(CONVERGENCE_POINTS, len(y) - 1)).astype(int))
    mean = np.array([np.mean(y[:k]) for k in m])
    u = np.array([np.std(y[:k], ddof=1) for k in m])
    ends = np.array([symmetric_interval(y[:k]) for k in m])
    ax.plot(m, mean, "-", lw=1.2, label="estimate")
    ax.plot(m, mean + u, "--", color="C1", lw=0.9, label="estimate +- u")
    ax.plot(m, mean - u, "--", color="C1", lw=0.9)
    ax.plot(m, ends[:, 0], ":", color="k", lw=0.9, label="95 % interval ends")
    ax.plot(m, ends[:, 1], ":", color="k", lw=0.9)
    ax.set_xscale("log")
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("trials", fontsize=7)
    ax.grid(True, alpha=0.3, which="both")


def cell_plots(study: Study, table: pa.Table, cell: int, columns: tuple[str, ...], out: Path) -> list[Path]:
    """The histogram and the convergence figure of one cell (module docstring); their paths."""
    values = _values(table, cell, columns)
    paths = []
    for stem, draw, what in (("histogram", _histogram, "the ok trials' values, with the Gaussian of the same "
                              "mean and u and the 95 % interval's ends"),
                             ("convergence", _convergence, "estimate, estimate +- u and the 95 % interval's ends "
                              "against the number of trials")):
        fig, axes = _grid(len(columns), f"study {study.name}, cell {cell}: {what}")
        for ax, name in zip(axes, columns, strict=True):
            draw(ax, name, values[name])
        if axes[0].get_legend_handles_labels()[0]:
            axes[0].legend(fontsize=6)
        fig.tight_layout()
        paths.append(save(fig, Path(out) / f"{stem}_cell{cell}.png"))
    return paths
