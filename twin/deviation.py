"""Deviation of measured points from the CAD model at the ESTIMATED pose, as a metrology
program shows it (not against the simulator's true surface: a real cell has only the CAD),
and the one colour scale the recording, the report's figure and its legend share.

The scale comes from the scenario, never fixed:

* the tolerance band ``+-tolerance_m`` (``[tolerances] max_surface_deviation_m``) is green;
* beyond it, warm colours (yellow to red) for material outside the CAD surface (positive
  deviation), cold ones (cyan to blue) for material inside (negative), up to the saturation
  ``saturation_m = max(2 tolerance_m, 6 u_point_m)``: twice the tolerance, or three expanded
  uncertainties (k = 2) of one point, whichever is larger, so that neither a tight tolerance
  nor a noisy sensor saturates the whole map;
* beyond the saturation the points are marked: magenta above, violet below;
* points farther than :data:`OFF_PART_M` from the CAD surface (the table, fixtures) are grey.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points

OFF_PART_M = 1e-3
#: Colours [0-255] of the scale: anchor positions on u = deviation / saturation are set by the band.
BELOW_SATURATION = (150, 40, 220)
ABOVE_SATURATION = (235, 0, 235)
OFF_PART = (130, 130, 130)
IN_TOLERANCE = (40, 180, 70)
COLD_END, COLD_BAND = (30, 60, 210), (70, 205, 235)
WARM_BAND, WARM_END = (245, 220, 40), (210, 30, 30)


@dataclass(frozen=True)
class DeviationScale:
    """The deviation colour scale [m]: the green tolerance band and the saturation."""

    tolerance_m: float
    saturation_m: float

    def anchors(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions on u = deviation / saturation in [-1, 1], RGB [0-1]) of the piecewise-linear
        map: cold end, cold band edge, green band, warm band edge, warm end (the band's edges are
        sharp: the green is constant inside)."""
        b = min(self.tolerance_m / self.saturation_m, 1.0)
        eps = 1e-9
        pos = np.array([-1.0, -b, -b + eps, b - eps, b, 1.0])
        rgb = np.array([COLD_END, COLD_BAND, IN_TOLERANCE, IN_TOLERANCE, WARM_BAND, WARM_END]) / 255.0
        return pos, rgb


def deviation_scale(tolerance_m: float, u_point_m: float) -> DeviationScale:
    """The scale for a surface tolerance and a point's standard uncertainty [m]."""
    return DeviationScale(float(tolerance_m), float(max(2.0 * tolerance_m, 6.0 * u_point_m, 1e-9)))


def cad_deviation_m(points_base: np.ndarray, T_base_workpiece_estimate: np.ndarray, cad: MeshIndex) -> np.ndarray:
    """(N,) signed distance [m] of base-frame points to the CAD model placed at the estimated pose
    (positive outside the material); NaN farther than :data:`OFF_PART_M` (off the part)."""
    p = np.asarray(points_base, dtype=np.float64).reshape(-1, 3)
    if not len(p):
        return np.zeros(0)
    dev = cad.signed_distance(transform_points(inv_pose(T_base_workpiece_estimate), p))
    dev[np.abs(dev) > OFF_PART_M] = np.nan
    return dev


def deviation_colours(deviation_m: np.ndarray, scale: DeviationScale) -> np.ndarray:
    """(N, 3) uint8 colours of signed deviations [m] on ``scale`` (NaN: off the part)."""
    d = np.asarray(deviation_m, dtype=np.float64)
    u = np.nan_to_num(d, nan=0.0) / scale.saturation_m
    pos, rgb = scale.anchors()
    out = np.column_stack([np.interp(np.clip(u, -1.0, 1.0), pos, rgb[:, k]) for k in range(3)]) * 255.0
    out[u > 1.0] = ABOVE_SATURATION
    out[u < -1.0] = BELOW_SATURATION
    out[np.isnan(d)] = OFF_PART
    return np.rint(out).astype(np.uint8)


def deviation_summary(deviation_m: np.ndarray, scale: DeviationScale) -> dict:
    """Counts and statistics of the on-part deviations [um] for the report."""
    d = np.asarray(deviation_m, dtype=np.float64)
    on = d[np.isfinite(d)]
    n = len(on)
    within = int(np.sum(np.abs(on) <= scale.tolerance_m))
    return {"points_on_part": n, "points_off_part": int(len(d) - n),
            "tolerance_um": scale.tolerance_m * 1e6, "saturation_um": scale.saturation_m * 1e6,
            "within_tolerance": within, "within_tolerance_share": within / n if n else None,
            "rms_um": float(np.sqrt(np.mean(on**2)) * 1e6) if n else None,
            "min_um": float(on.min() * 1e6) if n else None, "max_um": float(on.max() * 1e6) if n else None}


def _rgb(c: Sequence[int]) -> tuple[float, float, float]:
    return (c[0] / 255.0, c[1] / 255.0, c[2] / 255.0)


def draw_colour_bar(fig, cax, scale: DeviationScale, label: str, fontsize: float = 9) -> None:
    """A horizontal colour bar of ``scale`` in the axes ``cax`` of the matplotlib figure ``fig``,
    with ticks at the band and the saturation [um] (the recording's legend and the report's map)."""
    from matplotlib.cm import ScalarMappable

    cmap, norm = deviation_colormap(scale)
    bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), cax=cax, orientation="horizontal", extend="both")
    t, s = scale.tolerance_m * 1e6, scale.saturation_m * 1e6
    ticks = sorted({-s, -t, 0.0, t, s}) if t < s else [-s, 0.0, s]
    bar.set_ticks(ticks)
    bar.set_ticklabels([f"{v:+.3g}" if v else "0" for v in ticks])
    bar.set_label(label, fontsize=fontsize)


def deviation_colormap(scale: DeviationScale):
    """The matplotlib colour map and normalisation [um] of :func:`deviation_colours` (the same
    anchors; beyond the saturation its marks), for figures and legends."""
    from matplotlib.colors import LinearSegmentedColormap, Normalize

    pos, rgb = scale.anchors()
    base = LinearSegmentedColormap.from_list("deviation", list(zip((pos + 1.0) / 2.0, rgb, strict=True)), N=1024)
    cmap = base.with_extremes(over=_rgb(ABOVE_SATURATION), under=_rgb(BELOW_SATURATION), bad=_rgb(OFF_PART))
    s_um = scale.saturation_m * 1e6
    return cmap, Normalize(-s_um, s_um)
