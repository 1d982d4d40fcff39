"""The stored layout every recording carries: a large 3D view of the cell framed on the work
(the arm's base, the part and whatever else must be seen), a 3D view of the part with the points
coloured by their deviation from the CAD model at the estimated pose, the legend, and a tab
container with the report (verdict, pose table; shown first) and the time series (titles with
units, each over the time range of its own stage).

The cell view shows what was logged up to the time cursor (a visible time range from the
start to the cursor): the scan points, the paths (logged when they are planned) and the
replayed tool tip grow as the cursor moves, while poses (the arm, the beam's frame) show their
latest value. The part view shows every point of the scan whatever the cursor: the deviation map.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from twin.viz.legend import LEGEND_ENTITY

if TYPE_CHECKING:
    from rerun.encodings import EntityPathLike

TIMELINE = "sim_time"
REPORT_ENTITY = "report"
#: The points coloured by their deviation from the CAD model at the estimate (the metrology map).
CAD_DEVIATION_ENTITY = "world/deviation/points"
#: Entities hidden until switched on: the points coloured otherwise (against the true surface,
#: by scan line, by sensor status) and the tool's transit moves between process lines.
ALTERNATIVE_COLOURINGS = ("world/scan/points_by_line", "world/scan/points_by_status")
HIDDEN_IN_PART_VIEW = ("world/scan/points",)


@dataclass(frozen=True)
class Plot:
    """One time-series tab: its entity, title (with units) and the stage's time span [s] on
    ``sim_time`` (None: the whole timeline)."""

    entity: str
    title: str
    span_s: tuple[float, float] | None = None


def stage_span(t0_s: float, t1_s: float) -> tuple[float, float]:
    """A stage's time span with a 2 % margin on each side."""
    pad = 0.02 * max(t1_s - t0_s, 1e-3)
    return (t0_s - pad, t1_s + pad)


def cumulative() -> rrb.VisibleTimeRange:
    """Everything from the start of the timeline up to the cursor."""
    return rrb.VisibleTimeRange(TIMELINE, start=rrb.TimeRangeBoundary.infinite(),
                                end=rrb.TimeRangeBoundary.cursor_relative())


def whole() -> rrb.VisibleTimeRange:
    """The whole timeline, wherever the cursor is."""
    return rrb.VisibleTimeRange(TIMELINE, start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite())


def span(span_s: tuple[float, float] | None) -> rrb.VisibleTimeRange:
    """A fixed span of ``sim_time`` [s], wherever the cursor is (the whole timeline for None)."""
    if span_s is None:
        return whole()
    return rrb.VisibleTimeRange(TIMELINE, start=rrb.TimeRangeBoundary.absolute(seconds=float(span_s[0])),
                                end=rrb.TimeRangeBoundary.absolute(seconds=float(span_s[1])))


def eye_on(focus_world: np.ndarray, extent_m: float) -> rrb.EyeControls3D:
    """A camera looking at ``focus_world`` from above and in front, far enough to frame ``extent_m``."""
    focus = np.asarray(focus_world, dtype=np.float64)
    offset = max(extent_m, 0.05) * np.array([1.1, -1.5, 1.3])
    return rrb.EyeControls3D(position=focus + offset, look_target=focus, eye_up=[0.0, 0.0, 1.0])


def framing(points_world: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre, extent [m]) of the box around what a view must show: the camera of
    :func:`eye_on` at that extent has all of it in the picture."""
    p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    lo, hi = p.min(axis=0), p.max(axis=0)
    return (lo + hi) / 2.0, 0.75 * float(np.linalg.norm(hi - lo))


def _hidden(paths) -> dict[EntityPathLike, rrb.EntityBehavior]:
    return {e: rrb.EntityBehavior(visible=False) for e in paths}


def send_blueprint(part_world: np.ndarray, part_extent_m: float, cell_world: np.ndarray, plots: list[Plot],
                   hidden: tuple[str, ...] = ()) -> None:
    """Send the layout to the active recording.

    Args:
        part_world: (3,) the part's centre, world frame [m].
        part_extent_m: the part's size [m].
        cell_world: (K, 3) world points the cell view must frame (the arm's base, the part's
            corners, a reference sphere).
        plots: the time-series tabs.
        hidden: more entities hidden in the cell view until switched on (transit moves).
    """
    centre, extent = framing(cell_world)
    main = rrb.Spatial3DView(origin="world", name="cell", eye_controls=eye_on(centre, extent),
                             time_ranges=cumulative(),
                             overrides=_hidden(ALTERNATIVE_COLOURINGS + (CAD_DEVIATION_ENTITY,) + tuple(hidden)))
    # the part view shows every point whatever the cursor: the deviation map of the whole scan
    # (the solid true part left out, so nothing hides the points)
    part = rrb.Spatial3DView(origin="world", name="part: deviation from the CAD at the estimate",
                             contents=["world/workpiece/**", "- world/workpiece/true/mesh", "world/deviation/**",
                                       "world/scan/points", "world/probe/**"],
                             eye_controls=eye_on(part_world, 0.45 * part_extent_m), time_ranges=whole(),
                             overrides=_hidden(HIDDEN_IN_PART_VIEW))
    legend = rrb.Spatial2DView(origin=LEGEND_ENTITY, name="legend")
    tabs = [rrb.TimeSeriesView(origin=p.entity, name=p.title, time_ranges=span(p.span_s)) for p in plots]
    report = rrb.TextDocumentView(origin=REPORT_ENTITY, name="report")
    right = rrb.Vertical(part, legend, rrb.Tabs(report, *tabs, active_tab=0), row_shares=[3, 1, 2])
    layout = rrb.Horizontal(main, right, column_shares=[3, 2])
    rr.send_blueprint(rrb.Blueprint(layout, rrb.TimePanel(timeline=TIMELINE, play_state="paused"),
                                    rrb.SelectionPanel(state="collapsed"), collapse_panels=False))


PATH_COLOURS = {"scan_path": ([40, 120, 255], [255, 150, 30]), "cad_path": ([170, 60, 220], [40, 200, 90])}
#: Colours [0-255] of the cell view's entities (each in the legend).
ESTIMATE_COLOUR = (40, 200, 255)
ITERATION_COLOUR = (255, 220, 0)
NOMINAL_COLOUR = (120, 120, 120)
COARSE_COLOUR = (255, 150, 40)
DROPPED_COLOUR = (255, 60, 160)
CONTACT_COLOUR = (255, 0, 0)
BEAM_COLOUR = (255, 40, 40)
