"""Rerun recordings of the cell. The only module that imports rerun.

Entity paths mirror the frame tree: ``world/robot/<body>`` (geometry static, poses on the
``sim_time`` timeline), ``world/workpiece/true`` (and ``.../nominal``), ``world/scan/beam``,
``world/scan/points`` (each point appears at the time it is measured), ``plots/d_mm``.
Long runs are logged in columns (``rr.send_columns``); arm poses every ``pose_every`` samples.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import rerun as rr
import trimesh
from scipy.spatial.transform import Rotation

from twin.cell import Cell

POSE_EVERY = 10      # arm and beam logged every 10 ms (points and distances every 1 ms)
POINT_CHUNK = 100    # points grouped 100 ms per entity, so they stay visible once measured


def _geom_mesh(model: mujoco.MjModel, g: int) -> trimesh.Trimesh | None:
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
        mesh = _geom_mesh(model, g)
        if mesh is None:
            continue
        bname = model.body(body).name
        if bname == "workpiece":
            continue
        parent = "world/robot" if body != 0 else "world/cell"
        path = f"{parent}/{bname}/{name}" if body != 0 else f"{parent}/{name}"
        _log_mesh(path, mesh, model.geom_rgba[g])
    _log_pose_static("world/workpiece/true", cell.scenario.workpiece.T_world_workpiece_true)
    _log_mesh("world/workpiece/true/mesh", cell.mesh, (0.75, 0.6, 0.35))
    _log_pose_static("world/workpiece/nominal", cell.scenario.workpiece.T_world_workpiece_nominal)
    rr.log("world/workpiece/nominal/mesh", rr.LineStrips3D(
        _mesh_outline(cell.mesh), colors=[[120, 120, 120]], radii=0.0003), static=True)


def _mesh_outline(mesh: trimesh.Trimesh) -> list[np.ndarray]:
    edges = mesh.face_adjacency_edges[mesh.face_adjacency_angles > np.radians(30)]
    return [mesh.vertices[e] for e in edges]


def _log_pose_static(path: str, T: np.ndarray) -> None:
    rr.log(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)


def body_poses(cell: Cell, q: np.ndarray) -> dict[str, np.ndarray]:
    """World poses (K, 4, 4) of every arm body for joint samples q (K, 6)."""
    model, data = cell.model, cell.data
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


def log_scan(cell: Cell, scan, T_world_base: np.ndarray) -> None:
    """The arm moving, the beam, the points appearing and the distance, on ``sim_time``."""
    idx = np.arange(0, len(scan.t), POSE_EVERY)
    times = rr.TimeColumn("sim_time", duration=scan.t[idx])
    poses = body_poses(cell, scan.q_true[idx])
    for name, T in poses.items():
        rr.send_columns(f"world/robot/{name}", indexes=[times], columns=rr.Transform3D.columns(
            translation=T[:, :3, 3], mat3x3=T[:, :3, :3]))
    # Beam: from the emitter along +z to the hit (or the far end of the window).
    sensor_T = body_poses_site(cell, scan.q_true[idx])
    d = scan.d if scan.d.ndim == 1 else np.nanmean(scan.d, axis=1)
    length = np.where(np.isfinite(d[idx]), d[idx], cell.scenario.sensor.window_m[1])
    start = sensor_T[:, :3, 3]
    end = start + sensor_T[:, :3, 2] * length[:, None]
    strips = np.stack([start, end], axis=1)
    rr.send_columns("world/scan/beam", indexes=[times], columns=[
        *rr.LineStrips3D.columns(strips=strips).partition(np.ones(len(idx), dtype=int)),
    ])
    rr.log("world/scan/beam", rr.LineStrips3D.from_fields(colors=[[255, 40, 40]], radii=0.0004), static=True)
    # Points in the world frame, appearing as measured (chunks of POINT_CHUNK ms).
    pts = scan.points_base.reshape(len(scan.t), -1, 3)
    ok = scan.valid.reshape(len(scan.t), -1)
    R, p = T_world_base[:3, :3], T_world_base[:3, 3]
    for i0 in range(0, len(scan.t), POINT_CHUNK):
        sel = ok[i0:i0 + POINT_CHUNK]
        if not sel.any():
            continue
        chunk = pts[i0:i0 + POINT_CHUNK][sel] @ R.T + p
        rr.set_time("sim_time", duration=float(scan.t[i0]))
        rr.log(f"world/scan/points/{i0:08d}", rr.Points3D(chunk, radii=0.0003, colors=[[30, 200, 90]]))
    rr.send_columns("plots/d_mm", indexes=[rr.TimeColumn("sim_time", duration=scan.t)],
                    columns=rr.Scalars.columns(scalars=np.nan_to_num(d * 1e3, nan=np.nan)))


def body_poses_site(cell: Cell, q: np.ndarray) -> np.ndarray:
    model, data = cell.model, cell.data
    out = np.empty((len(q), 4, 4))
    for k, qk in enumerate(q):
        data.qpos[cell.qpos_adr] = qk
        mujoco.mj_kinematics(model, data)
        out[k] = np.eye(4)
        out[k, :3, :3] = data.site_xmat[cell.sensor_site].reshape(3, 3)
        out[k, :3, 3] = data.site_xpos[cell.sensor_site]
    return out


def save_scan_recording(path: str | Path, cell: Cell, scan, app_id: str = "scan_twin") -> Path:
    """Write a ``.rrd`` file with the cell, the moving arm, the beam, points and distances."""
    return save_run_recording(path, cell, scan, runs=[], app_id=app_id)


# --------------------------------------------------------------------------------------------
# Process paths: planned and replayed tool paths, tool frames, normals (twin run / twin demo)
# --------------------------------------------------------------------------------------------

FRAME_EVERY = 10      # one tool frame / normal arrow every 10 path points
FRAME_LENGTH_M = 0.004


def _world(T_world_base: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ T_world_base[:3, :3].T + T_world_base[:3, 3]


def log_path_lines(entity: str, lines: list, T_world_base: np.ndarray, color, radius: float = 0.0002) -> None:
    """Static polylines (each (n, 3) [m], base frame), e.g. the planned contact lines."""
    strips = [_world(T_world_base, np.asarray(l)) for l in lines if len(l) > 1]
    rr.log(entity, rr.LineStrips3D(strips, colors=[color], radii=radius), static=True)


def log_tool_frames(entity: str, T_base_tool: np.ndarray, T_world_base: np.ndarray, every: int = FRAME_EVERY,
                    length: float = FRAME_LENGTH_M) -> None:
    """Static x/y/z arrows (red/green/blue) of every ``every``-th tool frame."""
    T = T_world_base @ np.asarray(T_base_tool)[::every]
    origins = np.repeat(T[:, :3, 3], 3, axis=0)
    vectors = np.concatenate([T[:, :3, 0:1], T[:, :3, 1:2], T[:, :3, 2:3]], axis=2).transpose(0, 2, 1).reshape(-1, 3)
    colors = np.tile(np.array([[230, 40, 40], [40, 200, 40], [40, 80, 230]], dtype=np.uint8), (len(T), 1))
    rr.log(entity, rr.Arrows3D(origins=origins, vectors=vectors * length, colors=colors, radii=0.00015), static=True)


def log_normals(entity: str, points: np.ndarray, normals: np.ndarray, T_world_base: np.ndarray, color,
                every: int = FRAME_EVERY, length: float = FRAME_LENGTH_M) -> None:
    """Static normal arrows at every ``every``-th point (base frame in, world out)."""
    p = _world(T_world_base, np.asarray(points)[::every])
    n = np.asarray(normals)[::every] @ T_world_base[:3, :3].T
    rr.log(entity, rr.Arrows3D(origins=p, vectors=n * length, colors=[color], radii=0.0001), static=True)


def log_replay(cell: Cell, replay_log, t_offset: float, entity: str) -> None:
    """The arm replaying a trajectory on ``sim_time`` (from ``t_offset``) and the actual TCP path.

    ``entity``/actual: the TCP trail (static polyline, process samples), ``entity``/tcp: the
    moving TCP, ``plots/<name>/deviation_um``: the path deviation.
    """
    idx = np.arange(0, len(replay_log.t), POSE_EVERY)
    t = replay_log.t[idx] + t_offset
    times = rr.TimeColumn("sim_time", duration=t)
    poses = body_poses(cell, replay_log.q[idx])
    for name, T in poses.items():
        rr.send_columns(f"world/robot/{name}", indexes=[times], columns=rr.Transform3D.columns(
            translation=T[:, :3, 3], mat3x3=T[:, :3, :3]))
    tcp_w = _world(cell.T_world_base, replay_log.tcp_actual)
    strips = []
    proc = replay_log.process
    cuts = np.flatnonzero(np.diff(proc.astype(np.int8)) != 0) + 1
    for part in np.split(np.arange(len(proc)), cuts):
        if len(part) > 1 and proc[part[0]]:
            strips.append(tcp_w[part])
    rr.log(f"{entity}/actual", rr.LineStrips3D(strips, colors=[[255, 140, 0]], radii=0.00015), static=True)
    rr.send_columns(f"{entity}/tcp", indexes=[times], columns=rr.Points3D.columns(positions=tcp_w[idx]))
    rr.log(f"{entity}/tcp", rr.Points3D.from_fields(radii=0.001, colors=[[255, 140, 0]]), static=True)
    name = entity.rsplit("/", 1)[-1]
    dev = np.nan_to_num(replay_log.deviation_m * 1e6, nan=0.0)
    rr.send_columns(f"plots/{name}/deviation_um", indexes=[rr.TimeColumn("sim_time", duration=replay_log.t + t_offset)],
                    columns=rr.Scalars.columns(scalars=dev))


def save_run_recording(path: str | Path, cell: Cell, scan, runs: list, app_id: str = "scan_twin_run") -> Path:
    """Write a ``.rrd`` of ``twin run``: the scan, then each process path planned and replayed.

    Args:
        cell: the replay cell (arm, sensor and tool).
        scan: the Scan (logged from sim_time 0).
        runs: dicts with ``name``, ``path`` (ProcessPath, base frame), ``log`` (ReplayLog),
            ``t_offset`` [s], and optionally ``normals_points``/``normals`` ((N, 3) base frame).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(app_id)
    with rec:
        rec.save(str(path))
        rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        log_cell(cell)
        if scan is not None:
            log_scan(cell, scan, cell.T_world_base)
        for run in runs:
            ent = f"world/path/{run['name']}"
            p = run["path"]
            lines = [p.T_tool[a:b + 1, :3, 3] for a, b, kind, _ in p.segments if kind == "process"]
            log_path_lines(f"{ent}/planned", lines, cell.T_world_base, [60, 160, 255])
            log_tool_frames(f"{ent}/tool_frames", p.T_tool[p.process_mask()], cell.T_world_base)
            if run.get("normals") is not None:
                log_normals(f"{ent}/normals", run["normals_points"], run["normals"], cell.T_world_base,
                            [200, 60, 200])
            log_replay(cell, run["log"], run["t_offset"], ent)
        rec.flush()
    return path
