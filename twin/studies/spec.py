"""Study files (TOML): read, validate every key, expand the grid into cells.

A study names a base scenario, optional overrides of it, the localization settings, for
``kind = "points"`` the sampled point sets, a grid of factors and how many trials each grid
cell gets, or an adaptive rule (``docs/concepts/study-files.md`` documents every key). A grid key is a
dotted key path into the scenario (``"sensor.sigma_m"``), into the localization
(``"localize.method"``), into the point sets (``"points.noise_sigma_m"``), ``"scenario"``
(a list of scenario files: several base scenarios in one study) or ``"overrides"`` (a list of
tables merged over the scenario: variants that change several keys at once). Every grid value is checked
before any trial runs: a scenario factor by loading the scenario with the override, the
others against their allowed ranges.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from algorithms.paths.normals import TRIANGLES
from algorithms.registration.global_search.search import GLOBAL_METHODS
from algorithms.registration.local import METHODS
from algorithms.registration.printed import VARIANTS
from twin.errors import TwinError
from twin.formats.toml_files import read_toml
from twin.scenario import Scenario, load_scenario, merge_tables
from twin.studies.inputs import Resolved, check_not_both, off_overrides, parse_inputs, resolve

KINDS = ("fast", "full", "points", "normals")
TOP_KEYS = ("name", "seed", "scenario", "trials", "kind", "overrides", "inputs", "localize", "points", "normals",
            "adaptive", "success", "grid")
#: The kinds whose trials have the scenario's error sources (``[inputs]``, :mod:`twin.studies.inputs`).
INPUT_KINDS = ("fast", "full")
#: The table of each kind's own settings (a grid key ``"points.count"`` needs that kind).
KIND_TABLES = {"points": "points", "normals": "normals"}
#: Stages of the global methods run alone: document 001's genetic coarse stage (one GA run, no
#: fine stage), document 003's swarm without the polish.
STAGE_METHODS = ("genetic_coarse", "genetic_001", "pso_alone")
#: Peers, rows where the package is installed (``pip install -e ".[peers]"``).
PEER_METHODS = ("open3d_icp", "small_gicp")
ALL_METHODS = tuple(METHODS) + tuple(GLOBAL_METHODS) + STAGE_METHODS + PEER_METHODS
SUBSAMPLE_RULES = ("none", "hammersley", "uniform", "random")
#: Localization settings: name -> (default, check, what is allowed).
LOCALIZE_KEYS: dict[str, tuple[Any, Any, str]] = {
    "method": ("hong_tan", lambda v: v in ALL_METHODS, f"one of {', '.join(ALL_METHODS)}"),
    "init_angle_deg": (1.0, lambda v: _is_number(v) and 0.0 <= v <= 180.0, "a number in [0, 180]"),
    "init_distance_m": (0.001, lambda v: _is_number(v) and 0.0 <= v <= 0.1, "a number in [0, 0.1]"),
    "init_position": ("truth", lambda v: v in ("truth", "mean"), "'truth' or 'mean'"),
    "points": (0, lambda v: _is_int(v) and (v == 0 or 6 <= v <= 10_000_000),
               "0 (every scanned point) or an integer in [6, 10^7]"),
    "subsample": ("none", lambda v: v in SUBSAMPLE_RULES, f"one of {', '.join(SUBSAMPLE_RULES)}"),
    "variant": ("ours", lambda v: v in VARIANTS, f"one of {', '.join(VARIANTS)}"),
    "foot_points": ("mesh", lambda v: v in ("mesh", "newton"),
                    "'mesh' (closest points on the CAD mesh) or 'newton' (document 000's Newton foot points on "
                    "the part's exact surfaces, with variant 'printed')"),
    "tolerance": (0.0, lambda v: _is_number(v) and 0.0 <= v <= 0.1,
                  "a number in [0, 0.1]: delta of the stopping rule (0: the method's default)"),
    "ga_mutation": ("per_bit", lambda v: v in ("per_bit", "per_chromosome"), "'per_bit' or 'per_chromosome'"),
    "ga_rotation_range_deg": (0.0, lambda v: _is_number(v) and 0.0 <= v <= 180.0,
                              "a number in [0, 180] (0: every orientation)"),
}
#: Point sets of ``kind = "points"`` (document 000's simulation): name -> (default, check, allowed).
POINTS_KEYS: dict[str, tuple[Any, Any, str]] = {
    "count": (150, lambda v: _is_int(v) and 6 <= v <= 1_000_000, "an integer in [6, 10^6]"),
    "layout": ("random", lambda v: v in ("random", "grid"), "'random' or 'grid'"),
    "grid_rows": (10, lambda v: _is_int(v) and 2 <= v <= 1000, "an integer in [2, 1000]"),
    "grid_cols": (30, lambda v: _is_int(v) and 3 <= v <= 1000, "an integer in [3, 1000]"),
    "noise_mean_m": (0.0, lambda v: _is_number(v) and abs(v) <= 0.01, "a number in [-0.01, 0.01]"),
    "noise_sigma_m": (5e-6, lambda v: _is_number(v) and 0.0 < v <= 0.01, "a number in (0, 0.01]"),
    "noise_direction": ("isotropic", lambda v: v in ("isotropic", "normal"), "'isotropic' or 'normal'"),
    "form_error_m": (0.0, lambda v: _is_number(v) and 0.0 <= v <= 0.001, "a number in [0, 0.001]"),
    "truth": ("cad", lambda v: v in ("cad", "exact"),
              "'cad' (points on the CAD mesh the fit sees) or 'exact' (on the part's exact surfaces: "
              "hemisphere_punch, bottle_punch)"),
    "form_wavelength_m": (0.05, lambda v: _is_number(v) and 0.001 <= v <= 10.0, "a number in [0.001, 10]"),
    "region": ([], lambda v: _is_region(v), "a list of tables, each with normal = [x, y, z] and cone_deg, "
               "and/or box_min_m = [x, y, z] and box_max_m = [x, y, z] (workpiece frame)"),
}
#: Normals of ``kind = "normals"`` (document 004): name -> (default, check, allowed).
NORMALS_KEYS: dict[str, tuple[Any, Any, str]] = {
    "method": ("triangulation", lambda v: v in ("triangulation", "pca"), "'triangulation' or 'pca'"),
    "k": (16, lambda v: _is_int(v) and 3 <= v <= 1000, "an integer in [3, 1000]"),
    "cloud": ("raw", lambda v: v in ("raw", "simplified", "bspline"), "'raw', 'simplified' or 'bspline'"),
    "triangles": ("fan", lambda v: v in TRIANGLES, f"one of {', '.join(TRIANGLES)}"),
}
#: JCGM 101 7.9.4 a)'s batch size for a 95 % interval: M = max(100 / (1 - p), 10^4).
GUIDE_BATCH = 10_000
#: The adaptive rule (JCGM 101, 7.9): name -> (default, check, allowed).
ADAPTIVE_KEYS: dict[str, tuple[Any, Any, str]] = {
    "digits": (1, lambda v: _is_int(v) and 1 <= v <= 3, "an integer in [1, 3]"),
    "batch": (GUIDE_BATCH, lambda v: _is_int(v) and 10 <= v <= 100_000,
              "an integer in [10, 10^5]: M, the trials per batch (JCGM 101, 7.9.4 a: 10^4; fewer with a warning)"),
}
#: What counts as a success in the report, besides the status: name -> (default, check, allowed).
SUCCESS_KEYS: dict[str, tuple[Any, Any, str]] = {
    "angle_deg": (1.0, lambda v: _is_number(v) and 0 < v <= 180, "a number in (0, 180]"),
    "distance_m": (0.001, lambda v: _is_number(v) and 0 < v <= 1.0, "a number in (0, 1]"),
}
MAX_TRIALS = 1_000_000
#: Keys that choose how many trials run, not what a trial gives: a resumed study may change them.
EXTENDING_KEYS = ("trials", "adaptive")
#: The study's own keys: name -> (default, what is allowed); the tables are the *_KEYS above.
HEADER_KEYS: dict[str, tuple[Any, str]] = {
    "name": ("study", "a non-empty string"),
    "seed": (0, "an integer in [0, 2^63)"),
    "scenario": ("required", "the base scenario file, relative to the study file"),
    "trials": (10, f"an integer in [1, {MAX_TRIALS}]: trials per grid cell (the most, with [adaptive])"),
    "kind": ("fast", f"one of {', '.join(KINDS)}"),
    "overrides": ({}, "a table of scenario tables merged over the base scenario"),
    "inputs": ({}, "a table of error sources, each a treatment (per_reading, per_trial, fixed, off) or a table "
                   "with treatment, distribution and widths (fast and full trials)"),
    "grid": ({}, 'dotted key paths to value lists: "sensor.sigma_m", "localize.method", "points.count", '
                 '"scenario", "overrides"'),
}


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_vec3(v: Any) -> bool:
    return isinstance(v, list) and len(v) == 3 and all(_is_number(x) for x in v)


def _is_region(v: Any) -> bool:
    """A list of selector tables: ``normal`` + ``cone_deg`` and/or ``box_min_m`` + ``box_max_m``."""
    if not isinstance(v, list):
        return False
    for sel in v:
        if not isinstance(sel, dict) or not sel or set(sel) - {"normal", "cone_deg", "box_min_m", "box_max_m"}:
            return False
        if ("normal" in sel) != ("cone_deg" in sel) or ("box_min_m" in sel) != ("box_max_m" in sel):
            return False
        if "normal" in sel and not (_is_vec3(sel["normal"]) and any(x != 0 for x in sel["normal"])
                                    and _is_number(sel["cone_deg"]) and 0 <= sel["cone_deg"] <= 180):
            return False
        if "box_min_m" in sel and not (_is_vec3(sel["box_min_m"]) and _is_vec3(sel["box_max_m"])
                                       and all(a < b for a, b in zip(sel["box_min_m"], sel["box_max_m"],
                                                                     strict=True))):
            return False
    return True


def _table(raw: dict, name: str, keys: dict) -> dict:
    """The ``[name]`` table of a study with its defaults, every key checked."""
    table = raw.get(name, {})
    if not isinstance(table, dict):
        raise TwinError(f"study [{name}] must be a table, got {table!r}")
    bad = sorted(set(table) - set(keys))
    if bad:
        raise TwinError(f"unknown key(s) {', '.join(name + '.' + k for k in bad)}; "
                        f"allowed in [{name}]: {', '.join(keys)}")
    out = {k: copy.deepcopy(table.get(k, default)) for k, (default, _, _) in keys.items()}
    for k, v in out.items():
        _check_value(keys, k, v, f"{name}.{k}")
    return out


@dataclass(frozen=True)
class CellSettings:
    """What one grid cell runs: its scenario file and overrides, localization, point sets, normals."""

    scenario_path: Path
    overrides: dict
    localize: dict
    points: dict
    normals: dict


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
        scenario_path: the base scenario file (absolute); a ``scenario`` factor replaces it per cell.
        trials: trials per grid cell (the most per cell when ``adaptive``).
        kind: ``"fast"`` (sensor errors redrawn on a cached noise-free scan), ``"full"`` (the
            loop) or ``"points"`` (points sampled on the scenario's part, document 000's simulation).
        overrides: nested tables merged over the scenario file for every cell.
        localize: the localization settings every cell starts from (``LOCALIZE_KEYS``).
        points: the point sets of ``kind = "points"`` (``POINTS_KEYS``).
        normals: the normals of ``kind = "normals"`` (``NORMALS_KEYS``).
        adaptive: the adaptive rule (``ADAPTIVE_KEYS``), or None: a fixed number of trials.
        factors: the grid's keys in file order; ``levels``: their value lists.
        raw: the file's content (for the content hash).
        scenario_text: the text of every scenario file the study uses (for the content hash).
        base_dir: the study file's folder (scenario files are relative to it).
        success: the report's tolerance (``SUCCESS_KEYS``): a trial whose rotation and
            translation errors are within it is counted "within tolerance".
        input_files: (path, SHA-256 of its bytes) of every file the cells' scenarios read (the
            workpiece meshes), for the content hash: a file replaced under the same name is a
            different study.
        inputs: the declared treatment of each error source (``[inputs]``, checked; the sources
            it leaves out take their defaults, :mod:`twin.studies.inputs`).
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
    points: dict = field(default_factory=dict)
    normals: dict = field(default_factory=dict)
    adaptive: dict | None = None
    base_dir: Path = Path(".")
    success: dict = field(default_factory=lambda: {k: v[0] for k, v in SUCCESS_KEYS.items()})
    input_files: tuple[tuple[str, str], ...] = ()
    inputs: dict = field(default_factory=dict)

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

    def cell_settings(self, cell: int) -> CellSettings:
        """What grid cell ``cell`` runs: the study's settings with the cell's factor values and
        the error sources ``[inputs]`` declares ``off`` switched off."""
        s = self._factor_settings(cell)
        off = off_overrides(self.inputs)
        return dataclasses.replace(s, overrides=merge_tables(s.overrides, off)) if off else s

    def _factor_settings(self, cell: int) -> CellSettings:
        values = self.cells[cell]
        over = copy.deepcopy(self.overrides)
        loc, pts, nrm = dict(self.localize), copy.deepcopy(self.points), dict(self.normals)
        path = self.scenario_path
        for key, v in values.items():
            if key == "scenario":
                path = _scenario_file(self.base_dir, v)
            elif key == "overrides":
                over = merge_tables(over, v)
            elif key == "normals":
                nrm.update(v)
            elif key.startswith("localize."):
                loc[key.split(".", 1)[1]] = v
            elif key.startswith("points."):
                pts[key.split(".", 1)[1]] = v
            elif key.startswith("normals."):
                nrm[key.split(".", 1)[1]] = v
            else:
                over = merge_tables(over, _nested(key, v))
        return CellSettings(path, over, loc, pts, nrm)

    def cell_scenario(self, cell: int) -> Scenario:
        s = self.cell_settings(cell)
        return load_scenario(s.scenario_path, s.overrides, machine="arm")

    def cell_inputs(self, cell: int, scenario: Scenario | None = None) -> dict[str, Resolved]:
        """How cell ``cell``'s trials treat each error source of its scenario (``scenario``: the
        cell's, when the caller has loaded it)."""
        return resolve(self.inputs, scenario if scenario is not None else self.cell_scenario(cell), self.kind)

    def set_keys(self, cell: int) -> set[str]:
        """The dotted scenario keys the study sets in cell ``cell`` (its overrides and factors),
        a value ``"random"`` (drawn per realization) left out."""
        return set(_leaves(self._factor_settings(cell).overrides))

    @property
    def content_hash(self) -> str:
        """SHA-256 of the study's canonical content, its scenarios' text and the bytes of every file
        they read (not of the study file's layout or comments): two files meaning the same study
        on the same inputs have the same hash. ``trials`` and ``[adaptive]`` are left out: they say
        how many trials run, not what a trial gives (trial t of cell c is the same trial whatever
        they are), so raising them extends a study with ``--resume``."""
        body = {k: v for k, v in self.raw.items() if k not in ("scenario",) + EXTENDING_KEYS}
        canon = json.dumps({"study": body, "scenario": self.scenario_text, "files": self.input_files},
                           sort_keys=True, default=str)
        return hashlib.sha256(canon.encode()).hexdigest()

    def settings(self) -> dict:
        """The study as a JSON-ready dict (the manifest)."""
        return {"name": self.name, "seed": self.seed, "scenario": str(self.scenario_path), "trials": self.trials,
                "kind": self.kind, "overrides": self.overrides, "localize": self.localize,
                "inputs": self.inputs, "points": self.points, "normals": self.normals, "adaptive": self.adaptive,
                "success": self.success,
                "grid": {k: list(v) for k, v in zip(self.factors, self.levels, strict=True)},
                "cells": self.n_cells, "input_files": {path: digest for path, digest in self.input_files}}


