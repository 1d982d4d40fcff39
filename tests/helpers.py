"""Test helpers: scenarios with overrides."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

from twin.scenario import parse_scenario

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "scenarios"


def merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict) and not ({"xyz", "rpy_deg", "matrix"} & set(v)):
            out[k] = merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def raw_scenario(name: str) -> dict:
    return tomllib.loads((SCENARIOS / f"{name}.toml").read_text())


def scenario(name: str = "s_surface", **over):
    """Parse a scenario file with nested overrides, e.g. ``scan={"max_lines": 2}``."""
    return parse_scenario(merge(raw_scenario(name), over), name=name, base_dir=SCENARIOS)
