"""Teach files: what an operator did at the CMM, in order, as TOML.

::

    name = "inner_sphere"          # the program's name
    stylus = "S1"                   # the stylus selected when teaching began
    safe_distance_m = 0.030         # document 002's safe distance above the safety plane
    # optional: [settings] approach_m, retract_m, search_m (defaults 2, 2, 5 mm)
    # optional: [plane] point_m = [x, y, z], normal = [i, j, k] (default: through the
    #           part's highest point, parallel to the table)

    [[step]]                        # each step is exactly one of:
    move = [0.0, 0.0, 0.12]         #   a move of the ball centre [m], part frame
    [[step]]
    touch = "SPH1_1"                #   a touch: the point's label,
    feature = "SPH1"                #   the feature it belongs to,
    point = [0.0283, 0.0, 0.0217]   #   the nominal point on the part [m],
    normal = [-0.707, 0.0, 0.707]   #   and its outward normal (the probe moves along -normal)
    [[step]]
    stylus = "S2"                   #   the head indexed to another stylus

The first step is a move (where the probe was when teaching began). Coordinates are the
part's, in metres. Whether a touch lies on the part and the moves clear it is checked
against the part's CAD model where the teach is planned (:mod:`twin.workflows.cmm`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from algorithms.errors import AlgorithmError
from algorithms.probing.program import ProbeSettings
from algorithms.probing.safety_plane import SafetyPlane, Teach, TeachMove, TeachStep, TeachStylus, TeachTouch
from twin.errors import TwinError
from twin.formats.toml_files import read_toml

TOP_KEYS = ("name", "stylus", "safe_distance_m", "settings", "plane", "step")
SETTINGS_KEYS = ("approach_m", "retract_m", "search_m")
STEP_KINDS = ("move", "touch", "stylus")


def _vec3(v, where: str) -> tuple[float, float, float]:
    if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                       for x in v)):
        raise TwinError(f"{where} must be three numbers [x, y, z], got {v!r}")
    a = np.asarray(v, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise TwinError(f"{where} must be finite, got {v!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


def _unknown(table: dict, allowed: tuple[str, ...], where: str) -> None:
    bad = sorted(set(table) - set(allowed))
    if bad:
        raise TwinError(f"{where}: unknown key(s) {', '.join(bad)}; allowed: {', '.join(allowed)}")


def _step(raw, i: int) -> TeachStep:
    where = f"step {i + 1}"
    if not isinstance(raw, dict):
        raise TwinError(f"{where} must be a table ([[step]])")
    kinds = [k for k in STEP_KINDS if k in raw]
    if len(kinds) != 1:
        raise TwinError(f"{where} must have exactly one of {', '.join(STEP_KINDS)}, got {sorted(raw)}")
    kind = kinds[0]
    if kind == "move":
        _unknown(raw, ("move",), where)
        return TeachMove(_vec3(raw["move"], f"{where}.move"))
    if kind == "stylus":
        _unknown(raw, ("stylus",), where)
        if not isinstance(raw["stylus"], str):
            raise TwinError(f"{where}.stylus must be a stylus name, got {raw['stylus']!r}")
        return TeachStylus(raw["stylus"])
    _unknown(raw, ("touch", "feature", "point", "normal"), where)
    for key in ("feature", "point", "normal"):
        if key not in raw:
            raise TwinError(f"{where}: a touch needs 'feature', 'point' and 'normal'; '{key}' is missing")
    if not isinstance(raw["touch"], str) or not isinstance(raw["feature"], str):
        raise TwinError(f"{where}: touch and feature must be labels (strings)")
    normal = _vec3(raw["normal"], f"{where}.normal")
    if np.linalg.norm(normal) == 0:
        raise TwinError(f"{where}.normal must not be zero")
    return TeachTouch(raw["touch"], raw["feature"], _vec3(raw["point"], f"{where}.point"), normal)


def parse_teach(raw: dict, source: str = "teach") -> Teach:
    """A :class:`~algorithms.probing.safety_plane.Teach` from a teach file's table."""
    try:
        _unknown(raw, TOP_KEYS, source)
        for key in ("stylus", "safe_distance_m", "step"):
            if key not in raw:
                raise TwinError(f"{source}: '{key}' is required")
        name = raw.get("name", Path(source).stem)
        if not isinstance(name, str) or not name:
            raise TwinError(f"{source}: name must be a non-empty string")
        safe = raw["safe_distance_m"]
        if not isinstance(safe, (int, float)) or isinstance(safe, bool) or not np.isfinite(safe) or safe <= 0:
            raise TwinError(f"{source}: safe_distance_m must be a positive distance [m], got {safe!r}")
        settings_raw = raw.get("settings", {})
        if not isinstance(settings_raw, dict):
            raise TwinError(f"{source}: [settings] must be a table")
        _unknown(settings_raw, SETTINGS_KEYS, f"{source} [settings]")
        settings = ProbeSettings(**settings_raw, clearance_m=float(safe))
        plane = None
        if "plane" in raw:
            p = raw["plane"]
            if not isinstance(p, dict):
                raise TwinError(f"{source}: [plane] must be a table with point_m and normal")
            _unknown(p, ("point_m", "normal"), f"{source} [plane]")
            if "point_m" not in p or "normal" not in p:
                raise TwinError(f"{source} [plane] needs point_m and normal")
            plane = SafetyPlane(np.array(_vec3(p["point_m"], "plane.point_m")),
                                np.array(_vec3(p["normal"], "plane.normal")))
        steps = raw["step"]
        if not isinstance(steps, list) or not steps:
            raise TwinError(f"{source}: 'step' must be a list of [[step]] tables")
        return Teach(name, raw["stylus"], tuple(_step(s, i) for i, s in enumerate(steps)), float(safe), settings,
                     plane)
    except AlgorithmError as exc:
        raise TwinError(f"{source}: {exc}") from None
    except TypeError as exc:
        raise TwinError(f"{source}: {exc}") from None


def load_teach(path: str | Path) -> Teach:
    """Read and validate a teach file (one-line TwinError on any problem)."""
    path = Path(path)
    raw = read_toml(path, "teach file")
    return parse_teach(raw, str(path))
