"""``kind = "normals"``: document 004's normals on scan-line clouds, against the truth.

Each trial redraws the scan as a fast trial does (:func:`twin.studies.trials.scan_points`, the
cell's noise-free scan simulated once per worker), organises the point sensor's samples by scan
line, prepares the cloud named by ``normals.cloud`` and estimates the normals by
``normals.method``:

* clouds: ``raw`` (the organised samples after the outlier filter), ``simplified`` (document
  004's steps 1-4: also boundary and 0.2 mm simplification), ``bspline`` (per-line cubic
  least-squares B-splines resampled every 1 mm: the process path's contact points);
* methods: ``triangulation`` (document 004's cross-line triangulation, oriented; its triangles
  ``normals.triangles``: our fan, or the document's list as printed) or ``pca``
  (k-nearest-neighbour PCA with ``normals.k`` neighbours, unsigned: the better of n and -n).

The truth is the model's smooth normal at the point's closest point on the part at its true
pose. Columns: ``angle_rms_deg``, ``angle_p95_deg``, ``angle_max_deg`` [deg] and
``over_5deg_share`` (the share of points off by more than 5 deg), ``n_points``, ``status``
(``ok``, or ``error`` where the cloud or the method refused the lines) and ``time_s`` (the
normals' wall time).
"""

from __future__ import annotations

import time

import numpy as np

from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.paths.normals import angle_deg, pca_normals, triangulation_normals
from algorithms.paths.pointcloud import organize_scan_lines, prepare_scan_lines, remove_outliers
from algorithms.paths.spline import fit_lines
from twin import evaluate
from twin.scenario import load_scenario
from twin.studies.spec import Study
from twin.studies.trials import noise_free_scan, scan_points, trial_streams

NORMALS_COLUMNS = ("angle_rms_deg", "angle_p95_deg", "angle_max_deg", "over_5deg_share", "n_points", "status",
                   "time_s")
#: Resampling step of the ``bspline`` cloud [m] (the process path's spacing).
BSPLINE_SPACING_M = 0.001


def _lines(cloud: str, points: np.ndarray, line: np.ndarray) -> list[np.ndarray]:
    if cloud == "raw":
        return list(remove_outliers(organize_scan_lines(points, line)).lines)
    simplified = prepare_scan_lines(points, line)
    if cloud == "simplified":
        return list(simplified.lines)
    return list(fit_lines(simplified.lines, BSPLINE_SPACING_M).lines)


def _failed(n_points: int = 0) -> dict:
    nan = float("nan")
    return {"angle_rms_deg": nan, "angle_p95_deg": nan, "angle_max_deg": nan, "over_5deg_share": nan,
            "n_points": int(n_points), "status": "error", "time_s": 0.0}


def normals_trial(study: Study, cell: int, trial: int) -> dict:
    settings = study.cell_settings(cell)
    spec = settings.normals
    scenario = load_scenario(settings.scenario_path, settings.overrides, machine="arm")
    geo = noise_free_scan(scenario)
    _, rng_err, _, _ = trial_streams(study.seed, cell, trial)
    points, valid, _ = scan_points(scenario, geo, rng_err)
    p = np.where(valid[:, :1], points[:, 0], np.nan)  # the point sensor's one beam
    try:
        lines = _lines(spec["cloud"], p, geo.plan.line)
        pts = np.concatenate(lines)
        T = evaluate.Evaluation(geo.realized).T_base_workpiece
        t0 = time.perf_counter()
        if spec["method"] == "triangulation":
            n = np.concatenate(triangulation_normals(lines, orient=T[:3, 2], triangles=spec["triangles"]))
        else:
            n = pca_normals(pts, spec["k"], orient=T[:3, 2])
        elapsed = time.perf_counter() - t0
    except AlgorithmError:
        return _failed()
    index = geo.realized.workpiece.index
    cp = index.query(transform_points(inv_pose(T), pts))
    n_true = index.smooth_normals(cp.face, cp.foot) @ T[:3, :3].T
    a = angle_deg(n, n_true, unsigned=spec["method"] == "pca")
    return {"angle_rms_deg": float(np.sqrt(np.mean(a**2))), "angle_p95_deg": float(np.percentile(a, 95)),
            "angle_max_deg": float(a.max()), "over_5deg_share": float(np.mean(a > 5.0)), "n_points": len(pts),
            "status": "ok", "time_s": elapsed}
