"""The deviation map's scale and colours, the pose table and the report page, on known inputs:
the green band is the tolerance, the saturation marks lie beyond the scale, the scale follows
the tolerance and the sensor's uncertainty, a known pose error lands in its row, a free direction
is named and has no uncertainty."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import exp_se3
from twin.deviation import (
    ABOVE_SATURATION,
    BELOW_SATURATION,
    IN_TOLERANCE,
    OFF_PART,
    cad_deviation_m,
    deviation_colours,
    deviation_scale,
    deviation_summary,
)
from twin.io.figures import report_page
from twin.pose_table import markdown, name_direction, pose_table


def test_the_scale_follows_the_tolerance_and_the_uncertainty():
    assert deviation_scale(50e-6, 2e-6).saturation_m == pytest.approx(100e-6)   # twice the tolerance
    assert deviation_scale(5e-6, 4e-6).saturation_m == pytest.approx(24e-6)     # three expanded uncertainties


def test_colours_mark_the_band_the_saturation_and_off_the_part():
    scale = deviation_scale(20e-6, 2e-6)         # saturation 40 um
    rgb = deviation_colours(np.array([0.0, 19e-6, -19e-6, 21e-6, -21e-6, 39e-6, 41e-6, -41e-6, np.nan]), scale)
    assert [tuple(c) for c in rgb[:3]] == [IN_TOLERANCE] * 3
    assert tuple(rgb[3]) != IN_TOLERANCE and rgb[3][0] > rgb[3][2]       # warm outside
    assert tuple(rgb[4]) != IN_TOLERANCE and rgb[4][2] > rgb[4][0]       # cold inside
    assert tuple(rgb[6]) == ABOVE_SATURATION and tuple(rgb[7]) == BELOW_SATURATION
    assert tuple(rgb[5]) not in (ABOVE_SATURATION, BELOW_SATURATION)
    assert tuple(rgb[8]) == OFF_PART


def test_the_deviation_is_against_the_cad_at_the_given_pose():
    index = MeshIndex(trimesh.creation.box([0.1, 0.1, 0.1]))
    top = np.array([[0.01, 0.02, 0.05 + 30e-6], [-0.02, 0.0, 0.05 - 10e-6], [0.0, 0.0, 0.5]])
    T = np.eye(4)
    assert np.allclose(cad_deviation_m(top, T, index)[:2], [30e-6, -10e-6], atol=1e-12)
    assert np.isnan(cad_deviation_m(top, T, index)[2])                  # 0.45 m away: off the part
    T[2, 3] = 20e-6                                                     # the estimate 20 um higher
    assert np.allclose(cad_deviation_m(top, T, index)[:2], [10e-6, -30e-6], atol=1e-12)
    s = deviation_summary(cad_deviation_m(top, np.eye(4), index), deviation_scale(20e-6, 1e-6))
    assert (s["points_on_part"], s["points_off_part"], s["within_tolerance"]) == (2, 1, 1)


def test_the_pose_table_states_a_known_error_and_names_a_free_direction():
    T_true = np.eye(4)
    T_true[:3, 3] = [0.4, 0.1, 0.02]
    xi = np.array([0.0, 0.0, 30e-6, 5e-6, -2e-6, 0.0])                  # rz 30 urad, x 5 um, y -2 um
    T_est = T_true @ exp_se3(xi)
    free = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 1.0]])                   # z free
    determined = np.eye(6)[:5]
    cov = np.diag([1e-12, 1e-12, 4e-12, 1e-12, 9e-12])
    table = pose_table(T_true, T_est, T_true, determined, free, cov)
    rows = {r["component"]: r for r in table["rows"]}
    assert rows["rz"]["error"] == pytest.approx(30.0, abs=1e-6)
    assert rows["x"]["error"] == pytest.approx(5.0, abs=1e-6) and rows["y"]["error"] == pytest.approx(-2.0, abs=1e-6)
    assert rows["rz"]["std"] == pytest.approx(2.0) and rows["y"]["std"] == pytest.approx(3.0)
    assert rows["z"]["error"] is None and rows["z"]["std"] is None
    assert rows["x"]["truth"] == pytest.approx(400.0)
    assert table["free_directions"] == ["translation along z"]
    assert "| z |" in markdown(table) and "free" in markdown(table)
    assert name_direction(np.array([1.0, 1.0, 0, 0, 0, 0])).startswith("combination")


def test_the_report_page_shows_the_verdict_and_the_pose_table(tmp_path):
    T = np.eye(4)
    table = pose_table(T, T, T, np.eye(6), np.zeros((0, 6)), np.eye(6) * 1e-12)
    report = {"passed": False, "checks": [{"name": "cad_path: coverage", "passed": False, "detail": "80 %",
                                           "decides": True}],
              "localization": {"pose_table": table}, "scenario": "/a/long/path/part.toml", "wall_s": 12.3456789}
    page = report_page(report, [], tmp_path / "report.html", "twin run: part").read_text()
    assert "Verdict: <span class=fail>FAIL</span>" in page and "cad_path: coverage" in page
    assert "<h2>Pose</h2>" in page and "<td>rz</td>" in page
    assert "part.toml" in page and "/a/long/path" not in page and "12.35" in page