def _leaves(table: dict, prefix: str = "") -> list[str]:
    """Dotted paths of a nested table's leaves and of each table on the way (``noise.hand_eye_error``
    and ``noise.hand_eye_error.xyz``), values ``"random"`` left out."""
    out = []
    for k, v in table.items():
        path = f"{prefix}{k}"
        if isinstance(v, dict):
            out += [path] + _leaves(v, path + ".")
        elif v != "random":
            out.append(path)
    return out


def load_study(path: str | Path) -> Study:
    """Read and validate a study file; raise TwinError with one line on any problem."""
    path = Path(path)
    raw = read_toml(path, "study")
    return parse_study(raw, path.parent)


@dataclass(frozen=True)
class _Header:
    """A study's top-level keys, checked: name, seed, base scenario, trials, kind, overrides."""

    name: str
    seed: int
    scenario_path: Path
    trials: int
    kind: str
    overrides: dict


def _header(raw: dict, base_dir: Path) -> _Header:
    """Check the study's top-level keys (unknown keys, then each key's value)."""
    unknown = sorted(set(raw) - set(TOP_KEYS))
    if unknown:
        raise TwinError(f"unknown study key(s) {', '.join(unknown)}; allowed: {', '.join(TOP_KEYS)}")
    name = raw.get("name", HEADER_KEYS["name"][0])
    if not isinstance(name, str) or not name:
        raise TwinError(f"study name must be a non-empty string, got {name!r}")
    seed = raw.get("seed", HEADER_KEYS["seed"][0])
    if not _is_int(seed) or not 0 <= seed < 2**63:
        raise TwinError(f"study seed must be an integer in [0, 2^63), got {seed!r}")
    if "scenario" not in raw or not isinstance(raw["scenario"], str):
        raise TwinError("study scenario is required: the base scenario file, relative to the study file")
    scenario_path = (base_dir / raw["scenario"]).resolve()
    trials = raw.get("trials", HEADER_KEYS["trials"][0])
    if not _is_int(trials) or not 1 <= trials <= MAX_TRIALS:
        raise TwinError(f"study trials must be an integer in [1, {MAX_TRIALS}], got {trials!r}")
    kind = raw.get("kind", HEADER_KEYS["kind"][0])
    if kind not in KINDS:
        raise TwinError(f"study kind = {kind!r} is not one of {', '.join(KINDS)}")
    overrides = raw.get("overrides", {})
    if not isinstance(overrides, dict):
        raise TwinError(f"study overrides must be a table of scenario tables, got {overrides!r}")
    return _Header(name, seed, scenario_path, trials, kind, overrides)


