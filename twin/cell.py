"""The scan cell: the UR5e scene, the laser sensor on the flange, the workpiece mesh, composed with MjSpec.

Two cells come from one scenario:

* the TRUE cell (``which="true"``): the workpiece at its true pose, the arm with any perturbed
  kinematic parameters and the sensor at the true hand-eye transform. Only the simulator and
  the evaluation look at it.
* the NOMINAL cell (``which="nominal"``): what the planner believes: workpiece at the nominal
  pose, published kinematics, believed hand-eye. Scan planning and IK use it.

Both are built from one :class:`twin.realize.Realized` scenario: its truth (drawn once) and its
mesh. Geom groups (``twin.robot``): 1 arm and what it carries, 2 table/fixture, 3 workpiece.
Ray casts (the laser) hit the real mesh triangles; contacts use convex hulls (see
``models/ur5e/README.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from algorithms.geometry.mesh_index import MeshIndex
from twin.errors import TwinError
from twin.realize import Realized
from twin.robot import FLANGE_BODY, GROUP_FIXTURE, GROUP_WORKPIECE, JOINT_NAMES, SCENE_XML, T_WRIST3_FLANGE
from twin.scenario import Scenario
from twin.sensors import RaySensor, make_sensor
from twin.sensors.touch_probe import TouchProbe

TOOL_BALL_SITE = "tool_ball"


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
        scenario: the scenario it was built from.
        mesh: the workpiece mesh in the workpiece frame [m].
        index: the realized workpiece's closest-point index of ``mesh`` (built once per run).
        sensor: the sensor on the flange.
        T_world_base: (4, 4) robot base in the world.
        T_world_workpiece: (4, 4) workpiece pose in THIS cell.
        T_flange_sensor: (4, 4) hand-eye transform in THIS cell.
    """

    model: mujoco.MjModel
    data: mujoco.MjData
    which: str
    scenario: Scenario
    mesh: trimesh.Trimesh
    index: MeshIndex
    sensor: RaySensor
    T_world_base: np.ndarray
    T_world_workpiece: np.ndarray
    T_flange_sensor: np.ndarray
    probe: TouchProbe | None = None

    @property
    def sensor_site(self) -> int:
        return self.model.site(self.sensor.site).id

    @property
    def flange_site(self) -> int:
        return self.model.site("flange").id

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


def true_cell_content(realized: Realized) -> tuple:
    """What the true cell is built from besides the scenario's tables: the truth's link errors,
    hand-eye transform and placement, as plain lists (a key for sharing one compiled true cell
    among realizations that draw the same truth)."""
    t = realized.truth
    errors = [(e.body, np.asarray(e.dpos_m).tolist(), np.asarray(e.dR).tolist()) for e in t.link_errors]
    return errors, np.asarray(t.T_flange_sensor).tolist(), np.asarray(t.T_world_workpiece).tolist()


def _body_rotation(body) -> np.ndarray:
    """Rotation of a spec body relative to its parent, whichever way the XML wrote it."""
    if body.alt.type == mujoco.mjtOrientation.mjORIENTATION_EULER:
        return Rotation.from_euler("XYZ", np.asarray(body.alt.euler)).as_matrix()
    w, x, y, z = np.asarray(body.quat, dtype=float)
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def build_spec(realized: Realized, which: str = "true") -> tuple[mujoco.MjSpec, dict]:
    """Compose the cell's MjSpec. Returns the spec and the poses it was built with."""
    if which not in ("true", "nominal"):
        raise TwinError(f"cell must be 'true' or 'nominal', got {which!r}")
    scenario = realized.scenario
    spec = mujoco.MjSpec.from_file(str(SCENE_XML))
    true = which == "true"

    base = spec.body("base")
    base.pos = scenario.T_world_base[:3, 3]
    base.quat = quat_wxyz(scenario.T_world_base[:3, :3])

    if true:
        for err in realized.truth.link_errors:
            body = spec.body(err.body)
            body.pos = np.asarray(body.pos) + err.dpos_m
            body.quat = quat_wxyz(_body_rotation(body) @ err.dR)
            body.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT

    # The sensor on the flange (DH frame 6 = flange site of the wrist_3 body).
    T_flange_sensor = realized.truth.T_flange_sensor if true else scenario.sensor.T_flange_sensor
    T_wrist3_sensor = T_WRIST3_FLANGE @ T_flange_sensor
    sensor = make_sensor(realized.sensor, scenario.noise)
    body = spec.body(FLANGE_BODY).add_body(
        name="laser_sensor", pos=T_wrist3_sensor[:3, 3], quat=quat_wxyz(T_wrist3_sensor[:3, :3]))
    sensor.attach(spec, body)
    # The process tool's ball centre, with the tool's axes: the point the five-axis IK holds
    # while the tool spins freely about its axis (the tool itself is added for replays only).
    p = scenario.path
    T_wrist3_tool = T_WRIST3_FLANGE @ p.T_flange_tool
    spec.body(FLANGE_BODY).add_site(name=TOOL_BALL_SITE,
                                    pos=T_wrist3_tool[:3, 3] + p.tip_radius_m * T_wrist3_tool[:3, 2],
                                    quat=quat_wxyz(T_wrist3_tool[:3, :3]), size=[0.001, 0, 0])

    probe = None
    if scenario.probe is not None:
        probe = TouchProbe(scenario.probe, scenario.noise)
        T_wrist3_probe = T_WRIST3_FLANGE @ scenario.probe.T_flange_probe
        probe.attach(spec, spec.body(FLANGE_BODY).add_body(
            name="touch_probe", pos=T_wrist3_probe[:3, 3], quat=quat_wxyz(T_wrist3_probe[:3, :3])))
        _add_reference_sphere(spec, scenario.probe.sphere_xyz_m, scenario.probe.sphere_radius_m)

    # Workpiece mesh at this cell's pose.
    mesh = realized.workpiece.mesh
    T_world_workpiece = realized.truth.T_world_workpiece if true else scenario.workpiece.T_world_workpiece_nominal
    add_workpiece(spec, mesh, T_world_workpiece, GROUP_WORKPIECE, conaffinity=1)

    # Encoder readings, evaluated in the same step as the sensor (EtherCAT pairing).
    for name in JOINT_NAMES:
        spec.add_sensor(name=f"enc_{name}", type=mujoco.mjtSensor.mjSENS_JOINTPOS,
                        objtype=mujoco.mjtObj.mjOBJ_JOINT, objname=name)
    poses = {"T_world_workpiece": T_world_workpiece, "T_flange_sensor": T_flange_sensor, "sensor": sensor,
             "probe": probe}
    return spec, poses


