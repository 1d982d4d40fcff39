"""The recording of ``twin cmm``: the part at its true pose and each program on its own entity:
its ball-centre path, the probe (ball, stylus, body to the head) moving on the shared
timeline (every program starts at 0 s, so the cursor compares them), its hits and its
contacts marked where they happened."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from algorithms.geometry.se3 import transform_points
from twin import evaluate
from twin.cmm_machine import CmmRun, CmmSetup
from twin.viz.blueprint import TIMELINE, cumulative, eye_on

PROGRAM_COLOURS = {"baseline": [255, 150, 30], "document": [40, 120, 255], "full_check": [40, 200, 90]}
DEFAULT_COLOUR = [200, 200, 200]
#: The moving probe is logged every this many 1 ms samples.
PROBE_EVERY = 20


def save_cmm_recording(path: str | Path, setup: CmmSetup, runs: dict[str, CmmRun],
                       app_id: str = "scan_twin_cmm") -> Path:
    """Write the ``.rrd`` of one or more program runs on one scenario (world frame)."""
    path = Path(path)
    rec = rr.RecordingStream(app_id)
    T_true, T_nom = evaluate.true_part_pose_world(setup), setup.T_world_part_nominal
    mesh = setup.mesh
    with rec:
        rec.save(str(path))
        focus = transform_points(T_true, mesh.bounds.mean(axis=0)[None])[0]
        extent = float(np.ptp(mesh.vertices, axis=0).max())
        views = [rrb.Spatial3DView(origin="world", name="all programs", eye_controls=eye_on(focus, 2.5 * extent),
                                   time_ranges=cumulative())]
        views += [rrb.Spatial3DView(origin="world", name=m, contents=["world/part/**", f"world/cmm/{m}/**"],
                                    eye_controls=eye_on(focus, 2.5 * extent)) for m in runs]
        rr.send_blueprint(rrb.Blueprint(rrb.Horizontal(views[0], rrb.Vertical(*views[1:]) if len(views) > 1
                                                       else rrb.TextDocumentView(origin="report")),
                                        rrb.TimePanel(timeline=TIMELINE, play_state="paused"), collapse_panels=False))
        rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        v = transform_points(T_true, mesh.vertices)
        rr.log("world/part/mesh", rr.Mesh3D(vertex_positions=v, triangle_indices=mesh.faces,
                                            vertex_normals=mesh.vertex_normals @ T_true[:3, :3].T,
                                            albedo_factor=[190, 160, 110, 120]), static=True)
        for method, run in runs.items():
            _log_run(f"world/cmm/{method}", run, setup, T_nom, PROGRAM_COLOURS.get(method, DEFAULT_COLOUR))
        rec.flush()
    return path


def _log_run(root: str, run: CmmRun, setup: CmmSetup, T_nom: np.ndarray, colour) -> None:
    ball = transform_points(T_nom, run.ball_part_m)
    rr.log(f"{root}/path", rr.LineStrips3D([ball[::5]], colors=[colour], radii=0.0004), static=True)
    idx = np.arange(0, len(run.t_s), PROBE_EVERY)
    rr.send_columns(f"{root}/ball", indexes=[rr.TimeColumn(TIMELINE, duration=run.t_s[idx])],
                    columns=rr.Points3D.columns(positions=ball[idx]))
    rr.log(f"{root}/ball", rr.Points3D.from_fields(radii=0.0015, colors=[colour]), static=True)
    heads = run.head_world_m[idx]
    strips = np.stack([ball[idx], heads], axis=1)
    rr.send_columns(f"{root}/probe", indexes=[rr.TimeColumn(TIMELINE, duration=run.t_s[idx])],
                    columns=rr.LineStrips3D.columns(strips=list(strips)).partition([1] * len(idx)))
    rr.log(f"{root}/probe", rr.LineStrips3D.from_fields(radii=0.002, colors=[colour]), static=True)
    hits = [h for h in run.hits if h.measured_m is not None]
    if hits:
        rr.log(f"{root}/hits", rr.Points3D(transform_points(T_nom, np.array([h.measured_m for h in hits])),
                                           radii=0.0012, colors=[[40, 220, 90]], labels=[h.label for h in hits]),
               static=True)
    if run.contacts:
        where = transform_points(evaluate.true_part_pose_world(setup), np.array([c.part_point_m for c in run.contacts]))
        rr.log(f"{root}/contacts", rr.Points3D(where, radii=0.003, colors=[[255, 0, 60]],
                                               labels=[f"{c.solid}, statement {c.statement + 1} ({c.kind}), "
                                                       f"t {c.first_t_s:.2f} s" for c in run.contacts]), static=True)
