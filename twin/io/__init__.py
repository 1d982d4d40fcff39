"""Files the twin writes and reads: scan files (Parquet, PLY, JSON) and reports (JSON).

Every report field in units other than SI says so in its name (``_mm``, ``_um``, ``_deg``);
the conversion happens in :mod:`twin.io.report` only.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from twin.io.scan_files import read_points_ply, write_points_ply, write_scan

__all__ = ["read_points_ply", "write_points_ply", "write_scan"]


def __getattr__(name: str) -> Any:
    """The scan-file functions, imported on first use: ``twin.io.output`` (every command's
    output staging) stays free of NumPy and Arrow, so ``twin --help`` starts at once."""
    if name in __all__:
        return getattr(importlib.import_module("twin.io.scan_files"), name)
    raise AttributeError(f"module 'twin.io' has no attribute {name!r}")
