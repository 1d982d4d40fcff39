"""Scan segments as the active-scan agent chooses them: the action, the view it names, the
sensor poses it becomes, and what the CAD model predicts it will measure.

A view is a point on a sphere around the part (azimuth and elevation of the direction ``u``
from the part towards the sensor), an aim point on the plane through the part's centre
normal to ``u`` (two offsets), a stand-off within the sensor's window and the direction of a
short straight line in that plane. The beam points along ``-u`` at the aim point; where it
first meets the CAD model at the current estimate is the segment's centre ``p``; the sensor
then travels the line ``p + standoff u + tau w`` (``tau`` in ``[-L/2, L/2]``) with its beam
fixed, its x axis along the travel ``w``.

The action is six numbers in [-1, 1], mapped linearly (:func:`decode_action`):

====  ================  =================================================
 0    azimuth           [-180, 180] deg about world z
 1    elevation         [``ELEVATION_MIN_DEG``, 90] deg above the table
 2    stand-off         the sensor's window
 3    line direction    [0, 180] deg from the azimuth tangent ``e1``
 4    aim offset e1     [-R, R], R the radius of the part's bounding sphere
 5    aim offset e2     [-R, R]
====  ================  =================================================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithms.geometry.raycast import raycast_parallel
from algorithms.geometry.se3 import inv_pose
from twin.realize import Workpiece

ACTION_SIZE = 6
ELEVATION_MIN_DEG = 20.0
#: Spacing of the rays that predict a segment's points on the CAD model [m].
PREDICTION_STEP_M = 0.001


@dataclass(frozen=True)
class Geometry:
    """What views are measured against: the part's bounding sphere (workpiece frame) and the
    sensor's window."""

    centre_wp: np.ndarray
    radius_m: float
    window_m: tuple[float, float]
    max_incidence_rad: float

    @classmethod
    def of(cls, workpiece: Workpiece, window_m: tuple[float, float], max_incidence_deg: float) -> Geometry:
        lo, hi = workpiece.mesh.bounds
        return cls(0.5 * (lo + hi), float(0.5 * np.linalg.norm(hi - lo)), (float(window_m[0]), float(window_m[1])),
                   float(np.radians(max_incidence_deg)))