def add_workpiece(spec: mujoco.MjSpec, mesh: trimesh.Trimesh, T_world_workpiece: np.ndarray, group: int,
                  conaffinity: int) -> None:
    """The workpiece mesh (workpiece frame [m]) as the ``workpiece`` body and geom at
    ``T_world_workpiece``: the one way every machine's model (arm cell or CMM) takes the part.
    Rays see its real triangles; ``conaffinity`` 1 lets the arm's collision geoms meet it."""
    spec.add_mesh(name="workpiece_mesh", uservert=np.asarray(mesh.vertices, dtype=np.float64).ravel(),
                  userface=np.asarray(mesh.faces, dtype=np.int32).ravel())
    wp = spec.worldbody.add_body(name="workpiece", pos=T_world_workpiece[:3, 3],
                                 quat=quat_wxyz(T_world_workpiece[:3, :3]))
    wp.add_geom(name="workpiece", type=mujoco.mjtGeom.mjGEOM_MESH, meshname="workpiece_mesh",
                rgba=[0.75, 0.6, 0.35, 1], group=group, contype=0, conaffinity=conaffinity)


REFERENCE_SPHERE_STEM_RADIUS_M = 0.004


def _add_reference_sphere(spec: mujoco.MjSpec, centre_world: np.ndarray, radius_m: float) -> None:
    """The probe's qualification sphere on a vertical stem standing on the table (a fixture:
    geom ``reference_sphere``, group 2)."""
    centre = np.asarray(centre_world, dtype=np.float64)
    if centre[2] <= radius_m:
        raise TwinError(f"probe.sphere_xyz_m: the reference sphere's centre must stand higher than its radius "
                        f"above the table (z > {radius_m:g} m), got z = {centre[2]:g} m")
    stem = centre[2] - radius_m / 2
    fixture = spec.worldbody.add_body(name="reference_sphere", pos=centre)
    fixture.add_geom(name="reference_sphere", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius_m, 0, 0],
                     rgba=[0.85, 0.85, 0.9, 1], group=GROUP_FIXTURE)
    fixture.add_geom(name="reference_sphere_stem", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                     size=[REFERENCE_SPHERE_STEM_RADIUS_M, stem / 2, 0], pos=[0, 0, -radius_m / 2 - stem / 2],
                     rgba=[0.5, 0.5, 0.55, 1], group=GROUP_FIXTURE)


def build_cell(realized: Realized, which: str = "true") -> Cell:
    """Compile the true or nominal cell of a realized scenario."""
    spec, poses = build_spec(realized, which)
    return compile_cell(spec, realized, which, poses)


def compile_cell(spec: mujoco.MjSpec, realized: Realized, which: str, poses: dict) -> Cell:
    try:
        model = spec.compile()
    except ValueError as exc:
        raise TwinError(f"MuJoCo could not compile the cell: {str(exc).splitlines()[0]}") from None
    data = mujoco.MjData(model)
    scenario = realized.scenario
    return Cell(model, data, which, scenario, realized.workpiece.mesh, realized.workpiece.index, poses["sensor"],
                scenario.T_world_base.copy(), poses["T_world_workpiece"], poses["T_flange_sensor"],
                poses.get("probe"))
