"""Bulk ray casting against a cell, with MuJoCo's ray semantics at Embree's speed.

A scan of the 1024-beam line profiler casts about a million beams and as many receiver rays
per simulated second, too many for MuJoCo's camera rangefinder inside the rollout to keep up
with real time. Here the static mesh geoms (the workpiece, a meshed fixture) go to Embree
(embreex), a well-kept bulk ray caster; each Embree hit is then refined in double precision on
the triangle it found, so the distance and the face normal are MuJoCo's (the same float32
vertices, the same plane intersection; at an edge shared by two faces either face's normal is
right). tests/test_raycast.py holds the distances to MuJoCo's within 1e-9 m. Every other geom
(the table plane, the robot's links at each step's joints, primitive fixtures) is still cast by
MuJoCo, only for the beams that could reach it before the mesh.

The static meshes are moved to :data:`HIDDEN_GROUP` in a private copy of the model so that
MuJoCo's casts skip them; the cell's own model is untouched.
"""

from __future__ import annotations

import copy
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import embreex.mesh_construction
import embreex.rtcore_scene
import mujoco
import mujoco.batch
import numpy as np

# The geom group the static meshes are moved to in the private model (MuJoCo's rays skip it).
HIDDEN_GROUP = 5
# Rays are cast on this many threads (Embree and MuJoCo both release the interpreter).
RAY_THREADS = 2
# Below this many rays one thread is faster than starting two.
THREADED_MIN_RAYS = 50_000
# Many steps are cast in blocks of about this many rays: their temporaries (a few MB) are
# reused by the allocator instead of being mapped afresh (page faults would rival the casts).
BLOCK_RAYS = 256 * 1024


def _visible(model: mujoco.MjModel) -> np.ndarray:
    """(ngeom,) geoms a ray can see: MuJoCo's rays ignore a geom whose rgba, or whose
    material's rgba, has alpha 0."""
    alpha = model.geom_rgba[:, 3].copy()
    has_mat = model.geom_matid >= 0
    alpha[has_mat] = model.mat_rgba[model.geom_matid[has_mat], 3]
    return alpha > 0


def _one_thread(n: int, rays: int | None) -> bool:
    """Whether a job of ``n`` items (``rays`` rays, default ``n``) is too small to split."""
    return (n if rays is None else rays) < THREADED_MIN_RAYS or RAY_THREADS < 2 or n < RAY_THREADS


