"""Recordings read back (``rerun.chunk.RrdReader``): the stored layout, the estimated pose in
full precision and its iterations, one points entity per colouring (not one per chunk), the
points against the CAD at the estimate with their deviation and the scale's colours, the
legend, the verdict and pose table in the text panel, a colour per path, paths that appear when
they are planned, a beam that disappears when the scan ends, no singular transform and no
wall-clock timeline, and the same recording streamed live to a viewer while the run goes."""

from __future__ import annotations

import shutil
import socket
import subprocess
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from algorithms.geometry.mesh_index import MeshIndex
from tests.helpers import run_cli, scenario
from twin.deviation import cad_deviation_m, deviation_colours, deviation_scale
from twin.io.report import run_report
from twin.realize import realize
from twin.sensors.base import VALID
from twin.sensors.laser import sensor_sigma_m
from twin.viz import LiveRecording, save_run_recording
from twin.viz.scan import BEAM_HIDDEN_M, STATUS_COLOURS
from twin.workflows import loop


def _chunks(path) -> dict:
    chunks: dict = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")     # a streamed file has no footer (rerun warns, then scans it)
        for ch in RrdReader(path).stream().to_chunks():
            chunks.setdefault(str(ch.entity_path).lstrip("/"), []).append(ch.to_record_batch())
    return chunks


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rerun_executable() -> str:
    """The viewer itself (the ``rerun`` script on the PATH is a wrapper that leaves it running
    when it is terminated)."""
    import rerun_cli

    native = Path(rerun_cli.__file__).with_name("rerun")
    return str(native) if native.exists() else (shutil.which("rerun") or "rerun")


# The face counts of every MeshIndex built while the module's run is made, realized and
# recorded (the run must reuse the realized workpiece's index: one build of the part's mesh).
MESH_INDEX_BUILDS: list[int] = []


def _counting(init):
    def counted(self, mesh, *args, **kwargs):
        MESH_INDEX_BUILDS.append(len(mesh.faces))
        return init(self, mesh, *args, **kwargs)

    return counted


