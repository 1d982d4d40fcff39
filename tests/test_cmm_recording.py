"""The recording of ``twin cmm compare`` (twin/viz/cmm.py), read back: the machine drawn and
moving, one entity root per program, the probe as its latest pose only, the contacts as large
labelled markers, the report panel with the comparison table and the legend, and no spurious
``log_time``/``log_tick`` timelines."""

import json
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from twin.cli import main

ROOT = Path(__file__).resolve().parents[1]
CMM = ROOT / "scenarios" / "cmm"
PROGRAMS = ("baseline", "document", "full_check")
#: The motion is sampled every 20 ms (twin.viz.cmm.SAMPLE_EVERY).
SAMPLE_S = 0.02


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    """``twin cmm compare`` on the through-hole case (the baseline collides, 54 contact events;
    the document's and the full check's programs share one path and do not collide)."""
    out = tmp_path_factory.mktemp("cmm") / "compare"
    rc = main(["cmm", "compare", str(CMM / "teach" / "through_hole.toml"), str(CMM / "through_hole.toml"),
               "--out", str(out), "--quiet"])
    assert rc == 0
    reader = RrdReader(out / "cmm.rrd")
    chunks = [(str(ch.entity_path).lstrip("/"), ch.to_record_batch()) for ch in reader.stream().to_chunks()]
    blueprint = [(str(ch.entity_path).lstrip("/"), ch.to_record_batch())
                 for ch in reader.stream(store=reader.blueprints()[0]).to_chunks()]
    report = {p["method"]: p["run"] for p in json.loads((out / "report.json").read_text())["programs"]}
    return {"out": out, "chunks": chunks, "blueprint": blueprint, "report": report}


def _column(chunks, entity: str, column: str) -> list:
    """Every row of ``column`` on ``entity``, over all its chunks."""
    return [v for e, rb in chunks if e == entity and column in rb.schema.names for v in rb[column].to_pylist()]


def _times_s(chunks, entity: str) -> np.ndarray:
    """The ``sim_time`` [s] of every row of ``entity``."""
    ns = [rb["sim_time"].cast("int64").to_numpy() for e, rb in chunks if e == entity and "sim_time" in rb.schema.names]
    return np.concatenate(ns) * 1e-9 if ns else np.zeros(0)


def _entities(chunks, column: str) -> set[str]:
    return {e for e, rb in chunks if column in rb.schema.names}


def test_the_machine_is_drawn_and_its_axes_move_on_sim_time(compared):
    meshes = _entities(compared["chunks"], "Mesh3D:vertex_positions")
    assert "world/machine/table/granite" in meshes
    for m in PROGRAMS:
        bodies = {seg for e in meshes if e.startswith(f"world/machine/{m}/") for seg in e.split("/")[3:]}
        assert {"bridge", "carriage", "ram", "head"} <= bodies, (m, bodies)
        ram = next(e for e in _entities(compared["chunks"], "Transform3D:translation")
                   if e.startswith(f"world/machine/{m}/") and e.endswith("/ram"))
        z_m = np.array(_column(compared["chunks"], ram, "Transform3D:translation")).reshape(-1, 3)[:, 2]
        times_s = _times_s(compared["chunks"], ram)
        assert len(times_s) == len(z_m) > 10 and np.all(np.diff(np.sort(times_s)) > 0)
        assert np.ptp(z_m) > 0.01  # the Z axis travels
    # no singular transform: every rotation a unit quaternion, no scale logged
    for e, rb in compared["chunks"]:
        assert "Transform3D:scale" not in rb.schema.names and "Transform3D:mat3x3" not in rb.schema.names
        if "Transform3D:quaternion" in rb.schema.names:
            q = np.array(rb["Transform3D:quaternion"].to_pylist()).reshape(-1, 4)
            assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-5), e


def test_each_program_is_one_entity_root_in_its_own_colour_and_width(compared):
    entities = {e for e, _ in compared["chunks"]}
    roots = {e.split("/")[2] for e in entities if e.startswith("world/cmm/")}
    assert roots == set(PROGRAMS)
    colours, radii = {}, {}
    for m in PROGRAMS:
        assert {f"world/cmm/{m}/{x}" for x in ("path", "ball", "stylus", "hits")} <= entities
        colours[m] = tuple(_column(compared["chunks"], f"world/cmm/{m}/path", "LineStrips3D:colors")[0])
        radii[m] = _column(compared["chunks"], f"world/cmm/{m}/path", "LineStrips3D:radii")[0][0]
    # the document's and the full check's programs share their path: colour and width tell them apart
    assert len(set(colours.values())) == len(PROGRAMS)
    assert radii["baseline"] > radii["document"] > radii["full_check"] > 0