@dataclass(frozen=True)
class View:
    """A decoded action (angles [rad], lengths [m])."""

    azimuth_rad: float
    elevation_rad: float
    standoff_m: float
    line_angle_rad: float
    aim_offset_m: tuple[float, float]

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(u, e1, e2): u from the part towards the sensor, e1 the azimuth tangent, e2 = u x e1."""
        ca, sa = np.cos(self.azimuth_rad), np.sin(self.azimuth_rad)
        ce, se = np.cos(self.elevation_rad), np.sin(self.elevation_rad)
        u = np.array([ce * ca, ce * sa, se])
        e1 = np.array([-sa, ca, 0.0])
        return u, e1, np.cross(u, e1)

    def line_direction(self) -> np.ndarray:
        _, e1, e2 = self.basis()
        return np.cos(self.line_angle_rad) * e1 + np.sin(self.line_angle_rad) * e2


def decode_action(action: np.ndarray, geometry: Geometry) -> View:
    """The view an action in [-1, 1]^6 names (module docstring)."""
    a = np.asarray(action, dtype=np.float64)
    el_min = np.radians(ELEVATION_MIN_DEG)
    w0, w1 = geometry.window_m
    return View(
        azimuth_rad=float(np.pi * a[0]),
        elevation_rad=float(el_min + (0.5 * np.pi - el_min) * (a[1] + 1) / 2),
        standoff_m=float(w0 + (w1 - w0) * (a[2] + 1) / 2),
        line_angle_rad=float(0.5 * np.pi * (a[3] + 1)),
        aim_offset_m=(float(geometry.radius_m * a[4]), float(geometry.radius_m * a[5])),
    )


#: The views of ``actions="views"``: elevations [deg] with the azimuth step at each [deg] (four
#: azimuths looking straight down turn the aim offsets and the line), aim offsets (e1, e2) as
#: fractions of the part's radius, and line directions (actions: 0 and 90 deg from ``e1``).
VIEW_ELEVATIONS_DEG = {90.0: 90.0, 60.0: 45.0, 35.0: 45.0}
VIEW_AIM_OFFSETS = ((0.0, 0.0), (-0.5, 0.0), (0.5, 0.0), (0.0, -0.5), (0.0, 0.5))
VIEW_LINE_ACTIONS = (-1.0, 0.0)


def view_directions() -> list[tuple[float, float]]:
    """(azimuth action, elevation action) of every view direction of the table (20)."""
    out = []
    for el, step in VIEW_ELEVATIONS_DEG.items():
        a1 = 2 * (el - ELEVATION_MIN_DEG) / (90.0 - ELEVATION_MIN_DEG) - 1
        out += [(az / 180.0, a1) for az in np.arange(-180.0, 180.0, step)]
    return out


def view_table() -> np.ndarray:
    """(200, 6) the laser views of ``actions="views"``: every direction, aim offset and line
    direction, at mid-window."""
    return np.array([[az, el, 0.0, line, o1, o2] for az, el in view_directions()
                     for o1, o2 in VIEW_AIM_OFFSETS for line in VIEW_LINE_ACTIONS])


def encode_view(u: np.ndarray, aim_world: np.ndarray, line_world: np.ndarray, standoff_m: float,
                T_world_workpiece: np.ndarray, geometry: Geometry) -> np.ndarray:
    """The action (clipped to [-1, 1]) of the view looking along ``-u`` through ``aim_world``
    with the line along ``line_world`` (world frame): the inverse of :func:`decode_action`."""
    u = np.asarray(u, dtype=np.float64) / np.linalg.norm(u)
    az = float(np.arctan2(u[1], u[0]))
    el = float(np.arcsin(np.clip(u[2], -1.0, 1.0)))
    view = View(az, el, standoff_m, 0.0, (0.0, 0.0))
    _, e1, e2 = view.basis()
    c = T_world_workpiece[:3, :3] @ geometry.centre_wp + T_world_workpiece[:3, 3]
    d = np.asarray(aim_world, dtype=np.float64) - c
    line = np.asarray(line_world, dtype=np.float64)
    angle = float(np.arctan2(line @ e2, line @ e1)) % np.pi
    el_min = np.radians(ELEVATION_MIN_DEG)
    w0, w1 = geometry.window_m
    a = np.array([az / np.pi, 2 * (el - el_min) / (0.5 * np.pi - el_min) - 1, 2 * (standoff_m - w0) / (w1 - w0) - 1,
                  2 * angle / np.pi - 1, (d @ e1) / geometry.radius_m, (d @ e2) / geometry.radius_m])
    return np.clip(a, -1.0, 1.0)


def _to_workpiece(T_world_workpiece: np.ndarray, origins_world: np.ndarray, direction_world: np.ndarray):
    T_wp_world = inv_pose(T_world_workpiece)
    return origins_world @ T_wp_world[:3, :3].T + T_wp_world[:3, 3], T_wp_world[:3, :3] @ direction_world


def segment_centre(view: View, T_world_workpiece: np.ndarray, workpiece: Workpiece,
                   geometry: Geometry) -> np.ndarray | None:
    """Where the view's beam first meets the CAD model at ``T_world_workpiece`` (world [m]), or
    None when it misses the part."""
    u, e1, e2 = view.basis()
    c = T_world_workpiece[:3, :3] @ geometry.centre_wp + T_world_workpiece[:3, 3]
    aim = c + view.aim_offset_m[0] * e1 + view.aim_offset_m[1] * e2
    o, d = _to_workpiece(T_world_workpiece, (aim + 2.0 * geometry.radius_m * u)[None], -u)
    hit, p, _ = raycast_parallel(workpiece.mesh.vertices, workpiece.mesh.faces, o, d)
    if not hit[0]:
        return None
    return T_world_workpiece[:3, :3] @ p[0] + T_world_workpiece[:3, 3]


def sensor_line(view: View, centre_world: np.ndarray, length_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The (4, 4) world sensor poses at the two ends of the view's line through ``centre_world``."""
    u, _, _ = view.basis()
    w = view.line_direction()
    R = np.column_stack([w, np.cross(-u, w), -u])
    ends = []
    for tau in (-0.5 * length_m, 0.5 * length_m):
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = centre_world + view.standoff_m * u + tau * w
        ends.append(T)
    return ends[0], ends[1]


@dataclass(frozen=True)
class Prediction:
    """What a segment should measure if the CAD model at the estimate is right.

    Attributes:
        feet_wp: (M, 3) predicted points, workpiece frame [m].
        faces: (M,) their faces.
        readings_m: (M,) the distances the sensor would read [m].
    """

    feet_wp: np.ndarray
    faces: np.ndarray
    readings_m: np.ndarray


def predict_segments(ends: list[tuple[np.ndarray, np.ndarray]], T_world_workpiece: np.ndarray,
                     workpiece: Workpiece, geometry: Geometry) -> list[Prediction]:
    """Predicted points of segments that share one beam direction (their poses' z): rays every
    ``PREDICTION_STEP_M`` along each line, kept where the hit lies in the window and the
    incidence is within the sensor's limit (one ray cast for all of them)."""
    if not ends:
        return []
    beam = ends[0][0][:3, 2]
    origins, owner = [], []
    for k, (Ta, Tb) in enumerate(ends):
        n = max(2, int(round(np.linalg.norm(Tb[:3, 3] - Ta[:3, 3]) / PREDICTION_STEP_M)) + 1)
        origins.append(np.linspace(Ta[:3, 3], Tb[:3, 3], n))
        owner.append(np.full(n, k))
    starts = np.vstack(origins)
    who = np.concatenate(owner)
    o, d = _to_workpiece(T_world_workpiece, starts, beam)
    hit, P, face = raycast_parallel(workpiece.mesh.vertices, workpiece.mesh.faces, o, d)
    dist = np.einsum("ij,j->i", np.nan_to_num(P) - o, d)
    n_face = workpiece.mesh.face_normals[np.maximum(face, 0)]
    incidence = np.arccos(np.clip(-(n_face @ d), -1.0, 1.0))
    ok = hit & (dist >= geometry.window_m[0]) & (dist <= geometry.window_m[1]) & \
        (incidence <= geometry.max_incidence_rad)
    return [Prediction(P[ok & (who == k)], face[ok & (who == k)], dist[ok & (who == k)]) for k in range(len(ends))]
