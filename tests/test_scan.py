"""The scan cell: sensor geometry, noise model, reconstruction, error sources, files."""

import dataclasses

import mujoco
import numpy as np
import pyarrow.parquet as pq
import pytest

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from tests.helpers import scenario
from tests.tolerances import ANALYTIC_DISTANCE_M, ON_SURFACE_M
from twin.cell import build_spec, compile_cell
from twin.ik import IKSolver
from twin.realize import load_workpiece_mesh, realize
from twin.robot import HOME_Q
from twin.scan import IK_ORIENTATION_TOL_RAD, IK_POSITION_TOL_M, scan_scenario
from twin.sensors.base import OUT_OF_WINDOW, VALID

SHORT = {"max_lines": 3}


def residuals_m(scan, mesh_index):
    """Unsigned distance of every valid point to the TRUE scene: workpiece mesh or table plane [m]."""
    pts = scan.valid_points_base.reshape(-1, 3)
    p = transform_points(inv_pose(scan.T_base_workpiece_true), pts)
    to_table = np.abs(transform_points(scan.scenario.T_world_base, pts)[:, 2])
    return np.minimum(mesh_index.query(p).distance, to_table)


@pytest.fixture(scope="module")
def s_mesh():
    return load_workpiece_mesh(scenario("s_surface"))


@pytest.fixture(scope="module")
def s_index(s_mesh):
    return MeshIndex(s_mesh)


@pytest.fixture(scope="module")
def noise_off_scan(s_mesh):
    sc = scenario("s_surface", scan=SHORT)
    return scan_scenario(dataclasses.replace(sc, noise=sc.noise.all_off()), mesh=s_mesh)


@pytest.fixture(scope="module")
def default_scan(s_mesh):
    return scan_scenario(scenario("s_surface"), mesh=s_mesh)


def test_noise_off_points_lie_on_the_true_surface(noise_off_scan, s_index):
    r = residuals_m(noise_off_scan, s_index)
    assert noise_off_scan.valid.sum() > 5000
    assert r.max() < ON_SURFACE_M


def _point_sensor_at(sc, T_world_sensor, extra=None):
    """A compiled cell with the sensor driven (by IK) to ``T_world_sensor``."""
    realized = realize(sc)
    spec, poses = build_spec(realized, "true")
    if extra:
        extra(spec)
    cell = compile_cell(spec, realized, "true", poses)
    ik = IKSolver(cell.model, "laser", IK_POSITION_TOL_M, IK_ORIENTATION_TOL_RAD)
    ik.set_q(HOME_Q)
    pe, oe, _ = ik.solve(T_world_sensor, 0.05, 500, velocity_limited=False)
    assert pe < 1e-7 and oe < 1e-6
    cell.set_q(ik.q)
    ray = cell.data.sensordata[cell.model.sensor("laser_ray").adr[0]:][:13]
    return cell, ray


def test_distance_to_the_table_plane_is_analytic():
    sc = scenario("s_surface", workpiece={"true_pose": {"xyz": [0.6, 0.4, 0.0]}})
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0]) @ _rot_x(0.3)  # beam down, tilted 0.3 rad
    T[:3, 3] = [0.35, -0.1, 0.085]
    cell, ray = _point_sensor_at(sc, T)
    origin, direction = ray[4:7], ray[1:4]
    analytic = origin[2] / -direction[2]
    assert abs(ray[0] - analytic) < ANALYTIC_DISTANCE_M


def test_distance_to_a_sphere_is_analytic():
    sc = scenario("s_surface", workpiece={"true_pose": {"xyz": [0.6, 0.4, 0.0]}})
    centre, radius = np.array([0.42, -0.05, 0.03]), 0.025

    def add_sphere(spec):
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0], pos=centre,
                                group=3, contype=0, conaffinity=1)

    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = centre + [0.004, 0.007, radius + 0.07]
    cell, ray = _point_sensor_at(sc, T, add_sphere)
    o, u = ray[4:7], ray[1:4]
    oc = o - centre
    b = oc @ u
    analytic = -b - np.sqrt(b * b - (oc @ oc - radius**2))
    assert abs(ray[0] - analytic) < ANALYTIC_DISTANCE_M


def _rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def test_il065_defaults_timing_window_and_noise(default_scan, s_index):
    scan = default_scan
    assert np.array_equal(scan.t, np.arange(len(scan.t)) * 0.001)
    d = scan.d[scan.valid]
    assert d.min() >= 0.055 and d.max() <= 0.105
    assert np.all(np.isnan(scan.d[~scan.valid]))