class CellRays:
    """Rays against the geoms of one compiled cell.

    Args:
        model: the cell's model (copied; the copy's static meshes are hidden from MuJoCo).
        qpos_adr: (J,) the qpos addresses of the joints a cast's ``q`` gives (the arm's).
    """

    def __init__(self, model: mujoco.MjModel, qpos_adr: np.ndarray) -> None:
        if np.any(model.geom_group == HIDDEN_GROUP):
            raise ValueError(f"geom group {HIDDEN_GROUP} is in use: the bulk rays need it to hide the static meshes")
        self.model = copy.copy(model)
        self.data = mujoco.MjData(self.model)
        self.qpos_adr = np.asarray(qpos_adr)
        mujoco.mj_kinematics(self.model, self.data)
        m = self.model
        static = m.body_weldid[m.geom_bodyid] == 0
        self.group = m.geom_group.copy()
        self.mesh_geoms = np.flatnonzero(static & (m.geom_type == mujoco.mjtGeom.mjGEOM_MESH) & _visible(m))
        tris, owner = [], []
        for g in self.mesh_geoms:
            mid = m.geom_dataid[g]
            v = m.mesh_vert[m.mesh_vertadr[mid]:m.mesh_vertadr[mid] + m.mesh_vertnum[mid]].astype(np.float64)
            f = m.mesh_face[m.mesh_faceadr[mid]:m.mesh_faceadr[mid] + m.mesh_facenum[mid]]
            R, p = self.data.geom_xmat[g].reshape(3, 3), self.data.geom_xpos[g]
            tris.append((v @ R.T + p)[f])
            owner.append(np.full(len(f), g))
            m.geom_group[g] = HIDDEN_GROUP
        self.triangles = np.concatenate(tris) if tris else np.zeros((0, 3, 3))   # (F, 3, 3) world [m]
        self.face_geom = np.concatenate(owner) if owner else np.zeros(0, dtype=int)
        # Embree works in float32: near the meshes' centre its coordinates keep nanometres.
        self.centre = self.triangles.reshape(-1, 3).mean(axis=0) if len(self.triangles) else np.zeros(3)
        e1 = self.triangles[:, 1] - self.triangles[:, 0]
        normal = np.cross(e1, self.triangles[:, 2] - self.triangles[:, 0])
        self.face_normal = normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        self.face_offset = np.einsum("ij,ij->i", self.face_normal, self.triangles[:, 0] - self.centre)
        # per set of mesh geoms: its Embree scene and the scene's faces' indices (None: no faces)
        self._scenes: dict[tuple[int, ...], tuple[embreex.rtcore_scene.EmbreeScene, np.ndarray] | None] = {}
        # one MjData and one batch of one simulation per thread; the worker's index per thread
        self._datas = [self.data] + [mujoco.MjData(self.model) for _ in range(RAY_THREADS - 1)]
        for d in self._datas[1:]:
            mujoco.mj_kinematics(self.model, d)   # the static geoms' poses, read by every thread
        self._batches: list[mujoco.batch.Batch | None] = [None] * RAY_THREADS
        self._pool: ThreadPoolExecutor | None = None
        self._local = threading.local()
        self._scene_lock = threading.Lock()

    # -- the two halves: Embree (static meshes) and MuJoCo (the rest) --

    def _scene(self, geoms: np.ndarray) -> tuple[embreex.rtcore_scene.EmbreeScene, np.ndarray] | None:
        """The Embree scene of these static mesh geoms (built once per set) and the index of
        each of its faces in ``triangles``; None when they have no faces."""
        key = tuple(int(g) for g in geoms)
        with self._scene_lock:   # the workers of map_blocks may ask for the same scene at once
            if key not in self._scenes:
                faces = np.flatnonzero(np.isin(self.face_geom, geoms))
                built = None
                if len(faces):
                    scene = embreex.rtcore_scene.EmbreeScene()
                    embreex.mesh_construction.TriangleMesh(scene,
                                                           (self.triangles[faces] - self.centre).astype(np.float32))
                    scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))   # commit it now
                    built = (scene, faces)
                self._scenes[key] = built
        return self._scenes[key]

    def _embree(self, geoms: np.ndarray, start_rel: np.ndarray, unit: np.ndarray,
                length: np.ndarray | None = None) -> np.ndarray:
        """Embree on these mesh geoms; ``start_rel``: (M, 3) float32 starts relative to
        ``centre``; ``unit``: (M, 3) float32. Without ``length``: (M,) the first face hit (an
        index into ``triangles``), -1 for a miss; with ``length`` (M,): (M,) bool, something is
        hit before it (Embree's any-hit query)."""
        found = self._scene(geoms)
        if found is None or len(start_rel) == 0:
            return np.full(len(start_rel), -1, dtype=np.int64) if length is None else np.zeros(len(start_rel), bool)
        scene, faces = found
        if length is not None:
            far = length.astype(np.float32)
            parts = self._threaded(lambda _, s: scene.run(start_rel[s], unit[s], dists=far[s], query="OCCLUDED"),
                                   len(start_rel))
            return np.concatenate(parts) == 0   # OCCLUDED: 0 where something is in the way, -1 where not
        prim = np.concatenate(self._threaded(lambda _, s: scene.run(start_rel[s], unit[s]), len(start_rel)))
        out = np.full(len(start_rel), -1, dtype=np.int64)
        hit = prim >= 0
        out[hit] = faces[prim[hit]]
        return out

    def _refine(self, face: np.ndarray, start_rel: np.ndarray, unit: np.ndarray) -> np.ndarray:
        """Distance [m] along each ray (``start_rel`` relative to ``centre``, float64) to the
        plane of its face, in double precision."""
        n = self.face_normal[face]
        return (self.face_offset[face] - np.einsum("ij,ij->i", start_rel, n)) / np.einsum("ij,ij->i", unit, n)

    def _threaded(self, fn, n: int, rays: int | None = None) -> list:
        """``fn(thread, slice)`` over RAY_THREADS slices of ``range(n)``, results in order; one
        thread when the job is small (``rays``, default ``n``, under THREADED_MIN_RAYS) or when
        called from a worker of :meth:`map_blocks` (that worker's thread)."""
        worker = getattr(self._local, "thread", None)
        if worker is not None:
            return [fn(worker, slice(0, n))]
        if _one_thread(n, rays):
            return [fn(0, slice(0, n))]
        return self._on_threads(fn, n)

    def _on_threads(self, fn, n: int) -> list:
        """``fn(thread, slice)`` on the RAY_THREADS threads, each a contiguous share of ``range(n)``."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(RAY_THREADS)
        cuts = np.linspace(0, n, RAY_THREADS + 1).astype(int)
        slices = [slice(a, b) for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
        return list(self._pool.map(fn, range(RAY_THREADS), slices))

    def map_blocks(self, fn: Callable[[slice], object], n: int, block: int, rays: int | None = None) -> None:
        """``fn(rows)`` over blocks of ``block`` rows of ``range(n)``: each thread takes a
        contiguous share and works through it block by block, so the numpy work between the
        casts runs on every core too, and the temporaries stay a few MB (reused by the
        allocator rather than mapped afresh). The casts ``fn`` makes run on its thread. One
        thread when the job is small (``rays``, default ``n``, under THREADED_MIN_RAYS)."""
        def work(thread: int, share: slice) -> None:
            self._local.thread = thread
            try:
                for a in range(share.start, share.stop, block):
                    fn(slice(a, min(share.stop, a + block)))
            finally:
                self._local.thread = None

        if _one_thread(n, rays):
            work(0, slice(0, n))
        else:
            self._on_threads(work, n)

    def _others(self, include: np.ndarray) -> np.ndarray:
        """The geoms MuJoCo casts against, of those in ``include`` (the static meshes aside)."""
        return np.setdiff1d(np.flatnonzero(include & _visible(self.model)), self.mesh_geoms)

    def _group_mask(self, geoms: np.ndarray) -> np.ndarray:
        """MuJoCo's ``geomgroup`` for casting against ``geoms``' groups, the hidden meshes left out."""
        mask = np.zeros(mujoco.mjNGROUP, dtype=np.uint8)
        mask[np.unique(self.group[geoms])] = 1
        mask[HIDDEN_GROUP] = 0
        return mask

    # -- what the sensors ask --

    def beams(self, origin: np.ndarray, direction: np.ndarray, q: np.ndarray,
              exclude_body: int) -> tuple[np.ndarray, np.ndarray]:
        """What a camera rangefinder on ``exclude_body`` returns for K steps of B beams.

        Args:
            origin: (K, 3) emitter per step, world [m]; direction: (K, B, 3) unit beams, world.
            q: (K, J) joints at each step [rad] (the moving geoms are cast at them).
            exclude_body: the body whose geoms the beams ignore (the sensor's own).

        Returns:
            dist (K, B) [m], -1 for a miss; normal (K, B, 3), the hit face's normal (0 on a miss).
        """
        k, b = direction.shape[:2]
        dist = np.empty((k, b))
        normal = np.empty((k, b, 3))
        others = self._others(self.model.geom_bodyid != exclude_body)

        def block(rows: slice) -> None:
            dist[rows], normal[rows] = self._mesh_beams(origin[rows], direction[rows])
            if len(others):
                self._cast_others(others, origin[rows], direction[rows], q[rows], exclude_body, dist[rows],
                                  normal[rows])

        self.map_blocks(block, k, max(1, BLOCK_RAYS // max(b, 1)), k * b)
        return dist, normal

    def _mesh_beams(self, origin: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Embree's half of :meth:`beams`: (K, B) distances to the static meshes (-1: none) and
        (K, B, 3) their face normals."""
        k, b = direction.shape[:2]
        origin_rel = origin - self.centre
        unit = direction.reshape(-1, 3)
        face = self._embree(self.mesh_geoms, np.repeat(origin_rel.astype(np.float32), b, axis=0),
                            unit.astype(np.float32))
        hit = np.flatnonzero(face >= 0)
        dist = np.full(k * b, -1.0)
        normal = np.zeros((k * b, 3))
        dist[hit] = self._refine(face[hit], origin_rel[hit // b], unit[hit])
        normal[hit] = self.face_normal[face[hit]]
        return dist.reshape(k, b), normal.reshape(k, b, 3)

    def _cast_others(self, others: np.ndarray, origin: np.ndarray, direction: np.ndarray, q: np.ndarray,
                     exclude_body: int, dist: np.ndarray, normal: np.ndarray) -> None:
        """MuJoCo's multi-ray from each step's emitter at the step's joints, against ``others``;
        a hit nearer than the mesh's replaces it (in place). Only the beams that could reach
        one of ``others`` before the mesh (:meth:`_beams_near`) are cast."""
        m = self.model
        groups = self._group_mask(others)
        rows, cols = np.nonzero(self._beams_near(others, origin, direction, q, dist))
        if len(rows) == 0:
            return
        steps, first = np.unique(rows, return_index=True)
        bounds = np.append(first, len(rows))
        dd = np.empty(len(rows))
        nn = np.empty((len(rows), 3))

        def run(thread: int, s: slice) -> None:
            d = self._datas[thread]
            gid = np.empty(dist.shape[1], dtype=np.int32)
            for i in range(s.start, s.stop):
                step, lo, hi = steps[i], bounds[i], bounds[i + 1]
                d.qpos[self.qpos_adr] = q[step]
                mujoco.mj_kinematics(m, d)
                mujoco.mj_multiRay(m, d, origin[step], direction[step, cols[lo:hi]].reshape(-1), groups, 1,
                                   exclude_body, gid[:hi - lo], dd[lo:hi], nn[lo:hi].reshape(-1), hi - lo,
                                   mujoco.mjMAXVAL)

        self._threaded(run, len(steps), len(rows))
        d0 = dist[rows, cols]
        nearer = (dd >= 0) & ((d0 < 0) | (dd < d0))
        dist[rows[nearer], cols[nearer]] = dd[nearer]
        normal[rows[nearer], cols[nearer]] = nn[nearer]

    def _beams_near(self, geoms: np.ndarray, origin: np.ndarray, direction: np.ndarray, q: np.ndarray,
                    dist: np.ndarray) -> np.ndarray:
        """(K, B) False for the beams that cannot meet one of ``geoms`` before their mesh hit
        (``dist``, (K, B), -1 for none). A step's beams are all kept when a geom's bounding
        sphere (MuJoCo's ``geom_rbound`` about its centre at the step's joints) meets the cone
        around them within the step's farthest mesh hit (any distance if a beam missed) and
        its bounding box (``geom_aabb``) is not wholly behind the emitter; of a plane (taken as
        infinite), the beams that meet it before their mesh hit. Geoms without a bound (a
        height field) keep every beam."""
        m, d = self.model, self._datas[getattr(self._local, "thread", None) or 0]
        k = len(origin)
        cutoff = np.where(np.all(dist >= 0, axis=1), dist.max(axis=1), np.inf)
        axis = direction.sum(axis=1)
        axis /= np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-300)
        half = np.arccos(np.clip(np.einsum("kbi,ki->kb", direction, axis).min(axis=1), -1.0, 1.0))
        if np.any(half >= np.pi / 2):
            return np.ones(dist.shape, dtype=bool)   # a fan wider than a half-space: no cone to cull with
        corners_local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
        # each geom's pose at each step (the static ones do not move)
        pos = np.broadcast_to(d.geom_xpos[geoms], (k, len(geoms), 3)).copy()
        mat = np.broadcast_to(d.geom_xmat[geoms], (k, len(geoms), 9)).copy()
        moving = m.body_weldid[m.geom_bodyid[geoms]] != 0
        if np.any(moving):
            for i in range(k):
                d.qpos[self.qpos_adr] = q[i]
                mujoco.mj_kinematics(m, d)
                pos[i, moving] = d.geom_xpos[geoms[moving]]
                mat[i, moving] = d.geom_xmat[geoms[moving]]
            d.qpos[:] = m.qpos0
            mujoco.mj_kinematics(m, d)
        near = np.zeros(k, dtype=bool)
        beams = np.zeros(dist.shape, dtype=bool)
        for j, g in enumerate(geoms):
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:   # static: the table
                z = d.geom_xmat[g].reshape(3, 3)[:, 2]
                height = origin @ z - d.geom_xpos[g] @ z
                with np.errstate(divide="ignore", invalid="ignore"):
                    t = height[:, None] / -(direction @ z)
                beams |= (t >= 0) & ((dist < 0) | (t < dist))
                continue
            r = m.geom_rbound[g]
            if r <= 0:
                return np.ones(dist.shape, dtype=bool)
            v = pos[:, j] - origin
            dist = np.linalg.norm(v, axis=1)
            angle = np.arccos(np.clip(np.einsum("ki,ki->k", v, axis) / np.maximum(dist, 1e-300), -1.0, 1.0))
            widen = np.arcsin(np.clip(r / np.maximum(dist, 1e-300), 0.0, 1.0))
            maybe = (dist <= r) | ((angle <= half + widen) & (dist - r <= cutoff))
            # the bounding box's corners, world, at the maybe-steps: all behind the emitter -> unreachable
            box = m.geom_aabb[g]
            R = mat[maybe, j].reshape(-1, 3, 3)
            corners = pos[maybe, j][:, None, :] + np.einsum("kij,cj->kci", R, box[:3] + corners_local * box[3:])
            ahead = np.einsum("kci,ki->kc", corners - origin[maybe][:, None, :], axis[maybe]).max(axis=1) > 0.0
            maybe[maybe] = ahead
            near |= maybe
        beams[near] = True
        return beams

    def blocked(self, start: np.ndarray, unit: np.ndarray, length: np.ndarray, groups: np.ndarray) -> np.ndarray:
        """Whether each ray meets a geom of ``groups`` before ``length`` (static groups only).

        Args:
            start: (M, 3) ray starts, world [m]; unit: (M, 3) unit directions; length: (M,) [m].
            groups: (6,) geom-group mask (1 = included), as MuJoCo's ``geomgroup``; the groups
                must hold no moving geom (the scene would depend on the joints).

        Returns:
            (M,) bool, True where something is hit closer than ``length``.
        """
        m, d = self.model, self.data
        in_groups = np.asarray(groups, dtype=bool)[self.group]
        moving = in_groups & (m.body_weldid[m.geom_bodyid] != 0)
        if np.any(moving):
            raise ValueError(f"groups {np.flatnonzero(groups).tolist()} hold moving geoms "
                             f"({mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, int(np.flatnonzero(moving)[0]))})")
        blocked = self._embree(self.mesh_geoms[in_groups[self.mesh_geoms]], (start - self.centre).astype(np.float32),
                               unit.astype(np.float32), length)
        others = self._others(in_groups)
        # MuJoCo casts only the rays whose segment meets another geom's bounding sphere (or crosses a plane)
        reach = np.zeros(len(start), dtype=bool)
        for g in others:
            c = d.geom_xpos[g]
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
                z = d.geom_xmat[g].reshape(3, 3)[:, 2]
                h = start @ z - c @ z
                reach |= h * (h + length * (unit @ z)) <= 0.0
            elif m.geom_rbound[g] <= 0:
                reach[:] = True
            else:
                t = np.clip(np.einsum("ij,ij->i", c - start, unit), 0.0, length)
                reach |= np.linalg.norm(start + t[:, None] * unit - c, axis=1) <= m.geom_rbound[g]
        rest = np.flatnonzero(~blocked & reach)
        if len(rest):
            thread = getattr(self._local, "thread", None) or 0
            batch = self._batches[thread]
            if batch is None:
                batch = self._batches[thread] = mujoco.batch.Batch(self.model, 1, nthread=1)
            hit, _ = batch.ray(start[rest][None], unit[rest][None], geomgroup=self._group_mask(others), flg_static=True)
            blocked[rest] = (hit[0] >= 0.0) & (hit[0] < length[rest])
        return blocked
