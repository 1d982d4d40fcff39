"""The scan cell: the UR5e scene, the laser sensor on the flange, the workpiece mesh, composed with MjSpec.

Two cells come from one scenario:

* the TRUE cell (``which="true"``): the workpiece at its true pose, the arm with any perturbed
  kinematic parameters and the sensor at the true hand-eye transform. Only the simulator and
  the evaluation look at it.
* the NOMINAL cell (``which="nominal"``): what the planner believes: workpiece at the nominal
  pose, published kinematics, believed hand-eye. Scan planning and IK use it.

Geom groups: 1 arm and sensor housing, 2 table/fixture, 3 workpiece. Ray casts (the laser)
hit the real mesh triangles; contacts use convex hulls (see ``models/ur5e/README.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from algorithms.geometry.se3 import inv_pose
from twin.errors import TwinError
from twin.robot import FLANGE_BODY, JOINT_NAMES, LINK_BODIES, SCENE_XML, UR5E_DH
from twin.scenario import Scenario

GROUP_ARM, GROUP_FIXTURE, GROUP_WORKPIECE = 1, 2, 3
# Geom groups the laser's occlusion check may hit: static fixture and workpiece.
STATIC_GROUPS = np.array([0, 0, 1, 1, 0, 0], dtype=np.uint8)
# Rangefinder data fields (bitfield of mjtRayDataField): dist | dir | origin | point | normal.
RAYDATA_ALL = 1 | 2 | 4 | 8 | 16
RAYDATA_LINE = 1 | 2 | 16  # dist, dir, normal per beam


def quat_wxyz(R: np.ndarray) -> np.ndarray:
    """MuJoCo quaternion (w, x, y, z) of a rotation matrix."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


@dataclass
class Cell:
    """A compiled cell: the one stateful object of the project (MjModel + MjData).

    Attributes:
        model, data: MuJoCo model and data.
        which: "true" or "nominal".
        mesh: the workpiece mesh in the workpiece frame [m].
        T_world_base: (4, 4) robot base in the world.
        T_world_workpiece: (4, 4) workpiece pose in THIS cell.
        T_flange_sensor: (4, 4) hand-eye transform in THIS cell.
    """

    model: mujoco.MjModel
    data: mujoco.MjData
    which: str
    scenario: Scenario
    mesh: trimesh.Trimesh
    T_world_base: np.ndarray
    T_world_workpiece: np.ndarray
    T_flange_sensor: np.ndarray

    @property
    def sensor_site(self) -> int:
        return self.model.site("laser").id

    @property
    def flange_site(self) -> int:
        return self.model.site("flange").id

    @property
    def sensor_body(self) -> int:
        return self.model.body("laser_sensor").id

    @property
    def workpiece_geom(self) -> int:
        return self.model.geom("workpiece").id

    @property
    def qpos_adr(self) -> np.ndarray:
        return np.array([self.model.joint(n).qposadr[0] for n in JOINT_NAMES])

    def set_q(self, q: np.ndarray) -> None:
        """Set the joint positions (rest) and update kinematics."""
        self.data.qpos[self.qpos_adr] = q
        self.data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def site_pose(self, site: int) -> np.ndarray:
        """(4, 4) world pose of a site at the current kinematics."""
        T = np.eye(4)
        T[:3, :3] = self.data.site_xmat[site].reshape(3, 3)
        T[:3, 3] = self.data.site_xpos[site]
        return T


def load_workpiece_mesh(scenario: Scenario) -> trimesh.Trimesh:
    """The scenario's workpiece mesh in the workpiece frame [m]."""
    from twin.parts import load_mesh, make_workpiece

    wp = scenario.workpiece
    if wp.shape is not None:
        return make_workpiece(wp.shape, **wp.params)
    return load_mesh(wp.mesh, wp.units)


