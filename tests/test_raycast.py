"""Bulk rays (twin/sensors/raycast.py): the line profiler's beams are what MuJoCo's camera
rangefinder returns, and the receiver rays what MuJoCo's mj_ray returns, whatever is hit."""

import mujoco
import mujoco.batch
import numpy as np
import pytest

from algorithms.geometry.se3 import transform_points
from tests.helpers import scenario
from tests.tolerances import ANALYTIC_DISTANCE_M
from twin.cell import build_spec, compile_cell
from twin.ik import IKSolver
from twin.plan import plan_scan
from twin.realize import realize
from twin.robot import GROUP_ARM, GROUP_FIXTURE, HOME_Q, STATIC_GROUPS
from twin.scan import IK_ORIENTATION_TOL_RAD, IK_POSITION_TOL_M, solve_joint_references
from twin.sensors.raycast import CellRays

BEAMS = 1024
FAN_DEG = 20.0
RAYDATA = 1 | 2 | 16   # dist, dir, normal per pixel
# A ray through an edge shared by two faces may take either face's normal (same distance).
NORMAL_TIES = 1e-3


def _line_cell(with_obstacles: bool):
    """The S-surface cell with the line profiler, MuJoCo's camera rangefinder over the same
    fan on the sensor's body, and (optionally) three things in the fan: a box on a moving
    body, a static sphere and an invisible (alpha 0) static box."""
    sc = scenario("s_surface", sensor={"kind": "line", "beams": BEAMS, "fan_deg": FAN_DEG},
                  scan={"max_lines": 1, "line_axis": "y", "region_m": [[-0.02, -0.035], [0.02, 0.035]]})
    realized = realize(sc)
    nominal_spec, nominal_poses = build_spec(realized, "nominal")
    nominal = compile_cell(nominal_spec, realized, "nominal", nominal_poses)
    plan = plan_scan(nominal)
    q_ref, _ = solve_joint_references(nominal, plan)
    spec, poses = build_spec(realized, "true")
    body = spec.site("laser").parent
    half = np.radians(FAN_DEG) / 2
    fovy = float(np.degrees(2 * np.arctan(np.tan(half) / BEAMS)))
    body.add_camera(name="fan_camera", pos=[0, 0, 0], quat=[0, 1, 0, 0], resolution=[BEAMS, 1], fovy=fovy)
    spec.add_sensor(name="fan_rays", type=mujoco.mjtSensor.mjSENS_RANGEFINDER, objtype=mujoco.mjtObj.mjOBJ_CAMERA,
                    objname="fan_camera", intprm=[RAYDATA, 0, 0])
    mid = len(q_ref) // 2
    if with_obstacles:
        T = plan.T_world_sensor[mid]
        x, z = T[:3, 0], T[:3, 2]
        at = T[:3, 3] + 0.03 * z
        mover = spec.worldbody.add_body(name="mover", pos=at + 0.006 * x)
        mover.add_joint(name="mover_slide", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, 0, 1])
        mover.add_geom(name="mover_box", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.004, 0.004, 0.002],
                       group=GROUP_ARM, contype=0, conaffinity=0, rgba=[1, 0, 0, 1])
        spec.worldbody.add_geom(name="still_sphere", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.003, 0, 0],
                                pos=at - 0.006 * x, group=GROUP_FIXTURE, contype=0, conaffinity=0)
        spec.worldbody.add_geom(name="ghost_box", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.02, 0.02, 0.001],
                                pos=T[:3, 3] + 0.02 * z, group=GROUP_FIXTURE, rgba=[1, 1, 1, 0],
                                contype=0, conaffinity=0)
    cell = compile_cell(spec, realized, "true", poses)
    # 64 steps along the scan, one over the part's edge (half the fan on the table), and last
    # the one the obstacles were placed at
    return cell, np.vstack([q_ref[::max(1, len(q_ref) // 64)], _over_the_edge(nominal), q_ref[mid]])


def _over_the_edge(cell) -> np.ndarray:
    """Joints putting the sensor 65 mm above the part's +x edge (as the cell has it), beam
    down, fan along x."""
    corners = transform_points(cell.T_world_workpiece, cell.mesh.bounds)
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [corners[:, 0].max(), corners[:, 1].mean(), corners[:, 2].max() + 0.065]
    ik = IKSolver(cell.model, "laser", IK_POSITION_TOL_M, IK_ORIENTATION_TOL_RAD)
    ik.set_q(HOME_Q)
    pe, oe, _ = ik.solve(T, 0.05, 500, velocity_limited=False)
    assert pe < 1e-6 and oe < 1e-5
    return ik.q


def _camera_rays(cell, q):
    """MuJoCo's camera rangefinder at each joint vector: dist (K, B), normal (K, B, 3) and the
    sensordata rows."""
    adr = cell.model.sensor("fan_rays").adr[0]
    dist, normal, rows = [], [], []
    for qk in q:
        cell.set_q(qk)
        r = cell.data.sensordata[adr:adr + BEAMS * 7].reshape(BEAMS, 7)
        dist.append(r[:, 0].copy())
        normal.append(r[:, 4:7].copy())
        rows.append(cell.data.sensordata.copy())
    return np.array(dist), np.array(normal), np.array(rows)


@pytest.mark.parametrize("with_obstacles", [False, True])
def test_beams_are_the_camera_rangefinders(with_obstacles):
    cell, q = _line_cell(with_obstacles)
    dist, normal, rows = _camera_rays(cell, q)
    rays = cell.sensor.decode(cell.model, rows, q)
    assert np.array_equal(rays.dist >= 0, dist >= 0)
    hit = dist >= 0
    assert hit.mean() > 0.5
    # the table (a plane, MuJoCo's half) is hit over the edge
    spot_z = (rays.origin + rays.dist[..., None] * rays.direction)[-2, :, 2]
    table_z = cell.data.geom_xpos[cell.model.geom("table").id][2]
    assert np.sum(hit[-2] & (np.abs(spot_z - table_z) < ANALYTIC_DISTANCE_M)) > BEAMS // 10
    assert np.max(np.abs(rays.dist[hit] - dist[hit])) < ANALYTIC_DISTANCE_M
    mismatch = np.any(np.abs(rays.normal[hit] - normal[hit]) > 1e-9, axis=1)
    assert mismatch.mean() <= NORMAL_TIES
    if with_obstacles:
        # at the last step the moving box (+x half of the fan) and the static sphere (-x half)
        # are hit 30 mm out, by MuJoCo's half; the invisible box 20 mm out is not
        x = cell.sensor.beam_dirs_sensor()[:, 0]
        near = (rays.dist[-1] > 0.025) & (rays.dist[-1] < 0.035)
        assert np.any(near & (x > 0)) and np.any(near & (x < 0))
        assert not np.any((rays.dist[-1] >= 0) & (rays.dist[-1] < 0.025))


def test_receiver_rays_are_mujocos():
    cell, _ = _line_cell(with_obstacles=True)
    rng = np.random.default_rng(7)
    wp = cell.data.geom_xpos[cell.workpiece_geom]
    m = 20_000
    start = wp + rng.uniform([-0.06, -0.06, -0.01], [0.06, 0.06, 0.06], (m, 3))
    unit = rng.standard_normal((m, 3))
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    length = rng.uniform(0.001, 0.2, m)
    cast = CellRays(cell.model, cell.qpos_adr)
    blocked = cast.blocked(start, unit, length, STATIC_GROUPS)
    batch = mujoco.batch.Batch(cell.model, 1)
    d, _ = batch.ray(start[None], unit[None], geomgroup=STATIC_GROUPS, flg_static=True)
    d = d[0]
    expected = (d >= 0) & (d < length)
    decided = np.abs(d - length) > ANALYTIC_DISTANCE_M
    assert 0.1 < expected.mean() < 0.9
    assert np.array_equal(blocked[decided], expected[decided])


def test_receiver_rays_refuse_groups_with_moving_geoms():
    cell, _ = _line_cell(with_obstacles=False)
    cast = CellRays(cell.model, cell.qpos_adr)
    with pytest.raises(ValueError, match="moving geoms"):
        cast.blocked(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), np.ones(1), np.array([0, 1, 0, 0, 0, 0]))


def test_the_cells_own_model_is_untouched():
    cell, _ = _line_cell(with_obstacles=False)
    before = cell.model.geom_group.copy()
    cast = CellRays(cell.model, cell.qpos_adr)
    assert np.array_equal(cell.model.geom_group, before)
    assert cast.model.geom_group[cell.workpiece_geom] != before[cell.workpiece_geom]
