"""Process paths: planned and replayed tool paths, tool frames, normals."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from twin.cell import Cell
from twin.viz.cell import body_poses
from twin.viz.scan import POSE_EVERY

if TYPE_CHECKING:
    from twin.replay import ReplayLog

FRAME_EVERY = 50      # one tool frame / normal arrow every 50 path points
FRAME_LENGTH_M = 0.004


def _world(T_world_base: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ T_world_base[:3, :3].T + T_world_base[:3, 3]


def log_path_lines(entity: str, lines: Sequence[np.ndarray], T_world_base: np.ndarray, color: Sequence[int],
                   radius: float = 0.0002) -> None:
    """Static polylines (each (n, 3) [m], base frame), e.g. the planned contact lines."""
    strips = [_world(T_world_base, np.asarray(ln)) for ln in lines if len(ln) > 1]
    rr.log(entity, rr.LineStrips3D(strips, colors=[color], radii=radius), static=True)


def log_tool_frames(entity: str, T_base_tool: np.ndarray, T_world_base: np.ndarray, every: int = FRAME_EVERY,
                    length: float = FRAME_LENGTH_M) -> None:
    """Static x/y/z arrows (red/green/blue) of every ``every``-th tool frame."""
    T = T_world_base @ np.asarray(T_base_tool)[::every]
    origins = np.repeat(T[:, :3, 3], 3, axis=0)
    vectors = np.concatenate([T[:, :3, 0:1], T[:, :3, 1:2], T[:, :3, 2:3]], axis=2).transpose(0, 2, 1).reshape(-1, 3)
    colors = np.tile(np.array([[230, 40, 40], [40, 200, 40], [40, 80, 230]], dtype=np.uint8), (len(T), 1))
    rr.log(entity, rr.Arrows3D(origins=origins, vectors=vectors * length, colors=colors, radii=0.00015), static=True)


def log_normals(entity: str, points: np.ndarray, normals: np.ndarray, T_world_base: np.ndarray, color: Sequence[int],
                every: int = FRAME_EVERY, length: float = FRAME_LENGTH_M) -> None:
    """Static normal arrows at every ``every``-th point (base frame in, world out)."""
    p = _world(T_world_base, np.asarray(points)[::every])
    n = np.asarray(normals)[::every] @ T_world_base[:3, :3].T
    rr.log(entity, rr.Arrows3D(origins=p, vectors=n * length, colors=[color], radii=0.0001), static=True)


def log_replay(cell: Cell, replay_log: ReplayLog, t_offset: float, entity: str, colour: Sequence[int]) -> None:
    """The arm replaying a trajectory on ``sim_time`` (from ``t_offset``) and the actual TCP.

    ``entity``/tcp: the TCP every 10 ms, which the blueprint's cumulative views draw as a trail
    growing with the cursor; ``plots/<name>/deviation_um``: the path deviation.
    """
    idx = np.arange(0, len(replay_log.t), POSE_EVERY)
    t = replay_log.t[idx] + t_offset
    times = rr.TimeColumn("sim_time", duration=t)
    poses = body_poses(cell, replay_log.q[idx])
    for name, T in poses.items():
        rr.send_columns(f"world/robot/{name}", indexes=[times], columns=rr.Transform3D.columns(
            translation=T[:, :3, 3], mat3x3=T[:, :3, :3]))
    tcp_w = _world(cell.T_world_base, replay_log.tcp_actual)
    rr.send_columns(f"{entity}/tcp", indexes=[times], columns=rr.Points3D.columns(positions=tcp_w[idx]))
    rr.log(f"{entity}/tcp", rr.Points3D.from_fields(radii=0.0004, colors=[colour]), static=True)
    name = entity.rsplit("/", 1)[-1]
    dev = np.nan_to_num(replay_log.deviation_m * 1e6, nan=0.0)
    rr.send_columns(f"plots/{name}/deviation_um", indexes=[rr.TimeColumn("sim_time", duration=replay_log.t + t_offset)],
                    columns=rr.Scalars.columns(scalars=dev))
