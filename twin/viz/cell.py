"""Static geometry of the cell and the arm's body poses."""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
import rerun as rr
import trimesh
from scipy.spatial.transform import Rotation

from twin.cell import Cell
from twin.viz.columns import send_poses


def geom_mesh(model: mujoco.MjModel, g: int) -> trimesh.Trimesh | None:
    t = model.geom_type[g]
    size = model.geom_size[g]
    if t == mujoco.mjtGeom.mjGEOM_BOX:
        m = trimesh.creation.box(2 * size)
    elif t == mujoco.mjtGeom.mjGEOM_CAPSULE:
        m = trimesh.creation.capsule(height=2 * size[1], radius=size[0], count=[16, 8])
    elif t == mujoco.mjtGeom.mjGEOM_CYLINDER:
        m = trimesh.creation.cylinder(radius=size[0], height=2 * size[1], sections=24)
    elif t == mujoco.mjtGeom.mjGEOM_SPHERE:
        m = trimesh.creation.icosphere(2, radius=size[0])
    elif t == mujoco.mjtGeom.mjGEOM_PLANE:
        m = trimesh.creation.box([2 * size[0], 2 * size[1], 1e-3])
    elif t == mujoco.mjtGeom.mjGEOM_MESH:
        mid = model.geom_dataid[g]
        va, vn = model.mesh_vertadr[mid], model.mesh_vertnum[mid]
        fa, fn = model.mesh_faceadr[mid], model.mesh_facenum[mid]
        m = trimesh.Trimesh(model.mesh_vert[va:va + vn], model.mesh_face[fa:fa + fn], process=False)
    else:
        return None
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(np.roll(model.geom_quat[g], -1)).as_matrix()
    T[:3, 3] = model.geom_pos[g]
    m.apply_transform(T)
    return m


def _log_mesh(path: str, mesh: trimesh.Trimesh, rgba) -> None:
    color = (np.asarray(rgba[:3]) * 255).astype(np.uint8)
    rr.log(path, rr.Mesh3D(vertex_positions=mesh.vertices, triangle_indices=mesh.faces,
                           vertex_normals=mesh.vertex_normals, albedo_factor=color), static=True)


def log_cell(cell: Cell) -> None:
    """Static geometry: every body's geoms under ``world/robot/<body>`` and the workpiece."""
    model = cell.model
    for g in range(model.ngeom):
        body = model.geom_bodyid[g]
        name = model.geom(g).name or f"geom{g}"
        mesh = geom_mesh(model, g)
        if mesh is None:
            continue
        bname = model.body(body).name
        if bname == "workpiece":
            continue
        path = f"{body_entity(model, body)}/{name}" if body != 0 else f"world/cell/{name}"
        _log_mesh(path, mesh, model.geom_rgba[g])
    log_fixed_bodies(cell)
    _log_pose_static("world/workpiece/true", cell.T_world_workpiece)
    _log_mesh("world/workpiece/true/mesh", cell.mesh, (0.75, 0.6, 0.35))
    _log_pose_static("world/workpiece/nominal", cell.scenario.workpiece.T_world_workpiece_nominal)
    rr.log("world/workpiece/nominal/mesh", rr.LineStrips3D(
        mesh_outline(cell.mesh), colors=[[120, 120, 120]], radii=0.0003), static=True)


def mesh_outline(mesh: trimesh.Trimesh) -> list[np.ndarray]:
    edges = mesh.face_adjacency_edges[mesh.face_adjacency_angles > np.radians(30)]
    return [mesh.vertices[e] for e in edges]


def _log_pose_static(path: str, T: np.ndarray) -> None:
    rr.log(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)


def _rides_on_parent(model: mujoco.MjModel, b: int) -> bool:
    """A body without joints on a moving parent: it moves with the parent, rigidly."""
    return bool(model.body_jntnum[b] == 0 and model.body_parentid[b] != 0 and model.body_weldid[b] != 0)


