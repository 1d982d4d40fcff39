"""Recordings read back (``rerun.chunk.RrdReader``): the stored layout, the estimated pose in
full precision, one points entity per scan (not one per chunk), a colour per path, and a
beam that disappears when the scan ends."""

from __future__ import annotations

import numpy as np
import pytest
from rerun.chunk import RrdReader

from tests.helpers import scenario
from twin import pipeline
from twin.realize import realize
from twin.viz import save_run_recording


@pytest.fixture(scope="module")
def run_recording(tmp_path_factory):
    sc = scenario("s_surface", scan={"max_lines": 4}, path={"line_spacing_m": 0.03})
    result = pipeline.run(realize(sc))
    assert result.complete, result.failure
    path = tmp_path_factory.mktemp("rec") / "run.rrd"
    save_run_recording(path, result)
    chunks: dict = {}
    for ch in RrdReader(path).stream().to_chunks():
        chunks.setdefault(str(ch.entity_path).lstrip("/"), []).append(ch.to_record_batch())
    return result, RrdReader(path), chunks


def _column(batches, name) -> list:
    out = []
    for b in batches:
        if name in b.schema.names:
            out.extend(b.column(name).to_pylist())
    return out


def test_the_recording_carries_a_blueprint(run_recording):
    _, reader, _ = run_recording
    assert len(reader.blueprints()) == 1


def test_the_estimate_is_recorded_in_full_precision(run_recording):
    result, _, chunks = run_recording
    T = result.replay_cell.T_world_base @ result.localization.T_world_workpiece
    stored = np.asarray(_column(chunks["world/workpiece/estimate"], "pose_matrix")[0], dtype=np.float64)
    assert np.abs(stored.reshape(4, 4) - T).max() <= 1e-12
    translation = np.asarray(_column(chunks["world/workpiece/estimate"], "Transform3D:translation")[0])
    assert np.abs(translation.ravel() - T[:3, 3]).max() < 1e-6      # the transform itself is float32


def test_the_scan_points_are_one_entity_per_colouring(run_recording):
    result, _, chunks = run_recording
    point_entities = [e for e in chunks if e.startswith("world/scan/points")]
    assert sorted(point_entities) == ["world/scan/points", "world/scan/points_by_line"]
    n = sum(len(p) for p in _column(chunks["world/scan/points"], "Points3D:positions"))
    assert n == int(result.scan.valid.sum())


def test_every_path_has_its_own_colour(run_recording):
    _, _, chunks = run_recording
    colours = []
    for name in ("scan_path", "cad_path"):
        colours.append(tuple(np.ravel(_column(chunks[f"world/path/{name}/planned"], "LineStrips3D:colors")[0])))
        colours.append(tuple(np.ravel(_column(chunks[f"world/path/{name}/tcp"], "Points3D:colors")[0])))
    assert len(set(colours)) == 4, colours


def test_the_beam_is_shown_only_while_scanning(run_recording):
    result, _, chunks = run_recording
    mats = [np.asarray(m).ravel() for m in _column(chunks["world/scan/beam"], "Transform3D:mat3x3") if m is not None]
    assert np.abs(mats[-1]).max() == 0.0 and np.abs(mats[0]).max() > 0.0