def test_residual_rms_matches_the_configured_noise(s_mesh, s_index):
    # Gaussian and quantisation only: the normal residual is sigma * z plus the rounding.
    sc = scenario("s_surface", scan=SHORT, noise={"linearity": False},
                  sensor={"sigma_m": 5e-6})
    scan = scan_scenario(sc, mesh=s_mesh)
    r = residuals_m(scan, s_index)
    expected = np.sqrt(5e-6**2 + 1e-6**2 / 12)
    assert 0.9 < np.sqrt(np.mean(r**2)) / expected < 1.1


def test_linearity_curve_shows_as_a_systematic_error(s_mesh, s_index):
    sc = scenario("s_surface", scan={"max_lines": 2, "standoff_m": 0.0675},
                  noise={"gaussian": False, "quantization": False, "incidence": False})
    scan = scan_scenario(sc, mesh=s_mesh)
    # At a quarter window below the reference the curve is at its -10 um extreme.
    r = residuals_m(scan, s_index)
    on_line = scan.line[np.nonzero(scan.valid)[0]] >= 0
    assert np.median(r[on_line]) == pytest.approx(10e-6, rel=0.1)


def test_out_of_window_samples_are_nan_never_clamped(s_mesh):
    sc = scenario("s_surface", scan={"max_lines": 1, "standoff_m": 0.104, "retract_m": 0.01})
    scan = scan_scenario(sc, mesh=s_mesh)
    out = scan.status == OUT_OF_WINDOW
    assert out.any()
    assert np.all(np.isnan(scan.d[out])) and not scan.valid[out].any()
    assert np.all(scan.d_true[out] > 0)


def test_same_seed_same_numbers(s_mesh):
    sc = scenario("s_surface", scan={"max_lines": 1})
    a, b = scan_scenario(sc, mesh=s_mesh), scan_scenario(sc, mesh=s_mesh)
    assert np.array_equal(a.d, b.d, equal_nan=True) and np.array_equal(a.q, b.q)


@pytest.mark.parametrize("noise, lo_m, hi_m", [
    ({"encoder_sigma_rad": 1e-4}, 2e-5, 2e-3),
    ({"hand_eye_error": {"xyz": [0.0, 0.0, 0.0005]}}, 3e-4, 7e-4),
    ({"kinematic_sigma_m": 2e-4}, 5e-5, 5e-3),
    ({"time_skew_s": 0.004}, 2e-5, 2e-3),
])
def test_robot_side_error_sources_move_the_points(s_mesh, s_index, noise, lo_m, hi_m):
    off = {k: False for k in ("gaussian", "linearity", "quantization", "incidence", "occlusion")}
    sc = scenario("s_surface", scan=SHORT, noise={**off, **noise})
    r = residuals_m(scan_scenario(sc, mesh=s_mesh), s_index)
    assert lo_m < np.sqrt(np.mean(r**2)) < hi_m


def test_unreachable_region_names_the_line():
    from twin.errors import TwinError

    sc = scenario("s_surface", workpiece={"true_pose": {"xyz": [1.2, 0.1, 0.0]},
                                          "nominal_pose": {"xyz": [1.2, 0.1, 0.0]}})
    with pytest.raises(TwinError, match=r"scan line \d+ is unreachable|is unreachable"):
        scan_scenario(sc)


def test_line_profiler_points_on_surface_noise_off(s_mesh, s_index):
    sc = scenario("s_surface", sensor={"kind": "line", "beams": 64, "fan_deg": 20.0},
                  scan={"max_lines": 1, "line_axis": "y", "region_m": [[-0.02, -0.03], [0.02, 0.03]]})
    sc = dataclasses.replace(sc, noise=sc.noise.all_off())
    scan = scan_scenario(sc, mesh=s_mesh)
    assert scan.d.shape[1] == 64
    assert scan.valid.sum() > 1000
    assert residuals_m(scan, s_index).max() < ON_SURFACE_M


def test_scan_files(tmp_path, noise_off_scan):
    from twin.io import read_points_ply, write_scan

    out = write_scan(noise_off_scan, tmp_path / "scan")
    table = pq.read_table(out / "samples.parquet")
    assert table.column_names[:9] == ["t", "q1", "q2", "q3", "q4", "q5", "q6", "d", "valid"]
    d = table.column("d").to_numpy(zero_copy_only=False)
    valid = table.column("valid").to_numpy(zero_copy_only=False)
    assert np.all(np.isnan(d[~valid])) and np.all(np.isfinite(d[valid]))
    pts = read_points_ply(out / "points.ply")
    assert np.array_equal(pts, noise_off_scan.valid_points_base)
    assert (out / "scan.json").is_file()
    assert VALID == 0