def body_entity(model: mujoco.MjModel, b: int) -> str:
    """The entity of an arm body: ``world/robot/<body>`` for a body that moves on its own joint or
    is welded to the world; under its parent's entity for one that rides rigidly on its parent
    (a sensor, a tool: a static transform, so its pose is not logged again at every step)."""
    if _rides_on_parent(model, b):
        return f"{body_entity(model, int(model.body_parentid[b]))}/{model.body(b).name}"
    return f"world/robot/{model.body(b).name}"


def moving_bodies(model: mujoco.MjModel) -> list[str]:
    """The arm's bodies whose world poses are logged as they move: those on their own joint."""
    return [model.body(b).name for b in range(1, model.nbody)
            if model.body(b).name != "workpiece" and model.body_weldid[b] != 0 and not _rides_on_parent(model, b)]


def log_fixed_bodies(cell: Cell) -> None:
    """Static poses: the bodies welded to the world (the arm's base) in the world, the bodies
    riding on a parent relative to it."""
    model, data = cell.model, cell.data
    mujoco.mj_kinematics(model, data)
    for b in range(1, model.nbody):
        if model.body(b).name == "workpiece":
            continue
        if model.body_weldid[b] == 0:
            rr.log(body_entity(model, b), rr.Transform3D(translation=data.xpos[b], mat3x3=data.xmat[b].reshape(3, 3)),
                   static=True)
        elif _rides_on_parent(model, b):
            rr.log(body_entity(model, b), rr.Transform3D(translation=model.body_pos[b],
                                                         quaternion=np.roll(model.body_quat[b], -1)), static=True)


def send_arm(cell: Cell, t_s: np.ndarray, q: np.ndarray) -> None:
    """The moving bodies' poses for joint samples q (K, 6) at times ``t_s`` [s] on ``sim_time``."""
    for name, T in body_poses(cell, q, moving_bodies(cell.model)).items():
        send_poses(f"world/robot/{name}", t_s, T)


def body_poses(cell: Cell, q: np.ndarray, names: list[str] | None = None) -> dict[str, np.ndarray]:
    """World poses (K, 4, 4) of the arm's bodies (default: all) for joint samples q (K, 6)."""
    model, data = cell.model, cell.data
    if names is None:
        names = [model.body(b).name for b in range(1, model.nbody) if model.body(b).name != "workpiece"]
    out = {n: np.empty((len(q), 4, 4)) for n in names}
    for k, qk in enumerate(q):
        data.qpos[cell.qpos_adr] = qk
        mujoco.mj_kinematics(model, data)
        for n in names:
            b = model.body(n).id
            T = out[n][k]
            T[:3, :3] = data.xmat[b].reshape(3, 3)
            T[:3, 3] = data.xpos[b]
            T[3] = [0, 0, 0, 1]
    return out


def sensor_poses(cell: Cell, q: np.ndarray) -> np.ndarray:
    model, data = cell.model, cell.data
    out = np.empty((len(q), 4, 4))
    for k, qk in enumerate(q):
        data.qpos[cell.qpos_adr] = qk
        mujoco.mj_kinematics(model, data)
        out[k] = np.eye(4)
        out[k, :3, :3] = data.site_xmat[cell.sensor_site].reshape(3, 3)
        out[k, :3, 3] = data.site_xpos[cell.sensor_site]
    return out


def log_pose_with_outline(entity: str, T_world: np.ndarray, mesh: trimesh.Trimesh, colour: Sequence[int]) -> None:
    """A pose of the part (static): its frame, its sharp-edge outline, and the matrix in full
    precision (``pose_matrix``: 16 float64, row-major; the transform itself is stored in float32)."""
    T = np.asarray(T_world, dtype=np.float64)
    rr.log(entity, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
    rr.log(entity, rr.AnyValues(pose_matrix=T.ravel()), static=True)
    rr.log(f"{entity}/mesh", rr.LineStrips3D(mesh_outline(mesh), colors=[colour], radii=0.0003), static=True)
