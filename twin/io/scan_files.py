"""Scan files: samples (Parquet), points (PLY), metadata (JSON).

``samples.parquet`` columns (one row per 1 ms sample):

| column | type | unit | meaning |
|---|---|---|---|
| ``t`` | float64 | s | sample time, exactly ``sample_period_s`` apart |
| ``q1`` .. ``q6`` | float64 | rad | joint encoder readings paired with ``d`` |
| ``d`` | float64 (point) or list<float64>[B] (line) | m | distance along the beam, NaN if invalid |
| ``valid`` | bool (or list<bool>[B]) | - | the sensor reported a distance |
| ``status`` | uint8 (or list<uint8>[B]) | - | 0 valid, 1 no hit, 2 out of window, 3 incidence, 4 occluded |
| ``line`` | int32 | - | scan-line index, -1 on approach/retract/line-change moves |

``points.ply``: the valid reconstructed points, robot base frame, metres (float64 x, y, z).
``scan.json``: the scenario, sensor settings, sample period, counts and file list.

The commands stage these files in a temporary folder and move it into place at the end
(:mod:`twin.io.output`), so an interrupted run never leaves a folder that looks complete.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from twin.errors import TwinError
from twin.formats import read_ply

SAMPLES_FILE, POINTS_FILE, META_FILE = "samples.parquet", "points.ply", "scan.json"


def samples_table(scan) -> pa.Table:
    cols = {"t": pa.array(scan.t, pa.float64())}
    for j in range(6):
        cols[f"q{j + 1}"] = pa.array(scan.q[:, j], pa.float64())
    if scan.beams == 1:  # the file format: one beam is a plain column
        cols["d"] = pa.array(scan.d[:, 0], pa.float64(), from_pandas=False)
        cols["valid"] = pa.array(scan.valid[:, 0], pa.bool_())
        cols["status"] = pa.array(scan.status[:, 0], pa.uint8())
    else:
        b = scan.d.shape[1]
        cols["d"] = pa.FixedSizeListArray.from_arrays(pa.array(scan.d.ravel(), pa.float64()), b)
        cols["valid"] = pa.FixedSizeListArray.from_arrays(pa.array(scan.valid.ravel(), pa.bool_()), b)
        cols["status"] = pa.FixedSizeListArray.from_arrays(pa.array(scan.status.ravel(), pa.uint8()), b)
    cols["line"] = pa.array(scan.line, pa.int32())
    meta = {b"units": b"t [s], q1..q6 [rad], d [m] (NaN if invalid)", b"frame": b"d along the sensor +z"}
    return pa.table(cols).replace_schema_metadata(meta)


def scan_metadata(scan) -> dict:
    sc = scan.scenario
    return {
        "scenario": sc.to_dict(),
        "scenario_file": sc.source,
        "sensor": {
            "kind": sc.sensor.kind,
            "window_m": list(sc.sensor.window_m),
            "reference_m": sc.sensor.reference_m,
            "sigma_m": sc.sensor.sigma_m,
            "linearity_m": sc.sensor.linearity_m,
            "resolution_m": sc.sensor.resolution_m,
            "max_incidence_deg": sc.sensor.max_incidence_deg,
            "baseline_m": sc.sensor.baseline_m,
            "beams": sc.sensor.beams,
            "beam_dirs_sensor": scan.beam_dirs_sensor.tolist(),
            "T_flange_sensor_nominal": scan.T_flange_sensor_nominal.tolist(),
        },
        "noise": sc.to_dict()["noise"],
        "sample_period_s": sc.sensor.sample_period_s,
        "n_samples": int(len(scan.t)),
        "n_valid": int(np.count_nonzero(scan.valid)),
        "duration_s": float(scan.t[-1]),
        "points_frame": "robot base",
        "T_world_base": sc.T_world_base.tolist(),
        "T_base_workpiece_nominal": scan.T_base_workpiece_nominal.tolist(),
        "timings_s": scan.timings_s,
        "files": {"samples": SAMPLES_FILE, "points": POINTS_FILE},
        "columns": {"t": "s", "q1..q6": "rad", "d": "m, NaN if invalid", "valid": "bool",
                    "status": "0 valid, 1 no hit, 2 out of window, 3 incidence, 4 occluded",
                    "line": "scan-line index, -1 between lines"},
    }


def write_scan(scan, folder: str | Path, extra: dict | None = None) -> Path:
    """Write the scan's three files into ``folder`` (created if missing).

    The commands write into a staged folder (:class:`twin.io.output.Staged`) that is moved
    into place when everything is written; this function itself is not atomic.
    """
    out = Path(folder)
    if out.exists() and not out.is_dir():
        raise TwinError(f"{out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    pq.write_table(samples_table(scan), out / SAMPLES_FILE)
    write_points_ply(out / POINTS_FILE, scan.valid_points_base)
    meta = scan_metadata(scan)
    if extra:
        meta.update(extra)
    (out / META_FILE).write_text(json.dumps(meta, indent=2))
    return out


def write_points_ply(path: str | Path, points: np.ndarray) -> None:
    """Binary little-endian PLY with float64 x, y, z (metres keep sub-nanometre precision)."""
    pts = np.ascontiguousarray(points, dtype="<f8")
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment scan-twin points, robot base frame, metres\n"
        f"element vertex {len(pts)}\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
    )
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(pts.tobytes())


def read_points_ply(path: str | Path) -> np.ndarray:
    """(N, 3) float64 points from a PLY file (vertices of a point cloud or a mesh), checked
    strictly (:func:`twin.formats.read_ply`)."""
    path = Path(path)
    if not path.is_file():
        raise TwinError(f"points file not found: {path}")
    return read_ply(path).vertices
