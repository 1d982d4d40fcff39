"""Time-indexed data logged in columns (``rr.send_columns``), thinned for the viewer: poses as
quaternions at :data:`POSE_PERIOD_S`, 1 kHz series reduced to one value per
:data:`SERIES_PERIOD_S` (the one of largest magnitude, so a peak is never thinned away). The
full 1 ms data stays in the run's Parquet files."""

from __future__ import annotations

import numpy as np
import rerun as rr
from scipy.spatial.transform import Rotation

TIMELINE = "sim_time"
#: Poses of moving bodies are logged every 50 ms (20 frames a second of simulated time).
POSE_PERIOD_S = 0.05
#: Time series are logged at one value per 20 ms.
SERIES_PERIOD_S = 0.02


def every(t_s: np.ndarray, period_s: float) -> np.ndarray:
    """Indices of samples about ``period_s`` apart (the first and the last always included)."""
    t = np.asarray(t_s, dtype=np.float64)
    if len(t) < 2:
        return np.arange(len(t))
    dt = float(np.median(np.diff(t)))
    step = max(int(round(period_s / dt)), 1) if dt > 0 else 1
    idx = np.arange(0, len(t), step)
    return idx if idx[-1] == len(t) - 1 else np.r_[idx, len(t) - 1]


def send_poses(entity: str, t_s: np.ndarray, T: np.ndarray) -> None:
    """Rigid poses (K, 4, 4) at times ``t_s`` [s] on ``sim_time``, as translation + quaternion."""
    T = np.asarray(T, dtype=np.float64)
    quat = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # x, y, z, w: rerun's order
    rr.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=np.asarray(t_s, dtype=np.float64))],
                    columns=rr.Transform3D.columns(translation=T[:, :3, 3], quaternion=quat))


def peaks(t_s: np.ndarray, y: np.ndarray, period_s: float = SERIES_PERIOD_S) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) with one sample per ``period_s``: in each bin the sample of largest magnitude (NaN
    where the whole bin is NaN)."""
    t = np.asarray(t_s, dtype=np.float64)
    v = np.asarray(y, dtype=np.float64)
    start = every(t, period_s)[:-1] if len(t) > 1 else np.arange(len(t))
    if len(start) == 0 or len(start) == len(t):
        return t, v
    mag = np.where(np.isfinite(v), np.abs(v), -1.0)
    bins = np.searchsorted(start, np.arange(len(t)), side="right") - 1
    order = np.lexsort((-mag, bins))  # per bin, the largest magnitude first
    first = order[np.r_[True, bins[order][1:] != bins[order][:-1]]]
    return t[start], v[first]


def send_series(entity: str, t_s: np.ndarray, y: np.ndarray, period_s: float = SERIES_PERIOD_S) -> None:
    """A scalar series on ``sim_time``, thinned by :func:`peaks`."""
    t, v = peaks(t_s, y, period_s)
    rr.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=t)], columns=rr.Scalars.columns(scalars=v))


def quiet_timelines(rec: rr.RecordingStream) -> None:
    """No wall-clock ``log_time`` or ``log_tick`` timelines: every entity is on ``sim_time``
    (or static), so the time panel offers only the timelines that mean something."""
    rec.set_log_time_enabled(False)
    rec.set_log_tick_enabled(False)
