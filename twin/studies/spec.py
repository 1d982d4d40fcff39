"""Study files (TOML): read, validate every key, expand the grid into cells.

A study names one base scenario, optional overrides of it, the localization settings, a grid
of factors and how many trials each grid cell gets (``studies/README.md`` documents every key).
A grid key is a dotted key path into the scenario (``"sensor.sigma_m"``) or into the
localization (``"localize.method"``, ``"localize.init_angle_deg"``, ``"localize.init_distance_m"``).
Every grid value is checked before any trial runs: a scenario factor by loading the scenario
with the override, a localization factor against its allowed range.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from algorithms.registration.local import METHODS
from twin.errors import TwinError
from twin.formats.toml_files import read_toml
from twin.scenario import Scenario, load_scenario, merge_tables

KINDS = ("fast", "full")
TOP_KEYS = ("name", "seed", "scenario", "trials", "kind", "overrides", "localize", "grid")
#: Localization settings: name -> (default, check, what is allowed).
LOCALIZE_KEYS: dict[str, tuple[Any, Any, str]] = {
    "method": ("hong_tan", lambda v: v in METHODS, f"one of {', '.join(METHODS)}"),
    "init_angle_deg": (1.0, lambda v: _is_number(v) and 0.0 <= v <= 180.0, "a number in [0, 180]"),
    "init_distance_m": (0.001, lambda v: _is_number(v) and 0.0 <= v <= 0.1, "a number in [0, 0.1]"),
    "points": (0, lambda v: isinstance(v, int) and not isinstance(v, bool) and (v == 0 or 6 <= v <= 10_000_000),
               "0 (every scanned point) or an integer in [6, 10^7]"),
}
MAX_TRIALS = 1_000_000


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _nested(dotted: str, value: Any) -> dict:
    """``"a.b.c", v`` -> ``{"a": {"b": {"c": v}}}``."""
    out: Any = value
    for part in reversed(dotted.split(".")):
        out = {part: out}
    return out


@dataclass(frozen=True)
class Study:
    """A validated study.

    Attributes:
        name: the study's name.
        seed: the root of every trial's random stream (``SeedSequence(seed, spawn_key=(cell, trial))``).
        scenario_path: the base scenario file (absolute).
        trials: trials per grid cell.
        kind: ``"fast"`` (sensor errors redrawn on a cached noise-free scan) or ``"full"`` (the loop).
        overrides: nested tables merged over the scenario file for every cell.
        localize: the localization settings every cell starts from (``LOCALIZE_KEYS``).
        factors: the grid's keys in file order; ``levels``: their value lists.
        raw: the file's content (for the content hash).
    """

    name: str
    seed: int
    scenario_path: Path
    trials: int
    kind: str
    overrides: dict
    localize: dict
    factors: tuple[str, ...]
    levels: tuple[tuple, ...]
    raw: dict = field(repr=False)
    scenario_text: str = field(repr=False, default="")

    @property
    def cells(self) -> list[dict]:
        """Every grid cell as ``{factor: value}``, in row-major order (the last factor fastest)."""
        return [dict(zip(self.factors, combo, strict=True)) for combo in itertools.product(*self.levels)]

    @property
    def n_cells(self) -> int:
        n = 1
        for lv in self.levels:
            n *= len(lv)
        return n

    @property
    def n_trials(self) -> int:
        return self.n_cells * self.trials

    def cell_settings(self, cell: int) -> tuple[dict, dict]:
        """(scenario overrides, localization settings) of grid cell ``cell``."""
        values = self.cells[cell]
        over = copy.deepcopy(self.overrides)
        loc = dict(self.localize)
        for key, v in values.items():
            if key.startswith("localize."):
                loc[key.split(".", 1)[1]] = v
            else:
                over = merge_tables(over, _nested(key, v))
        return over, loc

    def cell_scenario(self, cell: int) -> Scenario:
        return load_scenario(self.scenario_path, self.cell_settings(cell)[0], machine="arm")

    @property
    def content_hash(self) -> str:
        """SHA-256 of the study's canonical content and its base scenario's text (not of the file's
        layout or comments): two files meaning the same study have the same hash."""
        body = {k: v for k, v in self.raw.items() if k != "scenario"}
        canon = json.dumps({"study": body, "scenario": self.scenario_text}, sort_keys=True, default=str)
        return hashlib.sha256(canon.encode()).hexdigest()

    def settings(self) -> dict:
        """The study as a JSON-ready dict (the manifest)."""
        return {"name": self.name, "seed": self.seed, "scenario": str(self.scenario_path), "trials": self.trials,
                "kind": self.kind, "overrides": self.overrides, "localize": self.localize,
                "grid": {k: list(v) for k, v in zip(self.factors, self.levels, strict=True)},
                "cells": self.n_cells}


def load_study(path: str | Path) -> Study:
    """Read and validate a study file; raise TwinError with one line on any problem."""
    path = Path(path)
    raw = read_toml(path, "study")
    return parse_study(raw, path.parent)


def parse_study(raw: dict, base_dir: Path) -> Study:
    unknown = sorted(set(raw) - set(TOP_KEYS))
    if unknown:
        raise TwinError(f"unknown study key(s) {', '.join(unknown)}; allowed: {', '.join(TOP_KEYS)}")
    name = raw.get("name", "study")
    if not isinstance(name, str) or not name:
        raise TwinError(f"study name must be a non-empty string, got {name!r}")
    seed = raw.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed < 2**63:
        raise TwinError(f"study seed must be an integer in [0, 2^63), got {seed!r}")
    if "scenario" not in raw or not isinstance(raw["scenario"], str):
        raise TwinError("study scenario is required: the base scenario file, relative to the study file")
    scenario_path = (base_dir / raw["scenario"]).resolve()
    trials = raw.get("trials", 10)
    if not isinstance(trials, int) or isinstance(trials, bool) or not 1 <= trials <= MAX_TRIALS:
        raise TwinError(f"study trials must be an integer in [1, {MAX_TRIALS}], got {trials!r}")
    kind = raw.get("kind", "fast")
    if kind not in KINDS:
        raise TwinError(f"study kind = {kind!r} is not one of {', '.join(KINDS)}")
    overrides = raw.get("overrides", {})
    if not isinstance(overrides, dict):
        raise TwinError(f"study overrides must be a table of scenario tables, got {overrides!r}")
    localize = raw.get("localize", {})
    if not isinstance(localize, dict):
        raise TwinError(f"study [localize] must be a table, got {localize!r}")
    bad = sorted(set(localize) - set(LOCALIZE_KEYS))
    if bad:
        raise TwinError(f"unknown key(s) {', '.join('localize.' + k for k in bad)}; "
                        f"allowed in [localize]: {', '.join(LOCALIZE_KEYS)}")
    loc = {k: localize.get(k, default) for k, (default, _, _) in LOCALIZE_KEYS.items()}
    for k, v in loc.items():
        _check_localize(k, v, f"localize.{k}")
    grid = raw.get("grid", {})
    if not isinstance(grid, dict):
        raise TwinError(f"study [grid] must be a table of key paths to value lists, got {grid!r}")
    factors, levels = [], []
    for key, values in grid.items():
        if not isinstance(values, list):
            raise TwinError(f"grid {key!r} must be a list of values, got {values!r}")
        if not values:
            raise TwinError(f"grid {key!r} is an empty list; give at least one value (or leave the key out)")
        factors.append(key)
        levels.append(tuple(values))
    try:
        scenario_text = scenario_path.read_text()
    except (OSError, UnicodeDecodeError):
        raise TwinError(f"study scenario not found or unreadable: {scenario_path}") from None
    load_scenario(scenario_path, overrides, machine="arm")  # the base overrides alone
    for key, values in zip(factors, levels, strict=True):
        _check_factor(key, values, kind, scenario_path, overrides)
    return Study(name, seed, scenario_path, trials, kind, copy.deepcopy(overrides), loc, tuple(factors),
                 tuple(levels), copy.deepcopy(raw), scenario_text)


def _check_localize(key: str, value: Any, where: str) -> None:
    _, ok, allowed = LOCALIZE_KEYS[key]
    if not ok(value):
        raise TwinError(f"{where} {value!r} is refused: must be {allowed}")


def _check_factor(key: str, values: tuple, kind: str, scenario_path: Path, overrides: dict) -> None:
    parts = key.split(".")
    if not all(parts):
        raise TwinError(f"grid key {key!r} is not a dotted key path (e.g. 'sensor.sigma_m', 'localize.method')")
    if parts[0] == "localize":
        if len(parts) != 2 or parts[1] not in LOCALIZE_KEYS:
            raise TwinError(f"unknown grid key {key!r}; localization keys allowed: "
                            f"{', '.join('localize.' + k for k in LOCALIZE_KEYS)}")
        if kind == "full":
            raise TwinError(f"grid key {key!r} needs kind = 'fast' (a full trial localizes as twin run does)")
        for v in values:
            _check_localize(parts[1], v, f"grid {key!r} value")
        return
    if parts[0] == "seed":
        raise TwinError("grid key 'seed' is not a factor: every trial draws its own random stream")
    for v in values:
        try:
            load_scenario(scenario_path, merge_tables(overrides, _nested(key, v)), machine="arm")
        except TwinError as exc:
            raise TwinError(f"grid {key!r} value {v!r} is refused: {' '.join(str(exc).split())}") from None
