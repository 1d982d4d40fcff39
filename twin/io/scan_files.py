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
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from twin.errors import TwinError
from twin.formats import read_ply

if TYPE_CHECKING:   # the module itself stays light: reading points loads neither the cell nor scipy
    from twin.scan_uncertainty import ScanReadings
    from twin.scenario import NoiseSpec, SensorSpec

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


def read_scan_readings(folder: str | Path) -> ScanReadings:
    """A folder written by ``twin scan`` read back: the valid samples on its scan lines, their
    points rebuilt from the logged joints and distances (document 004's eq. 2, as the scan
    did). Raises TwinError with one line when the folder is not a complete scan."""
    out = Path(folder)
    if not out.is_dir():
        raise TwinError(f"--scan must be a folder written by 'twin scan', got {folder}")
    meta, table = _read_scan_files(out)
    sensor, noise = _sensor_and_noise(meta, out)
    try:
        q = np.column_stack([table.column(f"q{j + 1}").to_numpy() for j in range(6)]).astype(np.float64)
        line = table.column("line").to_numpy().astype(np.int64)
        d = _beam_matrix(table.column("d"), len(q)).astype(np.float64)
        valid = _beam_matrix(table.column("valid"), len(q)).astype(bool)
        beam_dirs = np.asarray(meta["sensor"]["beam_dirs_sensor"], dtype=np.float64).reshape(-1, 3)
        T_nominal = np.asarray(meta["T_base_workpiece_nominal"], dtype=np.float64).reshape(4, 4)
    except (KeyError, TypeError, ValueError, pa.ArrowException) as exc:
        raise TwinError(f"{out / SAMPLES_FILE} or {out / META_FILE} is not a scan's (columns t, q1..q6, d, valid, "
                        f"line; sensor.beam_dirs_sensor): {exc}") from None
    if d.shape[1] != len(beam_dirs) or not np.all(np.isfinite(q)) or not np.all(np.isfinite(T_nominal)):
        raise TwinError(f"{out}: the samples, the beams and the poses of the scan do not agree "
                        f"({d.shape[1]} beams per sample, {len(beam_dirs)} beam directions, or a non-finite joint)")
    return scan_readings(q, d, valid, line, beam_dirs, sensor, noise, T_nominal)


def scan_readings(q: np.ndarray, d: np.ndarray, valid: np.ndarray, line: np.ndarray, beam_dirs_sensor: np.ndarray,
                  sensor: SensorSpec, noise: NoiseSpec, T_base_workpiece_nominal: np.ndarray) -> ScanReadings:
    """The readings of the valid samples on the scan lines: logged joints ``q`` (N, 6) [rad],
    distances ``d`` and ``valid`` (N, B), ``line`` (N,) (-1 between lines); the points rebuilt
    with the believed kinematics and the sensor's (believed) hand-eye."""
    from algorithms.geometry.kinematics import reconstruct_line_points
    from twin.robot import UR5E_DH
    from twin.scan_uncertainty import ScanReadings, beam_directions_base

    mask = valid & np.isfinite(d) & (line >= 0)[:, None]
    points = reconstruct_line_points(q, np.where(mask, d, np.nan), beam_dirs_sensor, UR5E_DH, sensor.T_flange_sensor)
    beams = beam_directions_base(q, beam_dirs_sensor, sensor.T_flange_sensor)
    q_points = np.broadcast_to(q[:, None, :], (*mask.shape, 6))[mask]
    return ScanReadings(points[mask], d[mask], beams[mask], np.ascontiguousarray(q_points), sensor, noise,
                        np.asarray(T_base_workpiece_nominal, dtype=np.float64))


def _read_scan_files(out: Path) -> tuple[dict, pa.Table]:
    for name in (SAMPLES_FILE, META_FILE):
        if not (out / name).is_file():
            raise TwinError(f"{out} is not a scan folder: {name} is missing (write one with 'twin scan')")
    try:
        meta = json.loads((out / META_FILE).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise TwinError(f"{out / META_FILE} cannot be read as JSON: {exc}") from None
    if not isinstance(meta, dict):
        raise TwinError(f"{out / META_FILE} must hold a JSON object")
    try:
        table = pq.read_table(out / SAMPLES_FILE)
    except (OSError, pa.ArrowException) as exc:
        raise TwinError(f"{out / SAMPLES_FILE} cannot be read as Parquet: {exc}") from None
    return meta, table


def _beam_matrix(column: pa.ChunkedArray, n: int) -> np.ndarray:
    """(n, B) values of a plain (B = 1) or fixed-size-list column."""
    arr = column.combine_chunks()
    if pa.types.is_fixed_size_list(arr.type):
        return arr.flatten().to_numpy(zero_copy_only=False).reshape(n, arr.type.list_size)
    return arr.to_numpy(zero_copy_only=False).reshape(n, 1)


def _sensor_and_noise(meta: dict, out: Path) -> tuple[SensorSpec, NoiseSpec]:
    """The scan's sensor settings and error switches, from its scenario's copy in scan.json."""
    from twin.scenario import NoiseSpec, SensorSpec

    try:
        sc = meta["scenario"]
        s, n = dict(sc["sensor"]), dict(sc["noise"])
        s["window_m"] = tuple(float(v) for v in s["window_m"])
        s["T_flange_sensor"] = np.asarray(s["T_flange_sensor"], dtype=np.float64).reshape(4, 4)
        s.setdefault("linearity_phase_deg", 0.0)
        n["T_hand_eye_error"] = np.asarray(n["T_hand_eye_error"], dtype=np.float64).reshape(4, 4)
        sensor, noise = SensorSpec(**s), NoiseSpec(**n)
    except (KeyError, TypeError, ValueError) as exc:
        raise TwinError(f"{out / META_FILE} does not describe the scan's sensor and noise (scenario.sensor, "
                        f"scenario.noise): {exc}") from None
    numbers = [sensor.sigma_m, sensor.linearity_m, sensor.resolution_m, noise.encoder_sigma_rad]
    if not all(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0 for v in numbers):
        raise TwinError(f"{out / META_FILE}: the sensor's sigma_m, linearity_m, resolution_m and the encoders' "
                        f"sigma must be finite, non-negative numbers")
    return sensor, noise
