"""Replay a joint trajectory in the TRUE cell at 1 ms and verify it (document 004, fig. 12).

The replay cell is the scenario's true cell (same kinematic perturbations as the scan) with:

* the process tool on the flange (``[path]``): a holder cylinder, a shank cylinder and a
  ball end whose lowest point on the tool axis is the TCP (site ``tcp``);
* the workpiece's collision shape replaced by a MuJoCo height field sampled from the exact
  mesh by vertical ray casts every ``HFIELD_RES_M`` (MuJoCo collides a mesh as its convex
  hull, which stands well above the concave valleys the tool works in, so every tool pose
  there would "collide"). The height field collides as prisms under the linearly
  interpolated samples: for parts that are height fields over their footprint (the
  S-surface, the punches) it is exact up to the interpolation error of the samples; holes
  and undercuts are filled (conservative: a contact may be reported where the real part has
  a cavity). The exact mesh stays in the model for rays and display, without collisions.

Contacts. The process is a contact process: the ball end is meant to touch the part along
the process lines. The ball geom therefore takes no part in MuJoCo's collisions (a process
force model is outside the twin), and its contact is measured exactly instead: the signed
distance of the ball to the exact true mesh at every sample, whose value on the process
lines is the surface error the process would leave, and whose minimum in the air is the
tool's clearance (below zero: an unintended tip contact). Every other geom of the robot
(links, sensor housing, tool holder and shank) collides with the part's height field and the
table through MuJoCo's contact pipeline; contact sensors (one per geom and target, nearest
contact) record them, and any such contact is unintended. The robot base, fixed on the table
by design, is not checked.

The servos are the cell's position/velocity actuators with gravity compensation; the replay
uses :func:`twin.sim.simulate` (``mujoco.rollout`` in chunks).
"""

from __future__ import annotations

import time
import weakref
from dataclasses import dataclass, field

import mujoco
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from algorithms.geometry.kinematics import dh_forward
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.raycast import raycast_parallel
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.paths.timing import Trajectory
from algorithms.paths.toolpath import ProcessPath
from twin.cell import Cell, build_spec, compile_cell, quat_wxyz
from twin.errors import TwinError
from twin.realize import Realized
from twin.robot import (
    FLANGE_BODY,
    GROUP_ARM,
    GROUP_WORKPIECE,
    JOINT_NAMES,
    T_WRIST3_FLANGE,
    UR5E_DH,
    VELOCITY_LIMIT_RAD_S,
)
from twin.scenario import Scenario
from twin.sim import simulate

HFIELD_RES_M = 0.001
JOINT_LIMIT_MARGIN_RAD = 1e-3
CONTACT_TARGETS = ("workpiece_collision", "table")
# Contact sensor: data = found | dist | pos; reduce = mindist; one slot.
_CONTACT_DATA = 1 | 8 | 16
_REDUCE_MINDIST = 1


def _add_tool(spec: mujoco.MjSpec, scenario: Scenario) -> None:
    p = scenario.path
    T_ft = p.T_flange_tool
    tool = spec.body(FLANGE_BODY).add_body(name="tool", pos=T_WRIST3_FLANGE[:3, 3], gravcomp=1)
    tip = T_ft[:3, 3]
    centre = tip + p.tip_radius_m * T_ft[:3, 2]
    axis = centre / max(float(np.linalg.norm(centre)), 1e-12)
    holder_end = axis * min(p.holder_length_m, 0.8 * float(np.linalg.norm(centre)))
    common = dict(contype=1, conaffinity=0, group=GROUP_ARM)
    if p.holder_radius_m > 0 and np.linalg.norm(holder_end) > 0:
        tool.add_geom(name="tool_holder", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                      fromto=np.concatenate([np.zeros(3), holder_end]), size=[p.holder_radius_m, 0, 0],
                      rgba=[0.3, 0.3, 0.35, 1], mass=0.5, **common)
    if p.shank_radius_m > 0:
        tool.add_geom(name="tool_shank", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                      fromto=np.concatenate([holder_end, centre]), size=[p.shank_radius_m, 0, 0],
                      rgba=[0.8, 0.8, 0.8, 1], mass=0.05, **common)
    if p.tip_radius_m > 0:
        tool.add_geom(name="tool_tip", type=mujoco.mjtGeom.mjGEOM_SPHERE, pos=centre, size=[p.tip_radius_m, 0, 0],
                      rgba=[0.9, 0.2, 0.2, 1], mass=0.01, contype=0, conaffinity=0, group=GROUP_ARM)
    tool.add_site(name="tcp", pos=tip, quat=quat_wxyz(T_ft[:3, :3]), size=[0.001, 0, 0])


