"""Evaluation against the truth: the only module that reads what only the simulator knows.

Reports, figures, recordings and studies measure against the truth through an
:class:`Evaluation` of the realized scenario (or the functions below); no other module opens
the truth (``tests/test_architecture.py`` checks it). Every function returns SI values
(metres, radians); :mod:`twin.io.report` turns them into the report's unit-named fields.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithms.geometry.kinematics import dh_forward
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, rotation_error_rad, transform_points, translation_error_m
from algorithms.paths.normals import angle_deg, pca_normals
from algorithms.probing.qualification import cosine_error_m
from algorithms.registration.uncertainty import information_rows, part_symmetry_directions, pose_error_twist
from twin.realize import Realized
from twin.robot import UR5E_DH


def surface_error_m(points_base: np.ndarray, T_base_workpiece_true: np.ndarray, index: MeshIndex) -> np.ndarray:
    """Signed distance [m] of base-frame points to the TRUE part surface (positive outside)."""
    p = transform_points(inv_pose(T_base_workpiece_true), points_base)
    cp = index.query(p)
    s = np.sign(np.einsum("ij,ij->i", p - cp.foot, cp.normal))
    s[s == 0] = 1.0
    return s * cp.distance


def true_normals_base(points_base: np.ndarray, T_base_workpiece_true: np.ndarray, index: MeshIndex) -> np.ndarray:
    """Smooth normals of the TRUE surface at the feet of base-frame points, base frame."""
    p = transform_points(inv_pose(T_base_workpiece_true), points_base)
    cp = index.query(p)
    return index.smooth_normals(cp.face, cp.foot) @ T_base_workpiece_true[:3, :3].T


@dataclass(frozen=True)
class Evaluation:
    """The truth of one realized scenario, opened for evaluation only (robot base frame, SI).

    Attributes:
        realized: the realized scenario whose truth is measured against.
    """

    realized: Realized

    @property
    def T_base_workpiece(self) -> np.ndarray:
        """(4, 4) the part's true pose in the robot base frame."""
        return self.realized.T_base_workpiece_true

    def surface_error_m(self, points_base: np.ndarray) -> np.ndarray:
        """(N,) signed distance [m] of base-frame points to the true surface (positive outside)."""
        return surface_error_m(points_base, self.T_base_workpiece, self.realized.workpiece.index)

    def in_true_workpiece(self, points_base: np.ndarray) -> np.ndarray:
        """(N, 3) base-frame points in the true workpiece frame [m]."""
        return transform_points(inv_pose(self.T_base_workpiece), points_base)

    def pose_errors(self, T_base_workpiece_estimate: np.ndarray) -> PoseErrors:
        """Rotation and translation errors of an estimate and of the nominal pose."""
        return pose_errors(T_base_workpiece_estimate, self.realized)

    def full_pose_errors(self, T_base_workpiece_estimate: np.ndarray, covariance: np.ndarray | None = None) -> dict:
        """:func:`full_pose_errors` of an estimate against the true pose."""
        return full_pose_errors(T_base_workpiece_estimate, self.T_base_workpiece, covariance)


def ideal_distances_m(scan) -> np.ndarray:
    """(N, B) the scan's ideal distances [m] (-1 where the beam missed): where each beam met the
    true part, before the sensor's errors."""
    return scan.d_true


def true_pretravel_m(hit) -> float | None:
    """The pre-travel [m] the simulator drew for a probe hit, or None for a miss."""
    return None if hit.truth is None else float(hit.truth.pretravel_m)


def true_part_pose_world(setup) -> np.ndarray:
    """(4, 4) where the part truly lies on the CMM's table (world frame)."""
    return setup.T_world_part_true


@dataclass(frozen=True)
class PoseErrors:
    """Rotation [rad] and translation [m] errors of an estimate and of the nominal pose."""

    rotation_rad: float
    translation_m: float
    nominal_rotation_rad: float
    nominal_translation_m: float