@dataclass(frozen=True)
class _Tables:
    """A study's settings tables with their defaults, every key checked."""

    localize: dict
    points: dict
    normals: dict
    adaptive: dict | None
    success: dict


def _tables(raw: dict, kind: str) -> _Tables:
    """Read ``[localize]``, ``[points]``, ``[normals]``, ``[adaptive]`` and ``[success]``,
    refusing a table the study's kind does not take."""
    loc = _table(raw, "localize", LOCALIZE_KEYS)
    for table, needs in KIND_TABLES.items():
        if table in raw and kind != needs:
            raise TwinError(f"study [{table}] needs kind = '{needs}'")
    pts = _table(raw, "points", POINTS_KEYS)
    nrm = _table(raw, "normals", NORMALS_KEYS)
    adaptive = _table(raw, "adaptive", ADAPTIVE_KEYS) if "adaptive" in raw else None
    if adaptive is not None and kind == "normals":
        raise TwinError("study [adaptive] watches pose errors; kind = 'normals' takes a fixed number of trials")
    success = _table(raw, "success", SUCCESS_KEYS)
    return _Tables(loc, pts, nrm, adaptive, success)


def _grid(raw: dict) -> tuple[dict, list[str], list[tuple]]:
    """The ``[grid]`` table, its keys in file order and their value lists (non-empty lists)."""
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
    return grid, factors, levels