def test_the_probe_is_its_latest_pose_sampled_every_20_ms_and_no_view_accumulates(compared):
    for m in PROGRAMS:
        cycle_s = compared["report"][m]["cycle_time_s"]
        t_s = _times_s(compared["chunks"], f"world/cmm/{m}/ball")
        assert cycle_s / SAMPLE_S - 1 <= len(t_s) <= cycle_s / SAMPLE_S + 2
        assert t_s.max() == pytest.approx(cycle_s, abs=1e-3)
        assert len(_times_s(compared["chunks"], f"world/cmm/{m}/stylus")) == len(t_s)
    # the ball turns red while the baseline's probe touches the part, never in the full check's run
    red = 0xE60000FF
    assert red in {c[0] for c in _column(compared["chunks"], "world/cmm/baseline/ball", "Points3D:colors")}
    assert red not in {c[0] for c in _column(compared["chunks"], "world/cmm/full_check/ball", "Points3D:colors")}
    names = {n for _, rb in compared["blueprint"] for n in rb.schema.names}
    assert not any("TimeRange" in n for n in names), names  # latest value only, in every view


def test_the_contacts_are_large_red_labelled_markers(compared):
    chunks, report = compared["chunks"], compared["report"]
    assert report["baseline"]["contacts"] == 54 and report["full_check"]["contacts"] == 0
    labels = _column(chunks, "world/cmm/baseline/contacts", "Points3D:labels")[0]
    each = _column(chunks, "world/cmm/baseline/contacts/each", "Points3D:positions")[0]
    assert len(each) == report["baseline"]["contacts"]
    # one marker per statement's move, labelled with its solids, statement (1-based), move and time
    listed = report["baseline"]["contact_list"]
    assert {(c["statement"], c["move"]) for c in listed} == {
        (int(label.split("statement ")[1].split(" ")[0]), label.split("(")[1].split(")")[0]) for label in labels}
    solids = {s.split(" x")[0] for label in labels for s in label.split(":")[0].split(", ")}
    assert solids == {c["solid"] for c in listed}
    assert all(label.endswith(" s") and ", t " in label for label in labels)  # the time
    assert _column(chunks, "world/cmm/baseline/contacts", "Points3D:show_labels") == [[True]]
    radius_m = _column(chunks, "world/cmm/baseline/contacts", "Points3D:radii")[0][0]
    ball_m = _column(chunks, "world/cmm/baseline/ball", "Points3D:radii")[0][0]
    assert radius_m >= 2 * ball_m
    assert not any(e.startswith(("world/cmm/document/contacts", "world/cmm/full_check/contacts"))
                   for e, _ in chunks)


def test_the_report_panel_has_the_comparison_table_and_the_legend(compared):
    text = _column(compared["chunks"], "report", "TextDocument:text")[0][0]
    table = (compared["out"] / "report.md").read_text()
    header = next(line for line in table.splitlines() if line.startswith("| program"))
    assert header in text and "through_hole on cmm_through_hole" in text
    for m in PROGRAMS:
        assert f"| {m} |" in text
    assert "Legend" in text and all(w in text for w in ("orange", "blue", "green", "red", "magenta"))
    assert "statement 9" in text  # the baseline's contacts, listed
    views = [(rb["ViewBlueprint:class_identifier"][0].as_py()[0], rb["ViewBlueprint:space_origin"][0].as_py()[0],
              rb["ViewBlueprint:display_name"][0].as_py()[0])
             for _, rb in compared["blueprint"] if "ViewBlueprint:class_identifier" in rb.schema.names]
    assert ("TextDocument", "report", "report") in views
    assert {name for kind, _, name in views if kind == "3D"} == {"all programs", "machine", *PROGRAMS}


def test_the_recording_has_no_log_time_or_log_tick_timeline(compared):
    names = {n for _, rb in compared["chunks"] for n in rb.schema.names}
    assert "sim_time" in names
    assert not names & {"log_time", "log_tick"}
