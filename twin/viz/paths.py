"""Process paths: planned and replayed tool paths, tool frames, normals.

The planned geometry is logged at the time the path exists (after the localization that
produced it), so the cell view does not show it before the scan; the replayed tool centre is
a trail on the process lines (``tcp``) and a thin line over the transit moves between them
(``transit``, hidden until switched on)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from twin.cell import Cell
from twin.viz.cell import send_arm
from twin.viz.columns import POSE_PERIOD_S, TIMELINE, every, send_series

if TYPE_CHECKING:
    from twin.replay import ReplayLog

FRAME_EVERY = 50      # one tool frame / normal arrow every 50 path points
FRAME_LENGTH_M = 0.004
TRANSIT_COLOUR = (150, 150, 150)


def _world(T_world_base: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ T_world_base[:3, :3].T + T_world_base[:3, 3]


def _at(t_s: float | None) -> None:
    """Log what follows at ``t_s`` on ``sim_time`` (static for None)."""
    if t_s is not None:
        rr.set_time(TIMELINE, duration=float(t_s))


def log_path_lines(entity: str, lines: Sequence[np.ndarray], T_world_base: np.ndarray, color: Sequence[int],
                   radius: float = 0.0002, t_s: float | None = None) -> None:
    """Polylines (each (n, 3) [m], base frame), e.g. the planned contact lines, from ``t_s``
    on (static for None)."""
    strips = [_world(T_world_base, np.asarray(ln)) for ln in lines if len(ln) > 1]
    _at(t_s)
    rr.log(entity, rr.LineStrips3D(strips, colors=[color], radii=radius), static=t_s is None)


def log_tool_frames(entity: str, T_base_tool: np.ndarray, T_world_base: np.ndarray, every_n: int = FRAME_EVERY,
                    length: float = FRAME_LENGTH_M, t_s: float | None = None) -> None:
    """x/y/z arrows (red/green/blue) of every ``every_n``-th tool frame, from ``t_s`` on."""
    T = T_world_base @ np.asarray(T_base_tool)[::every_n]
    origins = np.repeat(T[:, :3, 3], 3, axis=0)
    vectors = np.concatenate([T[:, :3, 0:1], T[:, :3, 1:2], T[:, :3, 2:3]], axis=2).transpose(0, 2, 1).reshape(-1, 3)
    colors = np.tile(np.array([[230, 40, 40], [40, 200, 40], [40, 80, 230]], dtype=np.uint8), (len(T), 1))
    _at(t_s)
    rr.log(entity, rr.Arrows3D(origins=origins, vectors=vectors * length, colors=colors, radii=0.00015),
           static=t_s is None)


def log_normals(entity: str, points: np.ndarray, normals: np.ndarray, T_world_base: np.ndarray, color: Sequence[int],
                every_n: int = FRAME_EVERY, length: float = FRAME_LENGTH_M, t_s: float | None = None) -> None:
    """Normal arrows at every ``every_n``-th point (base frame in, world out), from ``t_s`` on."""
    p = _world(T_world_base, np.asarray(points)[::every_n])
    n = np.asarray(normals)[::every_n] @ T_world_base[:3, :3].T
    _at(t_s)
    rr.log(entity, rr.Arrows3D(origins=p, vectors=n * length, colors=[color], radii=0.0001), static=t_s is None)


def log_replay(cell: Cell, replay_log: ReplayLog, t_offset: float, entity: str, colour: Sequence[int]) -> None:
    """The arm replaying a trajectory on ``sim_time`` (from ``t_offset``) and the actual TCP.

    ``entity``/tcp: the TCP on the process lines, which the blueprint's cumulative views draw as
    a trail growing with the cursor; ``entity``/transit: the TCP between them, thin and grey;
    ``plots/<name>/deviation_um``: the path deviation.
    """
    idx = every(replay_log.t, POSE_PERIOD_S)
    t = replay_log.t[idx] + t_offset
    send_arm(cell, t, replay_log.q[idx])
    tcp_w = _world(cell.T_world_base, replay_log.tcp_actual[idx])
    on_line = np.asarray(replay_log.process, dtype=bool)[idx]
    for sub, mask, radius, rgb in (("tcp", on_line, 0.0004, colour), ("transit", ~on_line, 0.0001, TRANSIT_COLOUR)):
        if mask.any():
            rr.send_columns(f"{entity}/{sub}", indexes=[rr.TimeColumn(TIMELINE, duration=t[mask])],
                            columns=rr.Points3D.columns(positions=tcp_w[mask]))
            rr.log(f"{entity}/{sub}", rr.Points3D.from_fields(radii=radius, colors=[rgb]), static=True)
    name = entity.rsplit("/", 1)[-1]
    send_series(f"plots/{name}/deviation_um", replay_log.t + t_offset, replay_log.deviation_m * 1e6)
