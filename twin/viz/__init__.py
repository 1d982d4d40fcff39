"""Rerun recordings: the only package that imports rerun, one module per stage.

Entity paths mirror the frame tree: ``world/robot/<body>`` (geometry static, poses on the
``sim_time`` timeline), ``world/workpiece/true`` (and ``.../nominal``), ``world/scan/beam``,
``world/scan/points`` (each point appears at the time it is measured), ``world/path/<name>``,
``plots/...``. Long runs are logged in columns (``rr.send_columns``).
"""

from twin.viz.recording import LiveRecording, save_run_recording, save_scan_recording

__all__ = ["LiveRecording", "save_run_recording", "save_scan_recording"]