@dataclass(frozen=True)
class HeightField:
    """The part's collision shape: its top surface sampled every ``HFIELD_RES_M`` seen from
    above (heights [m] above the part's lowest point, rows along y), in the workpiece frame."""

    x_m: np.ndarray
    y_m: np.ndarray
    heights_m: np.ndarray
    z0_m: float


#: Height fields made so far, per mesh (with the mesh's hash: a mesh changed since is cast again).
_HEIGHT_FIELDS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def height_field(mesh: trimesh.Trimesh) -> HeightField:
    """Cast vertical rays over the part's footprint (one sample beyond it on every side, so the
    walls drop to the table). The field is in the part's own frame, so it is cast once per
    mesh (a new episode or trial of the same part reuses it)."""
    key = hash(mesh)
    kept = _HEIGHT_FIELDS.get(mesh)
    if kept is None or kept[0] != key:
        kept = (key, _cast_height_field(mesh))
        _HEIGHT_FIELDS[mesh] = kept
    return kept[1]


def _cast_height_field(mesh: trimesh.Trimesh) -> HeightField:
    lo, hi = mesh.bounds
    res = HFIELD_RES_M
    nx = int(np.ceil((hi[0] - lo[0]) / res)) + 3
    ny = int(np.ceil((hi[1] - lo[1]) / res)) + 3
    xs = lo[0] - res + np.arange(nx) * res
    ys = lo[1] - res + np.arange(ny) * res
    X, Y = np.meshgrid(xs, ys)  # row = y, column = x (MuJoCo's hfield layout)
    origins = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, hi[2] + 0.01)])
    hit, P, _ = raycast_parallel(mesh.vertices, mesh.faces, origins, [0.0, 0.0, -1.0])
    z0 = float(lo[2])
    return HeightField(xs, ys, np.where(hit, P[:, 2], z0).reshape(X.shape) - z0, z0)


def _add_height_field(spec: mujoco.MjSpec, field: HeightField) -> None:
    xs, ys, Z = field.x_m, field.y_m, field.heights_m
    top = float(max(Z.max(), 1e-6))
    spec.add_hfield(name="workpiece_hfield", size=[(xs[-1] - xs[0]) / 2, (ys[-1] - ys[0]) / 2, top, 0.005],
                    nrow=len(ys), ncol=len(xs), userdata=(Z / top).ravel().tolist())
    wp = spec.body("workpiece")
    wp.add_geom(name="workpiece_collision", type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname="workpiece_hfield",
                pos=[(xs[0] + xs[-1]) / 2, (ys[0] + ys[-1]) / 2, field.z0_m], contype=0, conaffinity=1,
                group=GROUP_WORKPIECE, rgba=[0.75, 0.6, 0.35, 0.0])
    g = spec.geom("workpiece")
    g.contype = 0
    g.conaffinity = 0


def build_replay_cell(realized: Realized) -> Cell:
    """The true cell (the same truth as the scan's) with the tool, the height-field collision
    shape and the replay sensors: the process configuration of the true cell."""
    scenario = realized.scenario
    spec, poses = build_spec(realized, "true")
    _add_tool(spec, scenario)
    spec.add_sensor(name="tcp_pos", type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=mujoco.mjtObj.mjOBJ_SITE,
                    objname="tcp")
    spec.add_sensor(name="tcp_zaxis", type=mujoco.mjtSensor.mjSENS_FRAMEZAXIS, objtype=mujoco.mjtObj.mjOBJ_SITE,
                    objname="tcp")
    for j in JOINT_NAMES:
        spec.add_sensor(name=f"vel_{j}", type=mujoco.mjtSensor.mjSENS_JOINTVEL, objtype=mujoco.mjtObj.mjOBJ_JOINT,
                        objname=j)
    add_collision_checks(spec, realized.workpiece.mesh)
    return compile_cell(spec, realized, "true", poses)