def pose_errors(T_base_workpiece_estimate: np.ndarray, realized: Realized) -> PoseErrors:
    T_true, T_nom = realized.T_base_workpiece_true, realized.T_base_workpiece_nominal
    return PoseErrors(rotation_error_rad(T_base_workpiece_estimate, T_true),
                      translation_error_m(T_base_workpiece_estimate, T_true),
                      rotation_error_rad(T_nom, T_true), translation_error_m(T_nom, T_true))


@dataclass(frozen=True)
class ScanErrors:
    """Points against the true surface and servo tracking of a scan (SI units).

    Attributes:
        points_on_part, points_on_table: valid points nearer the part / the table plane.
        residual_m: (M,) distance of each on-part point to the true surface [m].
        tracking_m: (N,) sensor-origin distance between commanded and true joints [m].
    """

    points_on_part: int
    points_on_table: int
    residual_m: np.ndarray
    tracking_m: np.ndarray


def scan_errors(scan, realized: Realized) -> ScanErrors:
    pts = scan.valid_points_base
    p_wp = transform_points(inv_pose(realized.T_base_workpiece_true), pts)
    to_part = realized.workpiece.index.query(p_wp).distance if len(pts) else np.empty(0)
    to_table = np.abs(transform_points(realized.scenario.T_world_base, pts)[:, 2])
    on_part = to_part <= to_table
    T_ref = dh_forward(scan.q_ref, UR5E_DH) @ scan.T_flange_sensor_nominal
    T_act = dh_forward(scan.q_true, UR5E_DH) @ scan.T_flange_sensor_nominal
    dev = np.linalg.norm(T_ref[:, :3, 3] - T_act[:, :3, 3], axis=1)
    return ScanErrors(int(on_part.sum()), int((~on_part).sum()), to_part[on_part], dev)


@dataclass(frozen=True)
class ScanPathErrors:
    """The scan-derived contact points and normals against the true surface.

    Attributes:
        surface_m: (M,) signed distance of the fitted contact points to the true surface [m].
        normals_triangulation_deg, normals_pca_deg, tool_normals_deg: (M,) angles to the true
            normals [deg] (PCA with k = 16, unsigned).
    """

    surface_m: np.ndarray
    normals_triangulation_deg: np.ndarray
    normals_pca_deg: np.ndarray
    tool_normals_deg: np.ndarray


def scan_path_errors(points: np.ndarray, normals: np.ndarray, tool_normals: np.ndarray,
                     realized: Realized) -> ScanPathErrors:
    T_true, index = realized.T_base_workpiece_true, realized.workpiece.index
    n_true = true_normals_base(points, T_true, index)
    return ScanPathErrors(surface_error_m(points, T_true, index), angle_deg(normals, n_true),
                          angle_deg(pca_normals(points, 16), n_true, unsigned=True), angle_deg(tool_normals, n_true))


