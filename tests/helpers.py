"""Test helpers: scenarios with overrides."""

from __future__ import annotations

import tomllib
from pathlib import Path

from twin.scenario import load_scenario, merge_tables

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "scenarios"
merge = merge_tables


def raw_scenario(name: str) -> dict:
    return tomllib.loads((SCENARIOS / f"{name}.toml").read_text())


def scenario(name: str = "s_surface", **over):
    """Load a scenario file with nested overrides, e.g. ``scan={"max_lines": 2}``."""
    return load_scenario(SCENARIOS / f"{name}.toml", over)