def _scenario_texts(scenario_paths: list[Path], overrides: dict) -> list[str]:
    """The text of each scenario file, after checking that it loads with the base overrides."""
    texts = []
    for sp in scenario_paths:
        try:
            texts.append(sp.read_text())
        except (OSError, UnicodeDecodeError):
            raise TwinError(f"study scenario not found or unreadable: {sp}") from None
        load_scenario(sp, overrides, machine="arm")  # the base overrides alone
    return texts


def parse_study(raw: dict, base_dir: Path) -> Study:
    """Validate a study's content (a parsed study file) and expand its grid.

    Args:
        raw: the study file's tables.
        base_dir: the study file's folder (scenario files are relative to it).

    Raises:
        TwinError: one line naming the first key or value that is refused; every grid value
            and every grid cell is checked before any trial runs.
    """
    head = _header(raw, base_dir)
    kind, overrides = head.kind, head.overrides
    tables = _tables(raw, kind)
    inputs = parse_inputs(raw.get("inputs"))
    if "inputs" in raw and kind not in INPUT_KINDS:
        raise TwinError(f"study [inputs] needs kind = 'fast' or 'full' (a {kind} trial has no scenario error sources)")
    grid, factors, levels = _grid(raw)
    scenario_paths = [head.scenario_path]
    if "scenario" in grid:
        scenario_paths = [_scenario_file(base_dir, v) for v in grid["scenario"]]
    texts = _scenario_texts(scenario_paths, overrides)
    for key, values in zip(factors, levels, strict=True):
        _check_factor(key, values, kind, scenario_paths, overrides)
    study = Study(head.name, head.seed, head.scenario_path, head.trials, kind, copy.deepcopy(overrides),
                  tables.localize, tuple(factors), tuple(levels), copy.deepcopy(raw), "\n".join(texts),
                  tables.points, tables.normals, tables.adaptive, base_dir.resolve(), tables.success, inputs=inputs)
    designs: set[str] = set()
    for cell in range(study.n_cells):
        settings = study.cell_settings(cell)
        _check_cell(settings, kind)
        if kind in INPUT_KINDS:
            check_not_both(inputs, study.cell_inputs(cell), study.set_keys(cell))
        if kind == "points":
            _check_design(settings, designs)
    return dataclasses.replace(study, input_files=_input_files(study))