def _body_rotation(body) -> np.ndarray:
    """Rotation of a spec body relative to its parent, whichever way the XML wrote it."""
    if body.alt.type == mujoco.mjtOrientation.mjORIENTATION_EULER:
        return Rotation.from_euler("XYZ", np.asarray(body.alt.euler)).as_matrix()
    w, x, y, z = np.asarray(body.quat, dtype=float)
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def build_spec(scenario: Scenario, which: str = "true", mesh: trimesh.Trimesh | None = None,
               rng: np.random.Generator | None = None) -> tuple[mujoco.MjSpec, dict]:
    """Compose the cell's MjSpec. Returns the spec and the poses it was built with."""
    if which not in ("true", "nominal"):
        raise TwinError(f"cell must be 'true' or 'nominal', got {which!r}")
    if mesh is None:
        mesh = load_workpiece_mesh(scenario)
    spec = mujoco.MjSpec.from_file(str(SCENE_XML))
    noise = scenario.noise
    true = which == "true"

    base = spec.body("base")
    base.pos = scenario.T_world_base[:3, 3]
    base.quat = quat_wxyz(scenario.T_world_base[:3, :3])

    if true and (noise.kinematic_sigma_m > 0 or noise.kinematic_sigma_rad > 0):
        rng = rng if rng is not None else np.random.default_rng(scenario.seed)
        for name in LINK_BODIES[1:]:
            body = spec.body(name)
            body.pos = np.asarray(body.pos) + rng.normal(0.0, noise.kinematic_sigma_m, 3)
            dR = Rotation.from_rotvec(rng.normal(0.0, noise.kinematic_sigma_rad, 3)).as_matrix()
            body.quat = quat_wxyz(_body_rotation(body) @ dR)
            body.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT

    # Laser sensor on the flange (DH frame 6 = flange site of the wrist_3 body).
    T_flange_sensor = scenario.sensor.T_flange_sensor
    if true:
        T_flange_sensor = T_flange_sensor @ noise.T_hand_eye_error
    T_wrist3_flange = np.eye(4)
    T_wrist3_flange[2, 3] = UR5E_DH.d[5]
    T_wrist3_sensor = T_wrist3_flange @ T_flange_sensor
    sensor = spec.body(FLANGE_BODY).add_body(
        name="laser_sensor", pos=T_wrist3_sensor[:3, 3], quat=quat_wxyz(T_wrist3_sensor[:3, :3]))
    sensor.add_geom(name="laser_housing", type=mujoco.mjtGeom.mjGEOM_BOX,
                    size=[0.015, 0.010, 0.025], pos=[scenario.sensor.baseline_m / 2, 0, -0.026],
                    rgba=[0.15, 0.3, 0.8, 1], group=GROUP_ARM, contype=1, conaffinity=0)
    sensor.add_site(name="laser", pos=[0, 0, 0], size=[0.002, 0, 0], rgba=[1, 0, 0, 1])
    sensor.add_site(name="receiver", pos=[scenario.sensor.baseline_m, 0, 0], size=[0.002, 0, 0])
    if scenario.sensor.kind == "line":
        _add_line_camera(sensor, scenario)

    # Workpiece mesh at this cell's pose.
    T_world_workpiece = scenario.workpiece.T_world_workpiece_true if true else \
        scenario.workpiece.T_world_workpiece_nominal
    spec.add_mesh(name="workpiece_mesh", uservert=np.asarray(mesh.vertices, dtype=np.float64).ravel(),
                  userface=np.asarray(mesh.faces, dtype=np.int32).ravel())
    wp = spec.worldbody.add_body(name="workpiece", pos=T_world_workpiece[:3, 3],
                                 quat=quat_wxyz(T_world_workpiece[:3, :3]))
    wp.add_geom(name="workpiece", type=mujoco.mjtGeom.mjGEOM_MESH, meshname="workpiece_mesh",
                rgba=[0.75, 0.6, 0.35, 1], group=GROUP_WORKPIECE, contype=0, conaffinity=1)

    # Sensors: encoder readings and the laser ray, evaluated in the same step (EtherCAT pairing).
    for name in JOINT_NAMES:
        spec.add_sensor(name=f"enc_{name}", type=mujoco.mjtSensor.mjSENS_JOINTPOS,
                        objtype=mujoco.mjtObj.mjOBJ_JOINT, objname=name)
    for axis, kind in (("x", mujoco.mjtSensor.mjSENS_FRAMEXAXIS), ("y", mujoco.mjtSensor.mjSENS_FRAMEYAXIS)):
        spec.add_sensor(name=f"laser_{axis}axis", type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="laser")
    if scenario.sensor.kind == "point":
        spec.add_sensor(name="laser_ray", type=mujoco.mjtSensor.mjSENS_RANGEFINDER,
                        objtype=mujoco.mjtObj.mjOBJ_SITE, objname="laser", intprm=[RAYDATA_ALL, 0, 0])
    else:
        spec.add_sensor(name="laser_ray", type=mujoco.mjtSensor.mjSENS_RANGEFINDER,
                        objtype=mujoco.mjtObj.mjOBJ_CAMERA, objname="laser_fan", intprm=[RAYDATA_LINE, 0, 0])
    poses = {"T_world_workpiece": T_world_workpiece, "T_flange_sensor": T_flange_sensor}
    return spec, poses


def _add_line_camera(sensor_body, scenario: Scenario) -> None:
    """A fan of beams in the sensor's x-z plane: a 1-pixel-high perspective camera looking along +z."""
    n = scenario.sensor.beams
    half = np.radians(scenario.sensor.fan_deg) / 2
    # An N x 1 image: the vertical field of view fovy makes the horizontal one
    # 2 atan(N tan(fovy / 2)), so choose fovy for the fan's full width.
    fovy_deg = float(np.degrees(2 * np.arctan(np.tan(half) / n)))
    # Cameras look along their -z: turn 180 deg about x so the camera's -z is the sensor's +z.
    sensor_body.add_camera(name="laser_fan", pos=[0, 0, 0], quat=[0, 1, 0, 0],
                           resolution=[n, 1], fovy=fovy_deg)


def build_cell(scenario: Scenario, which: str = "true", mesh: trimesh.Trimesh | None = None,
               rng: np.random.Generator | None = None) -> Cell:
    """Compile the true or nominal cell of a scenario."""
    if mesh is None:
        mesh = load_workpiece_mesh(scenario)
    spec, poses = build_spec(scenario, which, mesh, rng)
    return compile_cell(spec, scenario, which, mesh, poses)


def compile_cell(spec: mujoco.MjSpec, scenario: Scenario, which: str, mesh: trimesh.Trimesh,
                 poses: dict) -> Cell:
    try:
        model = spec.compile()
    except ValueError as exc:
        raise TwinError(f"MuJoCo could not compile the cell: {str(exc).splitlines()[0]}") from None
    data = mujoco.MjData(model)
    return Cell(model, data, which, scenario, mesh, scenario.T_world_base.copy(),
                poses["T_world_workpiece"], poses["T_flange_sensor"])


def T_base_world(cell: Cell) -> np.ndarray:
    return inv_pose(cell.T_world_base)