def determined_errors(localization, realized: Realized, covariance=None) -> dict:
    """The estimate's error against the truth along its determined directions only.

    The error twist ``xi`` (``T_est = T_true exp(xi)``, workpiece frame) is split over the
    determined and free directions; the determined part is compared with the Cramer-Rao
    standard deviations of ``covariance`` (default: ``localization.covariance``). Returns lists (rad or m per
    direction) and the largest error in standard deviations.
    """
    D = np.asarray(localization.determined_directions, dtype=np.float64).reshape(-1, 6)
    F = np.asarray(localization.free_directions, dtype=np.float64).reshape(-1, 6)
    if len(D) == 0:
        return {"std": [], "error": [], "sigmas": [], "max_sigmas": None}
    xi = pose_error_twist(localization.T_world_workpiece, realized.T_base_workpiece_true)
    coef = np.linalg.lstsq(np.vstack([D, F]).T, xi, rcond=None)[0][: len(D)]
    C = localization.covariance if covariance is None else covariance
    std = np.sqrt(np.clip(np.diag(np.asarray(C, dtype=np.float64)), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        sig = np.abs(coef) / std
    return {"std": [float(v) for v in std], "error": [float(v) for v in coef],
            "sigmas": [round(float(v), 3) for v in sig], "max_sigmas": round(float(np.max(sig)), 3)}


def localization_trusted(localization) -> bool:
    """Whether the loop may act on the estimate: ``ok``, or, from the symmetric localization
    (document 000, Algorithm 2), ``unobservable``/``ambiguous`` with the fit consistent with
    the noise: the free directions are a symmetry of what was scanned, and the pose is
    determined (and used) in the others; the report lists both.
    """
    status = localization.status.value
    if localization.poor_fit_reason:
        return False
    return status in ("ok", "unobservable", "ambiguous")


def free_directions_part_symmetry(localization, index: MeshIndex) -> list[bool]:
    """For each free direction: whether it is a symmetry of the whole CAD model (a sphere's
    rotations) rather than only of the scanned surfaces (a bore's axis on a block)."""
    F = np.asarray(localization.free_directions, dtype=np.float64).reshape(-1, 6)
    return [bool(v) for v in part_symmetry_directions(index, F)] if len(F) else []


def contact_std_m(path_workpiece, localization, covariance) -> float:
    """The largest standard deviation, along its normal, of a CAD path contact point moved by
    the estimate: the pose covariance (along the determined directions) propagated."""
    D = np.asarray(localization.determined_directions, dtype=np.float64).reshape(-1, 6)
    if len(D) == 0:
        return 0.0
    mask = path_workpiece.process_mask()
    p, n = path_workpiece.contact[mask], path_workpiece.normal[mask]
    A = information_rows(p, n) @ D.T
    C = np.asarray(localization.covariance if covariance is None else covariance, dtype=np.float64)
    return float(np.sqrt(np.max(np.einsum("ij,jk,ik->i", A, C, A))))


def true_effective_radius_m(probe) -> float:
    """What qualification should find: the nominal ball radius minus the mean sideways
    pre-travel of the probe's model (the equator touches; the pole's axial excess goes into
    the ball-centre offset, :func:`twin.qualification.qualification_targets`)."""
    return float(probe.ball_radius_m - probe.stylus_length_m / probe.reference_stylus_m * probe.lateral_pretravel_m)


def full_pose_errors(T_estimate: np.ndarray, T_true: np.ndarray, covariance: np.ndarray | None) -> dict:
    """Rotation [rad] and translation [m] errors of a pose fixed in all six directions, its
    error twist ``[omega, v]`` (workpiece frame) and, with a (6, 6) covariance, each
    component in standard deviations and the Mahalanobis distance."""
    xi = pose_error_twist(T_estimate, T_true)
    out = {"rotation_rad": rotation_error_rad(T_estimate, T_true),
           "translation_m": translation_error_m(T_estimate, T_true), "twist": xi}
    if covariance is not None:
        C = np.asarray(covariance, dtype=np.float64)
        std = np.sqrt(np.clip(np.diag(C), 0.0, None))
        out["std"] = std
        out["sigmas"] = np.abs(xi) / std
        out["mahalanobis"] = float(np.sqrt(xi @ np.linalg.solve(C, xi)))
    return out


def cosine_errors_m(hits, T_base_workpiece: np.ndarray, effective_radius_m: float, realized: Realized) -> np.ndarray:
    """(n,) the r (1 - cos theta) error the radius compensation leaves at each hit when its
    normals come from the CAD model at ``T_base_workpiece``: theta between that normal and
    the true surface normal at the true contact."""
    index = realized.workpiece.index
    T_true = realized.T_base_workpiece_true
    out = []
    for h in hits:
        c_est = transform_points(inv_pose(T_base_workpiece), h.centre[None])
        cp = index.query(c_est)
        n_est = index.smooth_normals(cp.face, cp.foot)[0] @ T_base_workpiece[:3, :3].T
        n_true = true_normals_base(h.truth.centre_touch[None], T_true, index)[0]
        out.append(cosine_error_m(effective_radius_m, float(np.arccos(np.clip(n_est @ n_true, -1.0, 1.0)))))
    return np.asarray(out, dtype=np.float64)
