"""Files the twin writes and reads: scan files (Parquet, PLY, JSON) and reports (JSON).

Every report field in units other than SI says so in its name (``_mm``, ``_um``, ``_deg``);
the conversion happens in :mod:`twin.io.report` only.
"""

from twin.io.scan_files import read_points_ply, write_points_ply, write_scan

__all__ = ["read_points_ply", "write_points_ply", "write_scan"]