def _input_files(study: Study) -> tuple[tuple[str, str], ...]:
    """(path, SHA-256) of each mesh file a cell's scenario reads, sorted by path."""
    meshes = {study.cell_scenario(c).workpiece.mesh for c in range(study.n_cells)} - {None}
    out = []
    for path in sorted(str(m) for m in meshes):
        try:
            out.append((path, hashlib.sha256(Path(path).read_bytes()).hexdigest()))
        except OSError as exc:
            raise TwinError(f"study input file unreadable: {path} ({exc.strerror})") from None
    return tuple(out)


def _check_design(cell: CellSettings, seen: set[str]) -> None:
    """Refuse a region that selects no face or a grid that misses it, once per distinct part
    and design (before any trial runs)."""
    from twin.realize import load_workpiece_mesh
    from twin.studies.point_sets import make_design

    key = json.dumps([str(cell.scenario_path), cell.overrides,
                      {k: cell.points[k] for k in ("region", "layout", "grid_rows", "grid_cols")}],
                     sort_keys=True, default=str)
    if key in seen:
        return
    seen.add(key)
    make_design(load_workpiece_mesh(load_scenario(cell.scenario_path, cell.overrides, machine="arm")), cell.points)


def _scenario_file(base_dir: Path, value: Any) -> Path:
    if not isinstance(value, str) or not value:
        raise TwinError(f"grid 'scenario' values must be scenario file paths (relative to the study file), "
                        f"got {value!r}")
    return (base_dir / value).resolve()