def add_collision_checks(spec: mujoco.MjSpec, mesh: trimesh.Trimesh, hfield: HeightField | None = None) -> None:
    """The part's height-field collision shape (``hfield``, or :func:`height_field` of ``mesh``)
    and a contact sensor for every colliding robot geom against it and the table (named
    ``contact:GEOM:TARGET``; :func:`contact_records`)."""
    _add_height_field(spec, height_field(mesh) if hfield is None else hfield)
    for g in _checked_geoms(spec):
        for target in CONTACT_TARGETS:
            spec.add_sensor(name=f"contact:{g}:{target}", type=mujoco.mjtSensor.mjSENS_CONTACT,
                            objtype=mujoco.mjtObj.mjOBJ_GEOM, objname=g,
                            reftype=mujoco.mjtObj.mjOBJ_GEOM, refname=target,
                            intprm=[_CONTACT_DATA, _REDUCE_MINDIST, 1])


def contact_columns(model: mujoco.MjModel) -> tuple[list[str], np.ndarray]:
    """The contact sensors' names and their ``sensordata`` columns (5 per sensor)."""
    names, cols = [], []
    for i in range(model.nsensor):
        s = model.sensor(i)
        if s.name.startswith("contact:"):
            names.append(s.name)
            cols.append(np.arange(int(s.adr[0]), int(s.adr[0] + s.dim[0])))
    return names, (np.concatenate(cols) if cols else np.zeros(0, dtype=np.int64))


def contact_records(names: list[str], cdata: np.ndarray, t: np.ndarray, T_base_world: np.ndarray) -> list:
    """One :class:`ContactRecord` per contact sensor that found a contact (all unintended).

    Args:
        names: the contact sensors' names; cdata: (n, len(names), 5) their readings per step;
        t: (n,) step times [s]; T_base_world: maps world positions into the robot base frame.
    """
    out = []
    for k, nm in enumerate(names):
        found = cdata[:, k, 0] > 0
        if not found.any():
            continue
        _, geom, other = nm.split(":")
        idx = np.flatnonzero(found)
        j = idx[np.argmin(cdata[idx, k, 1])]
        where = transform_points(T_base_world, cdata[j, k, 2:5][None])[0]
        out.append(ContactRecord(geom, other, False, float(t[idx[0]]), float(t[idx[-1]]), int(len(idx)),
                                 float(-cdata[j, k, 1]), tuple(where)))
    return out


def _checked_geoms(spec: mujoco.MjSpec) -> list[str]:
    """Names of the robot geoms that take part in collisions (the base excluded)."""
    names = []

    def walk(body):
        for g in body.geoms:
            if g.contype != 0 and g.name:
                names.append(g.name)
        for b in body.bodies:
            walk(b)

    walk(spec.body("shoulder_pan_link"))
    return names


@dataclass(frozen=True)
class ContactRecord:
    """Contacts between one robot geom and one target over the replay.

    Attributes:
        geom: robot geom name; ``other``: "workpiece_collision", "table" or "workpiece (exact)".
        intended: whether the process means this contact.
        first_t_s, last_t_s: first and last time in contact [s].
        steps: number of 1 ms samples in contact.
        max_penetration_m: deepest penetration [m] (positive into the target).
        position_m: (3,) robot-base-frame position of the deepest contact [m].
    """

    geom: str
    other: str
    intended: bool
    first_t_s: float
    last_t_s: float
    steps: int
    max_penetration_m: float
    position_m: tuple

    def to_dict(self) -> dict:
        return {"geom": self.geom, "other": self.other, "intended": self.intended,
                "first_t_s": round(self.first_t_s, 4), "last_t_s": round(self.last_t_s, 4),
                "steps": self.steps, "max_penetration_mm": self.max_penetration_m * 1e3,
                "position_m": [round(float(v), 6) for v in self.position_m]}