@pytest.fixture(scope="module")
def run_recording(tmp_path_factory):
    """One run, written to a file at the end and streamed stage by stage to a Rerun server
    (``rerun --port P --save FILE``: a viewer's gRPC endpoint that writes what it receives)."""
    folder = tmp_path_factory.mktemp("rec")
    port = _free_port()
    server = subprocess.Popen([_rerun_executable(), "--port", str(port), "--save", str(folder / "live.rrd")],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    build_index = MeshIndex.__init__
    MeshIndex.__init__ = _counting(build_index)
    try:
        for _ in range(100):
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                time.sleep(0.1)
        live = LiveRecording(f"rerun+http://127.0.0.1:{port}/proxy")
        events = []

        def watch(event, value):
            events.append(event)
            live(event, value)

        sc = scenario("s_surface", scan={"max_lines": 4}, path={"line_spacing_m": 0.03})
        result = loop.run(realize(sc), watch=watch)
        report = run_report(result, sensor_sigma_m(sc))
        live.finish(result, report)
        time.sleep(1.0)
        path = folder / "run.rrd"
        save_run_recording(path, result, report=report)
    finally:
        MeshIndex.__init__ = build_index
        server.terminate()
        server.wait(timeout=10)
    assert result.complete, result.failure
    return result, RrdReader(path), _chunks(path), events, _chunks(folder / "live.rrd")


def _column(batches, name) -> list:
    out = []
    for b in batches:
        if name in b.schema.names:
            out.extend(b.column(name).to_pylist())
    return out


def test_one_run_builds_one_closest_point_index_of_its_part(run_recording):
    result = run_recording[0]
    assert MESH_INDEX_BUILDS.count(len(result.realized.workpiece.mesh.faces)) == 1, MESH_INDEX_BUILDS


def test_the_recording_carries_a_blueprint(run_recording):
    _, reader, *_ = run_recording
    assert len(reader.blueprints()) == 1


def test_the_estimate_is_recorded_in_full_precision(run_recording):
    result, _, chunks, *_ = run_recording
    T = result.replay_cell.T_world_base @ result.localization.T_world_workpiece
    stored = np.asarray(_column(chunks["world/workpiece/estimate"], "pose_matrix")[0], dtype=np.float64)
    assert np.abs(stored.reshape(4, 4) - T).max() <= 1e-12
    translation = np.asarray(_column(chunks["world/workpiece/estimate"], "Transform3D:translation")[0])
    assert np.abs(translation.ravel() - T[:3, 3]).max() < 1e-6      # the transform itself is float32


def test_the_scan_points_are_one_entity_per_colouring(run_recording):
    result, _, chunks, *_ = run_recording
    point_entities = [e for e in chunks if e.startswith("world/scan/points")]
    assert sorted(point_entities) == ["world/scan/points", "world/scan/points_by_line", "world/scan/points_by_status"]
    n = sum(len(p) for p in _column(chunks["world/scan/points"], "Points3D:positions"))
    assert n == int(result.scan.valid.sum())
    # by status: every beam that met the part, the valid ones in the valid colour
    colours = np.concatenate([np.asarray(c) for c in _column(chunks["world/scan/points_by_status"], "Points3D:colors")])
    assert len(colours) == int((result.scan.d_true > 0).sum())
    valid_colour = int.from_bytes(bytes([*STATUS_COLOURS[VALID], 255]), "big")
    assert int((colours.ravel() == valid_colour).sum()) == int(result.scan.valid.sum())


def test_the_estimate_moves_over_the_iterations(run_recording):
    result, _, chunks, *_ = run_recording
    loc = result.localization
    assert len(loc.pose_history) == len(loc.history) >= 2
    translations = [np.asarray(t).ravel() for t in _column(chunks["world/workpiece/iterations"],
                                                            "Transform3D:translation") if t is not None]
    # on two timelines (iteration and sim_time): each pose twice, the last the estimate's
    assert len(translations) == 2 * len(loc.history)
    T_last = result.replay_cell.T_world_base @ loc.pose_history[-1]
    assert np.abs(translations[-1] - T_last[:3, 3]).max() < 1e-6
    T_first = result.replay_cell.T_world_base @ loc.pose_history[0]
    assert np.abs(translations[0] - T_first[:3, 3]).max() < 1e-6


def test_every_path_has_its_own_colour(run_recording):
    _, _, chunks, *_ = run_recording
    colours = []
    for name in ("scan_path", "cad_path"):
        colours.append(tuple(np.ravel(_column(chunks[f"world/path/{name}/planned"], "LineStrips3D:colors")[0])))
        colours.append(tuple(np.ravel(_column(chunks[f"world/path/{name}/tcp"], "Points3D:colors")[0])))
    assert len(set(colours)) == 4, colours


def test_the_beam_is_shown_only_while_scanning(run_recording):
    result, _, chunks, *_ = run_recording
    mats = [np.asarray(m, dtype=np.float64).reshape(3, 3).T for m in _column(chunks["world/scan/beam"],
                                                                            "Transform3D:mat3x3") if m is not None]
    # the beam's length is its frame's z column: the distance while scanning, 1 um after
    assert np.linalg.norm(mats[-1][:, 2]) == pytest.approx(BEAM_HIDDEN_M, rel=1e-3)
    assert np.linalg.norm(mats[0][:, 2]) > 0.01


def test_no_transform_is_singular_and_no_wall_clock_timeline(run_recording):
    _, _, chunks, *_ = run_recording
    dets = []
    for entity, batches in chunks.items():
        for m in _column(batches, "Transform3D:mat3x3"):
            if m is not None:
                dets.append((entity, abs(np.linalg.det(np.asarray(m, dtype=np.float64).reshape(3, 3)))))
        for q in _column(batches, "Transform3D:quaternion"):
            if q is not None:
                assert abs(np.linalg.norm(np.asarray(q, dtype=np.float64)) - 1.0) < 1e-5, entity
        assert not any(b.schema.get_field_index("log_time") >= 0 or b.schema.get_field_index("log_tick") >= 0
                       for b in batches), entity
    assert dets and min(d for _, d in dets) > 0.0, min(dets, key=lambda e: e[1])


def test_the_part_view_shows_the_deviation_from_the_cad_at_the_estimate(run_recording):
    result, _, chunks, *_ = run_recording
    batches = chunks["world/deviation/points"]
    positions = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3)
                                for p in _column(batches, "Points3D:positions")])
    deviation_um = np.concatenate([np.asarray(v, dtype=np.float64) for v in _column(batches, "deviation_um")])
    colours = np.concatenate([np.asarray(c).ravel() for c in _column(batches, "Points3D:colors")])
    pts = result.scan.valid_points_base
    assert len(positions) == len(deviation_um) == len(colours) == len(pts)
    # the deviation is against the CAD model at the ESTIMATED pose, not the truth
    expected = cad_deviation_m(pts, result.localization.T_world_workpiece, result.realized.workpiece.index)
    assert np.nanmax(np.abs(deviation_um - expected * 1e6)) < 1e-3
    truth = result.replay_cell.index.signed_distance(
        (pts - result.realized.T_base_workpiece_true[:3, 3]) @ result.realized.T_base_workpiece_true[:3, :3])
    assert np.nanmax(np.abs(expected - truth)) > 1e-7
    # coloured on the scale of the scenario's tolerance and the sensor's uncertainty
    sc = result.realized.scenario
    scale = deviation_scale(sc.tolerances.max_surface_deviation_m, sensor_sigma_m(sc))
    rgb = deviation_colours(expected, scale).astype(np.uint32)
    packed = (rgb[:, 0] << 24) | (rgb[:, 1] << 16) | (rgb[:, 2] << 8) | 255
    assert np.array_equal(colours.astype(np.uint32), packed)


