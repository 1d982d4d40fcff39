"""The 6-DOF pose table of a localization: nominal, estimate and truth, the error and its
standard uncertainty per component, free directions named. One place builds it (into
``report.json``); the report page and the recording's text panel render it.

Columns, per component (rotations ``rx ry rz``, translations ``x y z``):

* ``nominal``, ``estimate``, ``truth``: the pose of the workpiece in the robot base frame, as
  the position of its origin [mm] and fixed-axis x-y-z angles [deg];
* ``error``: the estimate's error twist ``xi`` against the truth (``T_est = T_true exp(xi)``,
  workpiece frame) [urad, um];
* ``std``: its standard uncertainty (1 sigma) from the localization's covariance, in the same
  frame and units; ``null`` along a free direction (the points do not determine it).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.registration.uncertainty import pose_error_twist

COMPONENTS = ("rx", "ry", "rz", "x", "y", "z")
AXIS_NAMES = ("rotation about x", "rotation about y", "rotation about z", "translation along x",
              "translation along y", "translation along z")
#: A free direction whose unit twist has a component above this share names that component free.
FREE_SHARE = 0.1


def _absolute(T: np.ndarray) -> list[float]:
    """[rx, ry, rz] fixed-axis angles [deg] and [x, y, z] [mm] of a pose."""
    T = np.asarray(T, dtype=np.float64)
    ang = Rotation.from_matrix(T[:3, :3]).as_euler("xyz", degrees=True)
    return [float(v) for v in ang] + [float(v) * 1e3 for v in T[:3, 3]]


def name_direction(w: np.ndarray) -> str:
    """A free direction in words: the axis it is (nearly) along, or its unit twist."""
    w = np.asarray(w, dtype=np.float64)
    w = w / max(float(np.linalg.norm(w)), 1e-300)
    k = int(np.argmax(np.abs(w)))
    if abs(w[k]) >= 0.99:
        return AXIS_NAMES[k]
    return "combination [" + ", ".join(f"{v:+.2f}" for v in w) + "] (rx ry rz x y z)"


def twist_covariance(determined: np.ndarray, covariance: np.ndarray | None) -> np.ndarray | None:
    """(6, 6) covariance of the twist [omega, v] from the covariance over the determined
    directions (rows of ``determined``; singular along the free ones), or None without one."""
    D = np.asarray(determined, dtype=np.float64).reshape(-1, 6)
    if covariance is None or not len(D):
        return None
    return D.T @ np.asarray(covariance, dtype=np.float64).reshape(len(D), len(D)) @ D


def free_components(free: np.ndarray) -> np.ndarray:
    """(6,) bool: the twist components a free direction (rows of ``free``) moves by more than
    :data:`FREE_SHARE` (the points say nothing about them)."""
    F = np.asarray(free, dtype=np.float64).reshape(-1, 6)
    return np.array([bool(np.any(np.abs(F[:, k]) > FREE_SHARE)) for k in range(6)], dtype=bool)


def pose_table(T_nominal: np.ndarray, T_estimate: np.ndarray, T_true: np.ndarray, determined: np.ndarray,
               free: np.ndarray, covariance: np.ndarray | None) -> dict:
    """The table as JSON: ``rows`` (one per component) and ``free_directions`` (named)."""
    F = np.asarray(free, dtype=np.float64).reshape(-1, 6)
    free_comp = [bool(v) for v in free_components(F)]
    xi = pose_error_twist(T_estimate, T_true)
    C = twist_covariance(determined, covariance)
    std = None if C is None else np.sqrt(np.clip(np.diag(C), 0.0, None))
    nom, est, tru = _absolute(T_nominal), _absolute(T_estimate), _absolute(T_true)
    scale = [1e6] * 3 + [1e6] * 3   # rad -> urad, m -> um
    rows = []
    for k, comp in enumerate(COMPONENTS):
        rows.append({"component": comp, "nominal": nom[k], "estimate": est[k], "truth": tru[k],
                     "error": None if free_comp[k] else float(xi[k] * scale[k]),
                     "std": None if free_comp[k] or std is None else float(std[k] * scale[k])})
    return {"rows": rows, "free_directions": [name_direction(w) for w in F],
            "units": {"nominal/estimate/truth": "rx ry rz [deg] (fixed-axis x-y-z), x y z [mm], base frame",
                      "error/std": "rx ry rz [urad], x y z [um], workpiece frame"}}


def _cell(v: float | None, fmt: str) -> str:
    return "free" if v is None else format(v, fmt)


def table_rows(table: dict) -> list[list[str]]:
    """The table as text cells: header first."""
    out = [["", "nominal", "estimate", "truth", "error", "+-1 sigma"]]
    for r in table["rows"]:
        rot = r["component"].startswith("r")
        unit = ("deg", "urad") if rot else ("mm", "um")
        out.append([r["component"], f"{r['nominal']:.4f} {unit[0]}", f"{r['estimate']:.6f} {unit[0]}",
                    f"{r['truth']:.6f} {unit[0]}", _cell(r["error"], "+.2f") + f" {unit[1]}",
                    _cell(r["std"], ".2f") + f" {unit[1]}"])
    return out


def markdown(table: dict) -> str:
    """The table in Markdown, with the free directions named under it."""
    rows = table_rows(table)
    lines = ["| " + " | ".join(rows[0]) + " |", "|" + "---|" * len(rows[0])]
    lines += ["| " + " | ".join(r) + " |" for r in rows[1:]]
    lines.append("")
    lines.append("error and sigma: workpiece frame; nominal, estimate, truth: base frame (x-y-z angles)")
    if table["free_directions"]:
        lines.append("free (not determined by the points): " + "; ".join(table["free_directions"]))
    return "\n".join(lines)