@dataclass(frozen=True)
class ReplayLog:
    """What the replay measured (robot base frame, SI units).

    Attributes:
        t: (N,) [s]; q, q_ref: (N, 6) actual and commanded joints [rad]; qd: (N, 6) actual [rad/s].
        tcp_actual: (N, 3) actual TCP positions [m]; tool_axis: (N, 3) actual tool z.
        tcp_planned: (N, 3) TCP of the commanded joints with the nominal kinematics [m].
        tracking_error_m: (N,) |actual - commanded TCP| at the same time [m].
        deviation_m: (N,) distance of the actual TCP from the planned tool path (the polyline
            of the process line's planned TCP poses) [m]; NaN off the process lines.
        tip_surface_m: (N,) signed distance of the ball end to the exact true part [m]
            (negative: into the material).
        table_clearance_m: (N,) height of the ball's lowest point above the table [m].
        process: (N,) bool, sample on a process line.
        line: (N,) process line of each sample (-1 in the air); kind: (N,) segment kind.
        contacts: every unintended (and the intended tip) contact, see ContactRecord.
        joint_limit_hits: list of dicts (joint, first_t_s, steps).
        velocity_limit_hits: list of dicts (joint, first_t_s, steps, max_ratio).
        wall_s: wall time of the simulation [s].
    """

    t: np.ndarray
    q: np.ndarray
    q_ref: np.ndarray
    qd: np.ndarray
    tcp_actual: np.ndarray
    tool_axis: np.ndarray
    tcp_planned: np.ndarray
    tracking_error_m: np.ndarray
    deviation_m: np.ndarray
    tip_surface_m: np.ndarray
    table_clearance_m: np.ndarray
    process: np.ndarray
    line: np.ndarray
    kind: np.ndarray
    contacts: tuple
    joint_limit_hits: tuple
    velocity_limit_hits: tuple
    wall_s: float
    tip_tolerance_m: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def sim_s(self) -> float:
        return float(len(self.t) * (self.t[1] - self.t[0])) if len(self.t) > 1 else 0.0

    @property
    def unintended_contacts(self) -> tuple:
        return tuple(c for c in self.contacts if not c.intended)

    def summary(self) -> dict:
        """Report fields (units in the names)."""
        dev = self.deviation_m[self.process]
        i = int(np.nanargmax(self.deviation_m)) if np.any(np.isfinite(self.deviation_m)) else -1
        transit = self.kind == "transit"
        tip_on = self.tip_surface_m[self.process]
        return {
            "max_deviation_mm": float(np.nanmax(dev) * 1e3) if len(dev) else None,
            "rms_deviation_mm": float(np.sqrt(np.nanmean(dev**2)) * 1e3) if len(dev) else None,
            "max_deviation_at": None if i < 0 else {
                "t_s": round(float(self.t[i]), 4), "line": int(self.line[i]),
                "position_m": [round(float(v), 6) for v in self.tcp_actual[i]]},
            "max_tracking_error_mm": float(self.tracking_error_m.max() * 1e3),
            "rms_tracking_error_mm": float(np.sqrt(np.mean(self.tracking_error_m**2)) * 1e3),
            "tip_surface_error_max_mm": float(np.max(np.abs(tip_on)) * 1e3) if len(tip_on) else None,
            "tip_surface_error_rms_mm": float(np.sqrt(np.mean(tip_on**2)) * 1e3) if len(tip_on) else None,
            # how deep the ball end went into the true part on the process lines (0: never)
            "tip_penetration_max_mm": float(max(0.0, -np.min(tip_on)) * 1e3) if len(tip_on) else None,
            "tip_min_clearance_transit_mm": float(np.min(self.tip_surface_m[transit]) * 1e3) if transit.any() else None,
            "contacts": [c.to_dict() for c in self.contacts],
            "unintended_contacts": len(self.unintended_contacts),
            "joint_limit_hits": list(self.joint_limit_hits),
            "velocity_limit_hits": list(self.velocity_limit_hits),
            "simulated_s": round(self.sim_s, 3),
            "wall_s": round(self.wall_s, 3),
            "sim_speed_x_realtime": round(self.sim_s / self.wall_s, 1) if self.wall_s > 0 else None,
        }