def test_the_legend_and_the_verdict_are_in_the_recording(run_recording):
    result, _, chunks, *_ = run_recording
    blob = _column(chunks["legend"], "EncodedImage:blob")[0]
    assert bytes(np.asarray(blob, dtype=np.uint8).ravel()[:8]) == b"\x89PNG\r\n\x1a\n"
    text = _column(chunks["report"], "TextDocument:text")[0]
    text = text[0] if isinstance(text, list) else text
    assert "## Verdict: PASS" in text and "| rz |" in text and "## Pose" in text


def test_paths_appear_when_they_are_planned(run_recording):
    result, _, chunks, *_ = run_recording
    t_scan_end = float(result.scan.t[-1])
    for name in ("scan_path", "cad_path"):
        batches = chunks[f"world/path/{name}/planned"]
        times = [t for b in batches if "sim_time" in b.schema.names for t in b.column("sim_time").to_pylist()]
        assert times and min(t.total_seconds() if hasattr(t, "total_seconds") else t * 1e-9
                             for t in times) > t_scan_end


def test_the_run_streams_each_stage_to_a_live_viewer(run_recording):
    result, _, chunks, events, live = run_recording
    # the stages reach the viewer as they finish, in the loop's order
    assert events == ["cells", "scan", "localization", "run", "run"]
    assert set(live) == set(chunks)
    stored = np.asarray(_column(live["world/workpiece/estimate"], "pose_matrix")[0], dtype=np.float64)
    T = result.replay_cell.T_world_base @ result.localization.T_world_workpiece
    assert np.abs(stored.reshape(4, 4) - T).max() <= 1e-12
    n = sum(len(p) for p in _column(live["world/scan/points"], "Points3D:positions"))
    assert n == int(result.scan.valid.sum())


@pytest.mark.slow
@pytest.mark.parametrize("args, limit_bytes", [
    (["demo"], 10e6),
    (["run", "scenarios/bottle_punch.toml"], 25e6),
], ids=["demo", "bottle_punch"])
def test_recordings_stay_light_and_carry_the_verdict(tmp_path, args, limit_bytes):
    """The whole runs' recordings within their size limits (the 1 ms data stays in the Parquet
    files), with the verdict the exit code gives."""
    root = Path(__file__).resolve().parents[1]
    out = tmp_path / "out"
    rrd = tmp_path / "run.rrd"
    argv = [args[0], *([str(root / a) for a in args[1:]] if args[0] == "run" else [])]
    r = run_cli(*argv, "--out", out, "--rrd", rrd)
    assert r.returncode in (0, 3), r.stderr
    assert rrd.stat().st_size <= limit_bytes, rrd.stat().st_size
    chunks = _chunks(rrd)
    text = _column(chunks["report"], "TextDocument:text")[0]
    text = text[0] if isinstance(text, list) else text
    assert ("## Verdict: PASS" in text) == (r.returncode == 0)
    assert "world/deviation/points" in chunks and "legend" in chunks
