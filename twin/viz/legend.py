"""The legend a recording carries as an image (``legend``, shown beside the views): the
deviation colour bar with its tolerance band and saturation marks, and a swatch per colour
the cell view uses. The viewer has no colour bar of its own for points."""

from __future__ import annotations

import io
from collections.abc import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from twin.deviation import DeviationScale, draw_colour_bar

LEGEND_ENTITY = "legend"


def bar_label(scale: DeviationScale, against: str) -> str:
    """The colour bar's caption: what is measured against what, the band, the marks."""
    return (f"signed deviation from {against} [um]\ngreen within +-{scale.tolerance_m * 1e6:.3g} um; "
            "magenta / violet beyond the scale; grey off the part")


def legend_image(scale: DeviationScale | None, swatches: Sequence[tuple[str, Sequence[int]]],
                 bar_label: str = "") -> bytes:
    """A PNG: the deviation colour bar (when there is a scale; ``bar_label`` under it) above the
    swatches (label, RGB 0-255), two columns."""
    rows = (len(swatches) + 1) // 2
    height = (1.35 if scale is not None else 0.2) + 0.24 * rows
    fig = Figure(figsize=(6.4, height), dpi=110)
    canvas = FigureCanvasAgg(fig)
    top = 1.0
    if scale is not None:
        bar_h = 0.28 / height
        ax = fig.add_axes((0.05, 1.0 - 0.42 / height, 0.9, bar_h))
        draw_colour_bar(fig, ax, scale, bar_label)
        ax.tick_params(labelsize=8)
        top = 1.0 - 1.2 / height
    axs = fig.add_axes((0.02, 0.0, 0.96, max(top, 0.05)))
    axs.set_axis_off()
    axs.set_xlim(0, 2)
    axs.set_ylim(0, max(rows, 1))
    for k, (label, rgb) in enumerate(swatches):
        x, y = (k % 2), rows - 1 - k // 2
        axs.add_patch(Rectangle((x + 0.02, y + 0.25), 0.08, 0.5, color=np.asarray(rgb[:3]) / 255.0))
        axs.text(x + 0.13, y + 0.5, label, va="center", fontsize=8)
    out = io.BytesIO()
    canvas.print_png(out)
    return out.getvalue()