def _polyline_distance(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Distance of each query (M, 3) to the polyline through P (n, 3)."""
    if len(P) == 1:
        return np.linalg.norm(Q - P[0], axis=1)
    tree = cKDTree(P)
    kk = min(4, len(P))
    _, nn = tree.query(Q, k=kk)
    nn = nn.reshape(len(Q), kk)
    best = np.full(len(Q), np.inf)
    for c in range(kk):
        for off in (-1, 0):
            i0 = np.clip(nn[:, c] + off, 0, len(P) - 2)
            a, b = P[i0], P[i0 + 1]
            ab = b - a
            t = np.clip(np.einsum("ij,ij->i", Q - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0, 1)
            d = np.linalg.norm(a + t[:, None] * ab - Q, axis=1)
            best = np.minimum(best, d)
    return best



class _ReplaySensors:
    """The replay's sensor readings, filled chunk by chunk by :func:`twin.sim.simulate` (world frame).

    Attributes:
        tcp: (n, 3) TCP positions [m]; zax: (n, 3) tool z axes.
        qd: (n, 6) joint velocities [rad/s]; q_true: (n, 6) the joints the sensors saw [rad].
        contact_names: the contact sensors' names; cdata: (n, len(contact_names), 5) their readings.
    """

    def __init__(self, model: mujoco.MjModel, n: int) -> None:
        self.columns = {}
        for i in range(model.nsensor):
            s = model.sensor(i)
            self.columns[s.name] = slice(int(s.adr[0]), int(s.adr[0] + s.dim[0]))
        self.contact_names, self.contact_cols = contact_columns(model)
        self.tcp = np.empty((n, 3))
        self.zax = np.empty((n, 3))
        self.qd = np.empty((n, 6))
        self.q_true = np.empty((n, 6))
        self.cdata = np.empty((n, len(self.contact_names), 5))
        self.vel_cols = [self.columns[f"vel_{j}"].start for j in JOINT_NAMES]

    def on_chunk(self, i0: int, sens: np.ndarray, q_before: np.ndarray) -> None:
        i1 = i0 + len(sens)
        self.tcp[i0:i1] = sens[:, self.columns["tcp_pos"]]
        self.zax[i0:i1] = sens[:, self.columns["tcp_zaxis"]]
        self.qd[i0:i1] = sens[:, self.vel_cols]
        self.q_true[i0:i1] = q_before
        self.cdata[i0:i1] = sens[:, self.contact_cols].reshape(len(sens), len(self.contact_names), 5)


def _check_replay_inputs(model: mujoco.MjModel, trajectory: Trajectory) -> None:
    """Refuse a cell without the tool or a trajectory at another time step."""
    if "tcp" not in [model.site(i).name for i in range(model.nsite)]:
        raise TwinError("replay needs the replay cell (build_replay_cell): the model has no tool")
    if abs(model.opt.timestep - trajectory.dt) > 1e-12:
        raise TwinError(f"trajectory step {trajectory.dt} s differs from the cell's {model.opt.timestep} s")


def _path_deviation(path: ProcessPath, trajectory: Trajectory,
                    tcp_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segment kind (N,), process line (N,) of each sample, and the distance (N,) [m] of the
    actual TCP from the planned tool path on the process segments (NaN elsewhere)."""
    segs = path.segments
    kind = np.array([segs[s][2] for s in trajectory.segment])
    line = np.array([segs[s][3] for s in trajectory.segment])
    deviation = np.full(len(trajectory.t), np.nan)
    for si, (a, b, k, _ln) in enumerate(segs):
        if k != "process":
            continue
        sel = np.flatnonzero(trajectory.segment == si)
        if len(sel):
            deviation[sel] = _polyline_distance(path.T_tool[a:b + 1, :3, 3], tcp_b[sel])
    return kind, line, deviation


def _tip_clearances(cell: Cell, index: MeshIndex, tcp_b: np.ndarray, zax_b: np.ndarray,
                    T_bw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance (N,) [m] of the ball end to the exact part (workpiece frame of the TRUE
    cell; negative: into the material) and the height (N,) [m] of its lowest point above the table."""
    r = cell.scenario.path.tip_radius_m
    centre_b = tcp_b + r * zax_b
    T_base_wp = T_bw @ cell.T_world_workpiece
    c_wp = transform_points(inv_pose(T_base_wp), centre_b)
    tip_surface = index.signed_distance(c_wp) - r
    centre_w = transform_points(cell.T_world_base, centre_b)
    return tip_surface, centre_w[:, 2] - r


def _tip_contacts(t: np.ndarray, kind: np.ndarray, tip_surface: np.ndarray, table_clear: np.ndarray,
                  tcp_b: np.ndarray, tip_tolerance_m: float) -> list[ContactRecord]:
    """The ball end's contacts: with the part, intended on the process lines (touch-down and
    lift-off included) and unintended on the transits; with the table, always unintended."""
    contacts = []
    touching = tip_surface <= tip_tolerance_m
    in_process = kind != "transit"
    for intended, mask in ((True, touching & in_process), (False, touching & ~in_process)):
        if mask.any():
            idx = np.flatnonzero(mask)
            j = idx[np.argmin(tip_surface[idx])]
            contacts.append(ContactRecord("tool_tip", "workpiece (exact)", intended, float(t[idx[0]]),
                                          float(t[idx[-1]]), int(len(idx)), float(max(-tip_surface[j], 0.0)),
                                          tuple(tcp_b[j])))
    on_table = table_clear <= 0
    if on_table.any():
        idx = np.flatnonzero(on_table)
        j = idx[np.argmin(table_clear[idx])]
        contacts.append(ContactRecord("tool_tip", "table", False, float(t[idx[0]]), float(t[idx[-1]]),
                                      int(len(idx)), float(-table_clear[j]), tuple(tcp_b[j])))
    return contacts


def _limit_hits(model: mujoco.MjModel, q_true: np.ndarray, qd: np.ndarray,
                t: np.ndarray) -> tuple[list[dict], list[dict]]:
    """Per joint, the samples within ``JOINT_LIMIT_MARGIN_RAD`` of a joint limit and those over
    the velocity limit: (joint, first_t_s, steps[, max_ratio]) dicts."""
    rng = model.jnt_range[[model.joint(j).id for j in JOINT_NAMES]]
    jl, vl = [], []
    for j, name in enumerate(JOINT_NAMES):
        lo_j, hi_j = rng[j, 0] + JOINT_LIMIT_MARGIN_RAD, rng[j, 1] - JOINT_LIMIT_MARGIN_RAD
        hit = (q_true[:, j] <= lo_j) | (q_true[:, j] >= hi_j)
        if hit.any():
            jl.append({"joint": name, "first_t_s": float(t[np.argmax(hit)]), "steps": int(hit.sum())})
        ratio = np.abs(qd[:, j]) / VELOCITY_LIMIT_RAD_S[j]
        over = ratio > 1.0
        if over.any():
            vl.append({"joint": name, "first_t_s": float(t[np.argmax(over)]), "steps": int(over.sum()),
                       "max_ratio": float(ratio.max())})
    return jl, vl


def replay(cell: Cell, trajectory: Trajectory, path: ProcessPath, index: MeshIndex,
           tip_tolerance_m: float = 1e-4) -> ReplayLog:
    """Run ``trajectory`` in the replay cell (:func:`build_replay_cell`) and verify it.

    Args:
        cell: the replay cell (true cell with the tool).
        trajectory: joint references every 1 ms.
        path: the process path the trajectory was planned from (robot base frame).
        index: the MeshIndex of the workpiece mesh (``Realized.workpiece.index``).
        tip_tolerance_m: on a process line the ball counts as touching within this distance.

    Raises:
        TwinError: the cell has no tool, or the trajectory's step is not the cell's.
    """
    model = cell.model
    _check_replay_inputs(model, trajectory)
    log = _ReplaySensors(model, len(trajectory.t))
    t0 = time.perf_counter()
    simulate(cell, trajectory.q, trajectory.qd, log.on_chunk)
    wall = time.perf_counter() - t0

    T_bw = inv_pose(cell.T_world_base)
    tcp_b = transform_points(T_bw, log.tcp)
    zax_b = log.zax @ T_bw[:3, :3].T
    T_plan = dh_forward(trajectory.q, UR5E_DH) @ cell.scenario.path.T_flange_tool
    tcp_plan = T_plan[:, :3, 3]
    tracking = np.linalg.norm(tcp_b - tcp_plan, axis=1)
    kind, line, deviation = _path_deviation(path, trajectory, tcp_b)
    tip_surface, table_clear = _tip_clearances(cell, index, tcp_b, zax_b, T_bw)

    t = trajectory.t
    contacts = contact_records(log.contact_names, log.cdata, t, T_bw)
    contacts.extend(_tip_contacts(t, kind, tip_surface, table_clear, tcp_b, tip_tolerance_m))
    jl, vl = _limit_hits(model, log.q_true, log.qd, t)
    return ReplayLog(t, log.q_true, trajectory.q, log.qd, tcp_b, zax_b, tcp_plan, tracking, deviation, tip_surface,
                     table_clear, kind == "process", line, kind, tuple(contacts), tuple(jl), tuple(vl), wall,
                     tip_tolerance_m)
