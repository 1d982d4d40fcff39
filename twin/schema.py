"""Every key a scenario or study file may hold, read from the validators themselves.

The documentation's key reference is generated from here, so a key the validator accepts
cannot be missing from it and a key it no longer reads cannot linger there:

- scenario keys: the scenario validator (:func:`twin.scenario.parse_scenario`) notes every key
  it reads in :data:`twin.scenario.KEY_LOG`; it is run here on every shipped scenario (arm and
  CMM, one pass or several, with and without a probe), and each key is listed once with its
  type, the default the validator applied and what it allows;
- study keys: the tables of :mod:`twin.studies.spec` (``HEADER_KEYS``, ``LOCALIZE_KEYS``, ...).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from twin import scenario as scenario_module
from twin.formats.toml_files import read_toml

#: The folder of the shipped scenarios (the repository's ``scenarios/``).
SCENARIO_DIR = Path(__file__).resolve().parent.parent / "scenarios"


@dataclass(frozen=True)
class KeyDoc:
    """One key of a file: its table (``""`` for the top level), name, type, default, allowed values."""

    table: str
    key: str
    kind: str
    default: str
    allowed: str


def _show(value: Any) -> str:
    """A default as a reader writes it in TOML (a 4x4 identity as ``identity``)."""
    if isinstance(value, np.ndarray):
        if value.shape == (4, 4):
            return "identity" if np.allclose(value, np.eye(4)) else f"xyz {np.round(value[:3, 3], 6).tolist()}"
        return str(value.tolist())
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return value if value == "required" else f'"{value}"'
    return repr(value)


def scenario_files(folder: Path = SCENARIO_DIR) -> list[Path]:
    """The shipped scenario files: the arm's and the CMM's."""
    return sorted(folder.glob("*.toml")) + sorted(folder.glob("cmm/*.toml"))


def scenario_keys(files: list[Path] | None = None) -> list[KeyDoc]:
    """Every key the scenario validator reads from ``files`` (default: the shipped scenarios), in
    the order it reads them. A default is the one applied where a file leaves the key out
    (several when it depends on other keys, e.g. ``sensor.beams`` on ``sensor.kind``)."""
    log: list[tuple[str, str, str, Any, str, bool]] = []
    scenario_module.KEY_LOG = log
    try:
        # The least a scenario holds first: every other key then shows the validator's own default.
        scenario_module.parse_scenario(_MINIMAL, name="the file's name")
        scenario_module.parse_scenario(_ONE_PASS, name="the file's name")
        for path in files if files is not None else scenario_files():
            raw = read_toml(path, "scenario")
            scenario_module.parse_scenario(raw, name=path.stem, base_dir=path.parent, source=str(path))
    finally:
        scenario_module.KEY_LOG = None
    return _merge(log)


def _merge(log: list[tuple[str, str, str, Any, str, bool]]) -> list[KeyDoc]:
    """One row per (table, key); the defaults seen where the key was left out."""
    order: dict[tuple[str, str], tuple[str, str]] = {}
    defaults: dict[tuple[str, str], list[str]] = {}
    for where, key, kind, default, allowed, given in log:
        table = re.sub(r"\[\d+\]", "[]", where)
        table = "" if "." not in table and table not in _TABLES else table
        order.setdefault((table, key), (kind, allowed))
        seen = defaults.setdefault((table, key), [])
        shown = _show(default)
        if (not given or shown == "required") and shown not in seen:
            seen.append(shown)
    return [KeyDoc(table, key, kind, " or ".join(defaults[(table, key)]) or "-", allowed)
            for (table, key), (kind, allowed) in order.items()]


#: The smallest valid scenario: a generated part and where it truly is.
_MINIMAL = {"workpiece": {"shape": "s_surface", "true_pose": {"xyz": [0.5, 0.0, 0.0]}}}
#: The same with one ``[[scan.passes]]`` table, every key of the pass left to its default.
_ONE_PASS = {**_MINIMAL, "scan": {"passes": [{}]}}

#: The scenario's tables (the validator names the top level after the file, so these tell them apart).
_TABLES = ("workpiece", "robot", "sensor", "noise", "scan", "path", "probe", "locate", "tolerances", "cmm")


def study_keys() -> list[KeyDoc]:
    """Every key of a study file, from the tables the study validator checks against."""
    from twin.studies import inputs, spec

    rows = [KeyDoc("", key, "", _show(default), allowed) for key, (default, allowed) in spec.HEADER_KEYS.items()]
    tables = {"localize": spec.LOCALIZE_KEYS, "points": spec.POINTS_KEYS, "normals": spec.NORMALS_KEYS,
              "adaptive": spec.ADAPTIVE_KEYS, "success": spec.SUCCESS_KEYS}
    for table, keys in tables.items():
        rows += [KeyDoc(table, key, "", _show(default), allowed) for key, (default, _, allowed) in keys.items()]
    for name, src in inputs.SOURCES.items():
        default = ("fixed" if name == "part_pose" else
                   f"{'per_trial' if src.systematic else 'per_reading'} where the scenario has it on, else off")
        per_trial = (f"; per_trial: distribution, {', '.join(src.widths)}" if src.widths
                     else "; per_trial: amplitude" if name == "linearity" else "")
        rows.append(KeyDoc("inputs", name, "", default, ", ".join(src.treatments) + per_trial))
    return rows


def keys_markdown(keys: list[KeyDoc], meanings: dict[tuple[str, str], str] | None = None) -> str:
    """The keys as Markdown: one table per TOML table, in the order the validator reads them;
    ``meanings`` adds what each key means where one is known."""
    meanings = meanings or {}
    typed = any(k.kind for k in keys)
    head = ["key"] + (["type"] if typed else []) + ["default", "allowed", "meaning"]
    out: list[str] = []
    for table in dict.fromkeys(k.table for k in keys):
        title = f"`[[{table[:-2]}]]`" if table.endswith("[]") else f"`[{table}]`"
        out += ["", f"## {title}" if table else "## Top level", "",
                "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for k in (k for k in keys if k.table == table):
            cells = ([f"`{k.key}`"] + ([k.kind] if typed else [])
                     + [_cell(k.default), _cell(k.allowed), _cell(meanings.get((table, k.key), ""))])
            out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out).lstrip() + "\n"


def _cell(text: str) -> str:
    """Text safe inside a Markdown table cell."""
    return text.replace("|", "\\|").replace("\n", " ") if text else ""