def _check_value(keys: dict, key: str, value: Any, where: str) -> None:
    _, ok, allowed = keys[key]
    if not ok(value):
        raise TwinError(f"{where} {value!r} is refused: must be {allowed}")


def _check_cell(cell: CellSettings, kind: str) -> None:
    """Settings that are refused in combination, whichever factor set them."""
    loc, pts = cell.localize, cell.points
    if loc["subsample"] != "none" and not (kind == "points" and pts["layout"] == "grid"):
        raise TwinError(f"localize.subsample = {loc['subsample']!r} needs kind = 'points' with "
                        "points.layout = 'grid' (the document's M x N grid of measured points)")
    if kind == "points" and pts["layout"] == "grid" and pts["grid_rows"] > pts["grid_cols"]:
        raise TwinError(f"points.grid_rows {pts['grid_rows']} > points.grid_cols {pts['grid_cols']}: "
                        "document 000's Algorithm 4 needs M <= N")
    if loc["variant"] == "printed" and loc["method"] not in (*METHODS, "multistart"):
        raise TwinError(f"localize.variant = 'printed' is document 000's Algorithm 1 (a local method: "
                        f"{', '.join(METHODS)}) or Algorithm 5 (multistart) as printed, not {loc['method']!r}")
    ga_set = loc["ga_mutation"] != "per_bit" or loc["ga_rotation_range_deg"] > 0
    if ga_set and loc["method"] not in ("genetic_coarse", "genetic_001"):
        raise TwinError(f"localize.ga_mutation and localize.ga_rotation_range_deg read document 001's GA "
                        f"(method 'genetic_coarse' or 'genetic_001'), not {loc['method']!r}")
    if loc["foot_points"] == "newton" and (loc["variant"] != "printed" or loc["method"] not in METHODS):
        raise TwinError("localize.foot_points = 'newton' runs document 000's Algorithm 1 as printed: it needs "
                        f"localize.variant = 'printed' and a local method ({', '.join(METHODS)})")
    if loc["tolerance"] and loc["method"] not in METHODS:
        raise TwinError(f"localize.tolerance is the stopping rule's delta of a local method ({', '.join(METHODS)}), "
                        f"not of {loc['method']!r}")
    if loc["points"] and kind == "points":
        raise TwinError("localize.points subsets scanned points; with kind = 'points' set points.count")
    if kind == "normals" and cell.normals["method"] == "pca" and cell.normals["triangles"] != "fan":
        raise TwinError("normals.triangles chooses the triangulation's triangles; method 'pca' has none")
    if kind == "normals":
        scenario = load_scenario(cell.scenario_path, cell.overrides, machine="arm")
        if scenario.sensor.kind != "point":
            raise TwinError(f"kind = 'normals' needs a point sensor (scan lines of one beam); "
                            f"{cell.scenario_path.name} has sensor.kind = {scenario.sensor.kind!r}")


