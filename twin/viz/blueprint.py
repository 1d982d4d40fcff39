"""The stored layout every recording carries: a large 3D view of the cell framed on the part,
a 3D view of the part with the points coloured by their signed deviation, the time series in
tabs (titles with units) and a text panel with the headline figures.

The cell view shows what was logged up to the time cursor (a visible time range from the
start to the cursor): the scan points and the replayed tool tip grow as the cursor moves,
while poses (the arm, the beam's frame) show their latest value. The part view shows every
point of the scan whatever the cursor: the deviation map.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

if TYPE_CHECKING:
    from rerun.encodings import EntityPathLike

TIMELINE = "sim_time"
REPORT_ENTITY = "report"
#: Entities that show the scan points coloured otherwise, hidden until switched on.
ALTERNATIVE_COLOURINGS = ("world/scan/points_by_line", "world/scan/points_by_status")


def cumulative() -> rrb.VisibleTimeRange:
    """Everything from the start of the timeline up to the cursor."""
    return rrb.VisibleTimeRange(TIMELINE, start=rrb.TimeRangeBoundary.infinite(),
                                end=rrb.TimeRangeBoundary.cursor_relative())


def whole() -> rrb.VisibleTimeRange:
    """The whole timeline, wherever the cursor is."""
    return rrb.VisibleTimeRange(TIMELINE, start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite())


def eye_on(focus_world: np.ndarray, extent_m: float) -> rrb.EyeControls3D:
    """A camera looking at ``focus_world`` from above and in front, far enough to frame ``extent_m``."""
    focus = np.asarray(focus_world, dtype=np.float64)
    offset = max(extent_m, 0.05) * np.array([1.1, -1.5, 1.3])
    return rrb.EyeControls3D(position=focus + offset, look_target=focus, eye_up=[0.0, 0.0, 1.0])


def send_blueprint(focus_world: np.ndarray, extent_m: float, plots: list[tuple[str, str]]) -> None:
    """Send the layout to the active recording.

    Args:
        focus_world: (3,) the part's centre, world frame [m]; extent_m: its size [m].
        plots: (entity, title with units) of each time series, one tab each.
    """
    eye = eye_on(focus_world, extent_m)
    # one colouring of the points at a time: by deviation; by scan line and by sensor status
    # are there to switch on
    hidden: dict[EntityPathLike, rrb.EntityBehavior] = {e: rrb.EntityBehavior(visible=False)
                                                        for e in ALTERNATIVE_COLOURINGS}
    main = rrb.Spatial3DView(origin="world", name="cell", eye_controls=eye, time_ranges=cumulative(),
                             overrides=hidden)
    # the part view shows every point whatever the cursor: the deviation map of the whole scan
    # (the solid true part left out, so nothing hides the points)
    part = rrb.Spatial3DView(origin="world", name="part: points by signed deviation",
                             contents=["world/workpiece/**", "- world/workpiece/true/mesh", "world/scan/points",
                                       "world/probe/**"],
                             eye_controls=eye_on(focus_world, 0.45 * extent_m), time_ranges=whole())
    tabs = [rrb.TimeSeriesView(origin=entity, name=title) for entity, title in plots]
    right: list[rrb.Container | rrb.View] = [part]
    if tabs:
        right.append(rrb.Tabs(*tabs))
    right.append(rrb.TextDocumentView(origin=REPORT_ENTITY, name="report"))
    layout = rrb.Horizontal(main, rrb.Vertical(*right, row_shares=[2, 1, 1][: len(right)]), column_shares=[3, 2])
    rr.send_blueprint(rrb.Blueprint(layout, rrb.TimePanel(timeline=TIMELINE, play_state="paused"),
                                    collapse_panels=False))


def deviation_colours(deviation_m: np.ndarray, scale_m: float) -> np.ndarray:
    """(n, 3) uint8: blue (-scale) - white (0) - red (+scale), saturated beyond; grey where the
    deviation is NaN (points off the part)."""
    u = np.clip(np.nan_to_num(deviation_m, nan=0.0) / scale_m, -1.0, 1.0)
    white = np.array([245.0, 245.0, 245.0])
    red, blue = np.array([200.0, 30.0, 30.0]), np.array([30.0, 70.0, 210.0])
    out = np.where(u[:, None] >= 0, white + u[:, None] * (red - white), white - u[:, None] * (blue - white))
    out[np.isnan(deviation_m)] = [130, 130, 130]
    return out.astype(np.uint8)


PATH_COLOURS = {"scan_path": ([40, 120, 255], [255, 150, 30]), "cad_path": ([170, 60, 220], [40, 200, 90])}