def _check_normals_factor(values: tuple, kind: str) -> None:
    """Grid key ``normals``: tables of normals settings, for kind = "normals"."""
    if kind != "normals":
        raise TwinError("grid key 'normals' needs kind = 'normals'")
    for v in values:
        if not isinstance(v, dict) or not v or set(v) - set(NORMALS_KEYS):
            raise TwinError(f"grid 'normals' values must be tables of {', '.join(NORMALS_KEYS)} "
                            f"(e.g. {{ method = 'pca', k = 16 }}), got {v!r}")
        for k, x in v.items():
            _check_value(NORMALS_KEYS, k, x, f"grid 'normals' value {k}")


def _check_overrides_factor(values: tuple, scenario_paths: list[Path], overrides: dict) -> None:
    """Grid key ``overrides``: tables merged over the scenario; every scenario loads with each."""
    for v in values:
        if not isinstance(v, dict):
            raise TwinError(f"grid 'overrides' values must be tables of scenario tables "
                            f"(e.g. {{ noise = {{ encoder_sigma_rad = 1e-5 }} }}), got {v!r}")
        for sp in scenario_paths:
            try:
                load_scenario(sp, merge_tables(overrides, v), machine="arm")
            except TwinError as exc:
                raise TwinError(f"grid 'overrides' value {v!r} is refused: {' '.join(str(exc).split())}") \
                    from None


def _check_settings_factor(key: str, parts: list[str], values: tuple, kind: str) -> None:
    """Grid key ``localize.K``, ``points.K`` or ``normals.K``: a known key of that table, for a
    kind that takes it, and allowed values."""
    keys = {"localize": LOCALIZE_KEYS, "points": POINTS_KEYS, "normals": NORMALS_KEYS}[parts[0]]
    if len(parts) != 2 or parts[1] not in keys:
        raise TwinError(f"unknown grid key {key!r}; {parts[0]} keys allowed: "
                        f"{', '.join(parts[0] + '.' + k for k in keys)}")
    if parts[0] == "localize" and kind in ("full", "normals"):
        raise TwinError(f"grid key {key!r} needs kind = 'fast' or 'points' "
                        f"(a {kind} trial does not localize from the study's settings)")
    if parts[0] in KIND_TABLES and kind != KIND_TABLES[parts[0]]:
        raise TwinError(f"grid key {key!r} needs kind = '{KIND_TABLES[parts[0]]}'")
    for v in values:
        _check_value(keys, parts[1], v, f"grid {key!r} value")


def _check_scenario_factor(key: str, values: tuple, scenario_paths: list[Path], overrides: dict) -> None:
    """A dotted scenario key: every scenario loads with each value."""
    for v in values:
        for sp in scenario_paths:
            try:
                load_scenario(sp, merge_tables(overrides, _nested(key, v)), machine="arm")
            except TwinError as exc:
                raise TwinError(f"grid {key!r} value {v!r} is refused: {' '.join(str(exc).split())}") from None


def _check_factor(key: str, values: tuple, kind: str, scenario_paths: list[Path], overrides: dict) -> None:
    """Check one grid factor and all its values, whichever table it sets."""
    parts = key.split(".")
    if not all(parts):
        raise TwinError(f"grid key {key!r} is not a dotted key path (e.g. 'sensor.sigma_m', 'localize.method')")
    if key == "scenario":
        return  # each file was loaded by parse_study
    if key == "normals":
        _check_normals_factor(values, kind)
    elif key == "overrides":
        _check_overrides_factor(values, scenario_paths, overrides)
    elif parts[0] in ("localize", "points", "normals"):
        _check_settings_factor(key, parts, values, kind)
    elif parts[0] == "seed":
        raise TwinError("grid key 'seed' is not a factor: every trial draws its own random stream")
    else:
        _check_scenario_factor(key, values, scenario_paths, overrides)
