"""Scenario files (TOML): load, validate every key and value, and hold them as frozen dataclasses.

A scenario describes one cell: the workpiece and its TRUE and NOMINAL poses, the robot base,
the laser sensor, the error sources switched on, the scan plan and the seed. Every key is
documented in ``docs/concepts/scenario-files.md`` (every key with its default, generated from
this validator: the documentation's "Scenario keys"); unknown keys are an error.

Poses are written either as ``{ xyz = [x, y, z], rpy_deg = [roll, pitch, yaw] }`` (metres,
degrees, extrinsic x-y-z rotations) or as ``{ matrix = [[...4x4...]] }``.
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, overload

import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import as_pose
from twin.errors import TwinError
from twin.formats.toml_files import read_toml

SENSOR_WINDOW_M = (0.055, 0.105)  # Keyence IL-065 measuring window

#: While a list, every key the validator reads is noted in it as ``(table, key, kind, default,
#: allowed, given)``: the scenario key reference is generated from these notes
#: (:func:`twin.schema.scenario_keys`), so it lists exactly what the validator accepts.
KEY_LOG: list[tuple[str, str, str, Any, str, bool]] | None = None


def pose_from_table(value: Any, where: str) -> np.ndarray:
    """Parse a pose table into a (4, 4) rigid transform, or raise TwinError naming ``where``."""
    if not isinstance(value, dict):
        raise TwinError(f"{where} must be a table with xyz/rpy_deg or matrix, got {type(value).__name__}")
    keys = set(value)
    if "matrix" in keys:
        if keys != {"matrix"}:
            raise TwinError(f"{where}: give either 'matrix' or 'xyz'/'rpy_deg', not both ({sorted(keys)})")
        try:
            T = np.asarray(value["matrix"], dtype=np.float64)
        except (TypeError, ValueError):
            raise TwinError(f"{where}.matrix must be a 4x4 list of numbers") from None
        try:
            return as_pose(T, f"{where}.matrix")
        except AlgorithmError as exc:
            raise TwinError(str(exc)) from None
    unknown = keys - {"xyz", "rpy_deg"}
    if unknown:
        raise TwinError(f"{where}: unknown key(s) {sorted(unknown)}; allowed: matrix, or xyz and rpy_deg")
    xyz = _vector(value.get("xyz", [0.0, 0.0, 0.0]), 3, f"{where}.xyz")
    rpy = _vector(value.get("rpy_deg", [0.0, 0.0, 0.0]), 3, f"{where}.rpy_deg")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy, degrees=True).as_matrix()
    T[:3, 3] = xyz
    return T


def _vector(value: Any, n: int, where: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != n or not all(_is_number(v) for v in value):
        raise TwinError(f"{where} must be a list of {n} numbers, got {value!r}")
    out = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(out)):
        raise TwinError(f"{where} must be finite, got {value!r}")
    return out


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


class _Section:
    """Reads one TOML table, checking each key once and refusing the rest."""

    def __init__(self, table: Any, where: str) -> None:
        if not isinstance(table, dict):
            raise TwinError(f"[{where}] must be a table, got {type(table).__name__}")
        self.table = dict(table)
        self.where = where
        self.allowed: list[str] = []

    def _get(self, key: str, default: Any, kind: str = "value", allowed: str = "") -> Any:
        self.allowed.append(key)
        if KEY_LOG is not None:
            KEY_LOG.append((self.where, key, kind, default, allowed, key in self.table))
        return self.table.pop(key, default)

    def number(self, key: str, default: float, lo: float = -np.inf, hi: float = np.inf,
               lo_open: bool = False) -> float:
        rng = f"({lo:g}, {hi:g}]" if lo_open else f"[{lo:g}, {hi:g}]"
        v = self._get(key, default, "number", rng)
        if not _is_number(v) or not np.isfinite(v):
            raise TwinError(f"{self.where}.{key} must be a finite number, got {v!r}")
        if v < lo or v > hi or (lo_open and v <= lo):
            raise TwinError(f"{self.where}.{key} = {v!r} is outside the allowed range {rng}")
        return float(v)

    def integer(self, key: str, default: int, lo: int, hi: int) -> int:
        v = self._get(key, default, "integer", f"[{lo}, {hi}]")
        if not isinstance(v, int) or isinstance(v, bool) or v < lo or v > hi:
            raise TwinError(f"{self.where}.{key} must be an integer in [{lo}, {hi}], got {v!r}")
        return int(v)

    def boolean(self, key: str, default: bool) -> bool:
        v = self._get(key, default, "boolean", "true, false")
        if not isinstance(v, bool):
            raise TwinError(f"{self.where}.{key} must be true or false, got {v!r}")
        return v

    @overload
    def choice(self, key: str, default: str, choices: tuple[str, ...]) -> str: ...

    @overload
    def choice(self, key: str, default: None, choices: tuple[str, ...]) -> str | None: ...

    def choice(self, key: str, default: str | None, choices: tuple[str, ...]) -> str | None:
        """One of ``choices``; None only when the key is absent and ``default`` is None."""
        v = self._get(key, default, "string", ", ".join(f'"{c}"' for c in choices))
        if v is None and default is None:
            return None
        if v not in choices:
            raise TwinError(f"{self.where}.{key} = {v!r} is not one of {', '.join(choices)}")
        return v

    @overload
    def string(self, key: str, default: str) -> str: ...

    @overload
    def string(self, key: str, default: None) -> str | None: ...

    def string(self, key: str, default: str | None) -> str | None:
        """A string; None only when the key is absent and ``default`` is None."""
        v = self._get(key, default, "string")
        if v is not None and not isinstance(v, str):
            raise TwinError(f"{self.where}.{key} must be a string, got {v!r}")
        return v

    def pose(self, key: str, default: np.ndarray | None = None) -> np.ndarray:
        given = key in self.table
        v = self._get(key, "required" if default is None else default, "pose",
                      "{ xyz = [x, y, z], rpy_deg = [r, p, y] } or { matrix = 4x4 }")
        if not given:
            if default is None:
                raise TwinError(f"{self.where}.{key} is required (a pose: xyz/rpy_deg or matrix)")
            return default.copy()
        return pose_from_table(v, f"{self.where}.{key}")

    @overload
    def vector(self, key: str, default: list[float], n: int) -> np.ndarray: ...

    @overload
    def vector(self, key: str, default: None, n: int) -> np.ndarray | None: ...

    def vector(self, key: str, default: list[float] | None, n: int) -> np.ndarray | None:
        """An (n,) float array; None only when the key is absent and ``default`` is None."""
        v = self._get(key, default, "list", f"{n} finite numbers")
        if v is None:
            return None
        return _vector(v, n, f"{self.where}.{key}")

    def table_value(self, key: str) -> dict:
        v = self._get(key, {}, "table")
        if not isinstance(v, dict):
            raise TwinError(f"{self.where}.{key} must be a table, got {v!r}")
        return v

    def done(self) -> None:
        if self.table:
            bad = sorted(self.table)
            raise TwinError(
                f"unknown key(s) {', '.join(self.where + '.' + k for k in bad)}; "
                f"allowed in [{self.where}]: {', '.join(self.allowed)}"
            )


@dataclass(frozen=True)
class WorkpieceSpec:
    """The part: a generated seed part (``shape``) or a user mesh (``mesh`` + ``units``)."""

    shape: str | None
    mesh: str | None
    units: str
    params: dict
    T_world_workpiece_true: np.ndarray
    T_world_workpiece_nominal: np.ndarray


@dataclass(frozen=True)
class SensorSpec:
    """Laser displacement sensor (defaults: Keyence IL-065).

    Attributes:
        kind: "point" (one beam) or "line" (a fan of ``beams`` beams, ``fan_deg`` wide).
        window_m: measuring window [m] along the beam.
        reference_m: reference distance (stand-off) [m].
        sample_period_s: sampling period [s].
        sigma_m: repeatability, 1-sigma Gaussian noise at normal incidence [m].
        linearity_m: amplitude of the systematic linearity error curve [m].
        linearity_phase_deg: phase of that curve [deg] (:func:`twin.sensors.laser.linearity_error_m`),
            or None: unknown, drawn for each realization of the scenario (one sensor unit of
            the model, :func:`twin.realize.draw_truth`).
        resolution_m: output resolution (quantisation step) [m].
        max_incidence_deg: beyond this angle between beam and surface normal, no return.
        baseline_m: triangulation baseline: receiver offset from the emitter along sensor +x [m].
        T_flange_sensor: (4, 4) true hand-eye transform (sensor frame in the flange frame).
    """

    kind: str
    window_m: tuple[float, float]
    reference_m: float
    sample_period_s: float
    sigma_m: float
    linearity_m: float
    resolution_m: float
    max_incidence_deg: float
    baseline_m: float
    beams: int
    fan_deg: float
    T_flange_sensor: np.ndarray
    linearity_phase_deg: float | None = 0.0


@dataclass(frozen=True)
class NoiseSpec:
    """Error-source switches. Sensor effects default on; robot-side errors default off."""

    gaussian: bool
    linearity: bool
    quantization: bool
    incidence: bool
    occlusion: bool
    encoder_sigma_rad: float
    time_skew_s: float
    kinematic_sigma_m: float
    kinematic_sigma_rad: float
    T_hand_eye_error: np.ndarray

    def all_off(self) -> NoiseSpec:
        return NoiseSpec(False, False, False, False, False, 0.0, 0.0, 0.0, 0.0, np.eye(4))


@dataclass(frozen=True)
class PassSpec:
    """One pass of a multi-pass scan (``[[scan.passes]]``), defined on the CAD model.

    Scan lines are laid on a plane normal to ``view``; planning rays are cast along ``view``
    at the nominal CAD model and each line keeps the runs of consecutive hits, split at sharp
    edges and steps (see :mod:`twin.plan`).

    Attributes:
        name: label of the pass in plans and reports.
        beam: "fixed" (the beam along ``view``) or "normal" (along the smoothed surface normal).
        view: (3,) unit planning-ray direction in the workpiece frame (the beam when fixed).
        region_m: ((xmin, ymin, zmin), (xmax, ymax, zmax)) box in the workpiece frame [m]
            (or ((xmin, ymin), (xmax, ymax)): any height): only hits inside it are scanned;
            None for the whole part.
        line_axis: (3,) unit direction the lines run along, in the workpiece frame (projected
            onto the plane normal to ``view``).
        line_spacing_m, speed_m_s, transit_speed_m_s, standoff_m, retract_m: as in ScanSpec.
        edge_margin_m: each line ends this far (arc length) before a part edge or step [m].
        max_lines: keep only the first N lines of the pass.
    """

    name: str
    beam: str
    view: np.ndarray
    region_m: tuple[tuple[float, ...], tuple[float, ...]] | None
    line_axis: np.ndarray
    line_spacing_m: float
    speed_m_s: float
    transit_speed_m_s: float
    standoff_m: float
    retract_m: float
    edge_margin_m: float
    max_lines: int


@dataclass(frozen=True)
class AutoPlanSpec:
    """Settings of the automatic multi-pass planner (``scan.passes = "auto"``, :mod:`twin.plan`).

    Attributes:
        tilts_deg: tilts of the candidate views from straight down [deg] (besides straight down).
        azimuths: number of candidate azimuths per tilt, evenly spaced from the workpiece +x.
        max_passes: the most passes planned.
        min_relative_eigenvalue: views are added until the predicted information's smallest
            relative eigenvalue reaches this.
    """

    tilts_deg: tuple[float, ...]
    azimuths: int
    max_passes: int
    min_relative_eigenvalue: float


@dataclass(frozen=True)
class ScanSpec:
    """Raster scan plan, defined on the CAD model at the nominal pose.

    Attributes:
        region_m: ((xmin, ymin), (xmax, ymax)) in the workpiece frame [m], or None for the
            part's footprint shrunk by ``margin_m``.
        line_spacing_m: distance between scan lines [m].
        speed_m_s: scan speed along a line [m/s].
        transit_speed_m_s: speed of approach, retract and line-change moves [m/s].
        standoff_m: sensor-to-surface distance along the beam [m] (default: the reference).
        beam: "normal" (beam along the surface normal) or "fixed" (along ``direction``).
        direction: (3,) fixed beam direction in the workpiece frame.
        retract_m: lift above the stand-off between lines [m].
        line_axis: "x" or "y": workpiece axis the lines run along.
        passes: None (one pass from the keys above), or the explicit passes in order.
        auto: the automatic planner's settings when ``passes = "auto"``, else None.
        transit_clearance_m: between passes the sensor moves at least this far above the
            part's top [m].
    """

    region_m: tuple[tuple[float, float], tuple[float, float]] | None
    margin_m: float
    line_spacing_m: float
    speed_m_s: float
    transit_speed_m_s: float
    standoff_m: float
    beam: str
    direction: np.ndarray
    retract_m: float
    line_axis: str
    max_lines: int
    passes: tuple[PassSpec, ...] | None = None
    auto: AutoPlanSpec | None = None
    transit_clearance_m: float = 0.03


@dataclass(frozen=True)
class PathSpec:
    """Process path, from the scan (document 004) or from the CAD model (document 003 step 5).

    The process is a contact process (polishing, deburring) with a ball-end tool on the
    flange: the tool tip touches the surface at the contact points. Every key of the
    ``[path]`` table is optional; the defaults are below.

    Attributes:
        T_flange_tool: (4, 4) tool frame (TCP: the tip of the tool on its axis) in the flange
            frame, ``tool`` key (default 100 mm along the flange z, turned 180 deg about x
            so that the tool z points back out of the surface, as eq. 11's normal does).
        tip_radius_m: ball-end radius [m] (0 for a point tip).
        shank_radius_m: radius of the shank between the holder and the ball [m].
        holder_radius_m: radius of the holder at the flange [m].
        holder_length_m: length of the holder from the flange face [m].
        feed_m_s: feed rate along the contact lines [m/s].
        transit_speed_m_s: speed of approach, retract and transit moves [m/s].
        acceleration_m_s2: path acceleration limit of process lines and transits [m/s^2].
        touchdown_acceleration_m_s2: acceleration limit of the approach and retract moves along
            the tool axis [m/s^2]: the servo lag in the deceleration before touch-down pushes
            the tool into the part in proportion to it, so it is low.
        point_spacing_m: spacing of the contact points along a line [m].
        line_spacing_m: spacing of the lines of the CAD raster path [m].
        margin_m: the CAD raster stays this far inside the part's footprint [m].
        line_axis: "x" or "y": workpiece axis the CAD raster lines run along.
        retract_m: lift along the tool axis before and after each line [m].
        heading: "smooth" (tool x starts along ``heading_direction`` on each line and turns as
            little as possible about the tool axis), "fixed" (x along ``heading_direction``
            projected on the plane normal to the axis) or "travel" (eq. 11: along the travel).
        heading_direction: (3,) in the workpiece frame.
        axis: "normal" (tool axis along the surface normal, eq. 11) or "fixed".
        axis_direction: (3,) tool axis in the workpiece frame for ``axis = "fixed"``.
        lead_deg: tilt of the tool axis towards +x of the contact frame [deg].
        tilt_deg: tilt of the tool axis towards +y of the contact frame [deg].
        knot_spacing_m: arc length per knot span of the per-line B-spline fits [m].
        simplify_spacing_m: bin length of the even-spacing simplification [m].
        outlier_window_m: window of the robust outlier filter [m].
        outlier_k: rejection threshold in robust sigmas.
        max_gap_m: a gap wider than this splits a scan line (part boundary) [m].
        empty_lines: "error" (a scan line without valid points is an error) or "drop".
        region_axis: (3,) axis of the process region's normal cone, workpiece frame.
        region_cone_deg: the surfaces whose normal lies within this angle of ``region_axis``
            are processed (default 60: what a ball-end tool reaches from above).
        region_box_m: ((x, y, z), (x, y, z)) corners of a box the processed points must lie
            in (workpiece frame), or None.
        max_tilt_deg: the ball-end tool may tilt its axis this far from the surface normal,
            about the ball's centre (the contact point stays the same), where the shank or
            holder would otherwise come too close to the part [deg]; 0: the axis stays on the
            normal (eq. 11).
        region_features: names of the part's CAD features (faces of a generated part, e.g.
            "hemisphere", "plate_top") the processed points must also lie on; () : any.
    """

    T_flange_tool: np.ndarray
    tip_radius_m: float
    shank_radius_m: float
    holder_radius_m: float
    holder_length_m: float
    feed_m_s: float
    transit_speed_m_s: float
    acceleration_m_s2: float
    touchdown_acceleration_m_s2: float
    point_spacing_m: float
    line_spacing_m: float
    margin_m: float
    line_axis: str
    retract_m: float
    heading: str
    heading_direction: np.ndarray
    axis: str
    axis_direction: np.ndarray
    lead_deg: float
    tilt_deg: float
    knot_spacing_m: float
    simplify_spacing_m: float
    outlier_window_m: float
    outlier_k: float
    max_gap_m: float
    empty_lines: str
    region_axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    region_cone_deg: float = 60.0
    region_box_m: tuple | None = None
    max_tilt_deg: float = 0.0
    region_features: tuple = ()


@dataclass(frozen=True)
class ProbeSpec:
    """A touch-trigger probe on the flange, beside the laser (``[probe]``; defaults: a
    Renishaw TP20 class probe (body 13.2 mm across) with its standard-force module on a
    50 mm extension bar, so the ball reaches 76 mm below the laser's housing, and a 20 mm
    M2 stylus with a 2 mm ball).

    Geometry (probe frame: z along the stylus, from the probe body to the ball; the body's
    back face at the origin):
        T_flange_probe: (4, 4) probe frame in the flange frame (the believed mount).
        body_radius_m, body_length_m: the extension, probe body and module as one cylinder [m].
        stylus_length_m: from the module's face to the ball centre [m]; stylus_radius_m its stem.
        ball_radius_m: the stylus ball's nominal radius [m].
    Trigger (:class:`algorithms.probing.pretravel.PretravelModel`, at ``reference_stylus_m``):
        lateral_pretravel_m, lobe_m, lobe_phase_deg, axial_pretravel_m, reference_stylus_m,
        repeatability_2sigma_m (unidirectional repeatability, 2 sigma, as data sheets give it).
    Moves:
        approach_m: the probing move starts this far off the expected surface [m];
        search_m: and goes on this far past it before it is reported a miss [m];
        probing_speed_m_s, transit_speed_m_s [m/s]; stop_deceleration_m_s2: the arm's braking
        after a trigger [m/s^2]; clearance_m: the stylus and body keep this far from the part
        on planned moves [m]; safe_height_m: transits between points run this far above the
        part's top [m].
    Qualification:
        sphere_xyz_m: (3,) the reference sphere's centre, world frame (a calibrated fixture of
        the cell) [m]; sphere_radius_m; qualification_points: probed on its equator, plus its pole.
    Fine points:
        points: the number of planned probe points (m >= 6); edge_margin_m: each lies this far
        from an edge of its face; candidate_spacing_m: spacing of the candidate points.
    """

    T_flange_probe: np.ndarray
    body_radius_m: float
    body_length_m: float
    stylus_length_m: float
    stylus_radius_m: float
    ball_radius_m: float
    lateral_pretravel_m: float
    lobe_m: float
    lobe_phase_deg: float
    axial_pretravel_m: float
    reference_stylus_m: float
    repeatability_2sigma_m: float
    approach_m: float
    search_m: float
    probing_speed_m_s: float
    transit_speed_m_s: float
    stop_deceleration_m_s2: float
    clearance_m: float
    safe_height_m: float
    sphere_xyz_m: np.ndarray
    sphere_radius_m: float
    qualification_points: int
    points: int
    edge_margin_m: float
    candidate_spacing_m: float

    @property
    def tip_length_m(self) -> float:
        """Ball centre's distance from the probe frame's origin along its z [m]."""
        return self.body_length_m + self.stylus_length_m


@dataclass(frozen=True)
class LocateSpec:
    """Document 001's hierarchy (``[locate]``, :mod:`twin.workflows.locate`).

    Attributes:
        coarse: "multistart" (document 000's Algorithm 5), "ga" (document 001's genetic
            algorithm with its constants, one run as the document does) or "ga_restarts"
            (up to ten runs, each checked by a short exact descent).
        coarse_line_spacing_m: line spacing of the sparse coarse laser pass [m].
        coarse_speed_m_s: its scan speed [m/s].
        coarse_margin_m: the coarse pass covers the nominal part's footprint grown by this on
            every side [m] (the part may lie tens of millimetres off its nominal place).
        planner: "d_optimal" (default), "spread" or "random" choice of the fine probe points.
    """

    coarse: str = "multistart"
    coarse_line_spacing_m: float = 0.010
    coarse_speed_m_s: float = 0.10
    coarse_margin_m: float = 0.04
    planner: str = "d_optimal"


@dataclass(frozen=True)
class CmmSpec:
    """The coordinate measuring machine of a ``machine = "cmm"`` scenario (``[cmm]``).

    The machine itself (axes, ranges, servos, speed and acceleration limits) is the model in
    ``models/cmm``; the probe on its head is the scenario's ``[probe]`` (body, stylus, ball,
    trigger). These keys say how a program runs on it.

    Attributes:
        styli: stylus name -> (A, B) head angles [deg]: A tilts the probe from straight down,
            B turns it about the vertical; the probe points along
            (sin A cos B, sin A sin B, -cos A) in the machine frame.
        transit_speed_m_s: speed of the GOTO and approach moves [m/s] (at most the machine's).
        acceleration_m_s2: acceleration of every move [m/s^2] (at most the machine's).
        index_time_s: time the head takes to index to another stylus [s].
        clearance_m: every solid of the probe keeps this far from the part on planned moves [m].
        encoder_sigma_m: noise of the scale readings latched at a trigger [m] (1 sigma).
    """

    styli: dict
    transit_speed_m_s: float = 0.15
    acceleration_m_s2: float = 1.0
    index_time_s: float = 1.5
    clearance_m: float = 0.001
    encoder_sigma_m: float = 1e-7

    def direction(self, name: str) -> np.ndarray:
        """The unit probe direction of a stylus in the machine frame."""
        a, b = np.radians(self.styli[name])
        return np.array([np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), -np.cos(a)])


@dataclass(frozen=True)
class ToleranceSpec:
    """What a finished command must meet to pass (``[tolerances]``, every key optional). A
    command that finishes outside them exits 3 and names the failed check (``twin run``:
    :mod:`twin.verdicts`).

    Attributes:
        min_process_coverage: ``twin run``: the fraction of each process path's planned contact
            points that must be kept (not dropped as unreachable, singular, discontinuous or
            colliding) [0-1].
        max_replay_deviation_m: ``twin run``: the largest distance of the replayed tool centre
            from its planned path on the process lines [m].
        max_tip_penetration_m: ``twin run``: the deepest the replayed ball end may go into the
            true part on the process lines [m].
        max_position_uncertainty_m: ``twin locate``: the largest expanded uncertainty (k = 2)
            of the final pose along a translation axis [m].
        max_rotation_uncertainty_rad: ``twin locate``: the same about a rotation axis [rad].
        max_surface_deviation_m: the surface profile tolerance: the largest signed deviation of a
            measured point from the CAD model at the estimated pose that is in tolerance [m]; the
            green band of the deviation map (:mod:`twin.deviation`), reported, not decided on.
    """

    min_process_coverage: float = 0.95
    max_replay_deviation_m: float = 0.5e-3
    max_tip_penetration_m: float = 0.3e-3
    max_position_uncertainty_m: float = 10e-6
    max_rotation_uncertainty_rad: float = 2e-4
    max_surface_deviation_m: float = 0.05e-3


MACHINES = ("arm", "cmm")
COARSE_METHODS = ("multistart", "ga", "ga_restarts")
PROBE_PLANNERS = ("d_optimal", "spread", "random")


@dataclass(frozen=True)
class Scenario:
    name: str
    seed: int
    workpiece: WorkpieceSpec
    T_world_base: np.ndarray
    sensor: SensorSpec
    noise: NoiseSpec
    scan: ScanSpec
    source: str = ""
    raw: dict = field(default_factory=dict, repr=False)
    path: PathSpec = field(default_factory=lambda: _parse_path(_Section({}, "path")))
    probe: ProbeSpec | None = None
    locate: LocateSpec = field(default_factory=LocateSpec)
    machine: str = "arm"
    cmm: CmmSpec | None = None
    tolerances: ToleranceSpec = field(default_factory=ToleranceSpec)

    def to_dict(self) -> dict:
        """A JSON-ready copy (numpy arrays as nested lists)."""
        def conv(x):
            if isinstance(x, np.ndarray):
                return x.tolist()
            if isinstance(x, dict):
                return {k: conv(v) for k, v in x.items() if k != "raw"}
            if isinstance(x, (list, tuple)):
                return [conv(v) for v in x]
            return x
        return conv(asdict(self))


def load_scenario(path: str | Path, overrides: dict | None = None, machine: str | None = None) -> Scenario:
    """Read and validate a scenario TOML file; raise TwinError with one clear line on any problem.

    Args:
        path: the TOML file.
        overrides: nested tables merged over the file before validation, e.g.
            ``{"scan": {"max_lines": 3}, "noise": {"gaussian": False}}``; a pose table
            replaces the file's pose as a whole.
        machine: "arm" or "cmm": refuse a scenario for the other machine.
    """
    path = Path(path)
    raw = read_toml(path, "scenario")
    if overrides:
        raw = merge_tables(raw, overrides)
    scenario = parse_scenario(raw, name=path.stem, base_dir=path.parent, source=str(path))
    if machine is not None and scenario.machine != machine:
        other = "twin cmm" if scenario.machine == "cmm" else "twin run, scan, demo, locate or study"
        raise TwinError(f"scenario {path} is for machine = {scenario.machine!r}; this command needs machine = "
                        f"{machine!r} (use {other})")
    return scenario


def merge_tables(base: dict, over: dict) -> dict:
    """``base`` with ``over`` merged in, table by table (pose tables are replaced whole)."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict) and not ({"xyz", "rpy_deg", "matrix"} & set(v)):
            out[k] = merge_tables(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def parse_scenario(raw: dict, name: str = "scenario", base_dir: Path | None = None,
                   source: str = "") -> Scenario:
    top = _Section(raw, name)
    seed = top.integer("seed", 0, 0, 2**63 - 1)
    title = top.string("name", name)
    wp = _parse_workpiece(_Section(top.table_value("workpiece"), "workpiece"), base_dir)
    robot = _Section(top.table_value("robot"), "robot")
    T_world_base = robot.pose("base_pose", np.eye(4))
    robot.done()
    sensor = _parse_sensor(_Section(top.table_value("sensor"), "sensor"))
    noise = _parse_noise(_Section(top.table_value("noise"), "noise"))
    scan = _parse_scan(_Section(top.table_value("scan"), "scan"), sensor)
    path = _parse_path(_Section(top.table_value("path"), "path"))
    probe_table = top._get("probe", None, "table", "the touch probe (its keys: [probe] below)")
    probe = None if probe_table is None else _parse_probe(_Section(probe_table, "probe"))
    locate = _parse_locate(_Section(top.table_value("locate"), "locate"))
    machine = str(top.choice("machine", "arm", MACHINES))
    tolerances = _parse_tolerances(_Section(top.table_value("tolerances"), "tolerances"))
    cmm_table = top._get("cmm", None, "table", "machine = \"cmm\" only (its keys: [cmm] below)")
    top.done()
    cmm = None
    if machine == "cmm":
        cmm = _parse_cmm(_Section({} if cmm_table is None else cmm_table, "cmm"))
        if probe is None:
            probe = _parse_probe(_Section({}, "probe"))
    elif cmm_table is not None:
        raise TwinError('[cmm] applies to machine = "cmm" only; this scenario\'s machine is the arm')
    return Scenario(title, seed, wp, T_world_base, sensor, noise, scan, source, raw, path, probe, locate,
                    machine, cmm, tolerances)


def _parse_workpiece(s: _Section, base_dir: Path | None) -> WorkpieceSpec:
    from twin.parts import WORKPIECE_NAMES

    shape = s.string("shape", None)
    mesh = s.string("mesh", None)
    units = s.choice("units", "m", ("m", "mm"))
    params = s.table_value("params")
    T_true = s.pose("true_pose")
    T_nominal = s.pose("nominal_pose", T_true)
    s.done()
    if (shape is None) == (mesh is None):
        raise TwinError("workpiece needs exactly one of 'shape' (a generated part) or 'mesh' (a file path)")
    if shape is not None and shape not in WORKPIECE_NAMES:
        raise TwinError(f"workpiece.shape = {shape!r} is not one of {', '.join(WORKPIECE_NAMES)}")
    if mesh is not None:
        p = Path(mesh)
        if not p.is_absolute() and base_dir is not None:
            p = base_dir / p
        mesh = str(p)
        if params:
            raise TwinError("workpiece.params apply to generated shapes only, not to a mesh file")
    return WorkpieceSpec(shape, mesh, units, dict(params), T_true, T_nominal)


def _parse_sensor(s: _Section) -> SensorSpec:
    kind = s.choice("kind", "point", ("point", "line"))
    window = s.vector("window_m", list(SENSOR_WINDOW_M), 2)
    if not (0 < window[0] < window[1]):
        raise TwinError(f"sensor.window_m must be [near, far] with 0 < near < far, got {window.tolist()}")
    reference = s.number("reference_m", 0.080, window[0], window[1])
    period = s.number("sample_period_s", 0.001, 0.0, 1.0, lo_open=True)
    sigma = s.number("sigma_m", 2e-6, 0.0, 1e-2)
    linearity = s.number("linearity_m", 10e-6, 0.0, 1e-2)
    phase = _linearity_phase(s)
    resolution = s.number("resolution_m", 1e-6, 0.0, 1e-2)
    max_inc = s.number("max_incidence_deg", 60.0, 0.0, 90.0, lo_open=True)
    baseline = s.number("baseline_m", 0.020, 0.0, 0.5)
    beams = s.integer("beams", 1024 if kind == "line" else 1, 1, 8192)
    fan = s.number("fan_deg", 20.0, 0.0, 120.0)
    T_fs = s.pose("hand_eye", _default_hand_eye())
    s.done()
    if period != 0.001:
        # Samples pair with the 1 ms physics step; other periods would need resampling.
        raise TwinError(f"sensor.sample_period_s must be 0.001 (the cell's 1 ms step), got {period!r}")
    if kind == "point" and beams != 1:
        raise TwinError("sensor.beams applies to kind = 'line' only")
    return SensorSpec(kind, (float(window[0]), float(window[1])), reference, period, sigma,
                      linearity, resolution, max_inc, baseline, beams, fan, T_fs, phase)


def _linearity_phase(s: _Section) -> float | None:
    """``linearity_phase_deg``: a number in [0, 360) or "random" (None: drawn per realization)."""
    v = s._get("linearity_phase_deg", 0.0, "number or string", '[0, 360) or "random"')
    if v == "random":
        return None
    if not _is_number(v) or not (0.0 <= v < 360.0):
        raise TwinError(f'sensor.linearity_phase_deg must be a number in [0, 360) or "random", got {v!r}')
    return float(v)


def _default_hand_eye() -> np.ndarray:
    """Sensor 40 mm below the flange face, beam parallel to the flange z, 30 mm off axis."""
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.030, 0.040]
    return T


def _parse_noise(s: _Section) -> NoiseSpec:
    n = NoiseSpec(
        gaussian=s.boolean("gaussian", True),
        linearity=s.boolean("linearity", True),
        quantization=s.boolean("quantization", True),
        incidence=s.boolean("incidence", True),
        occlusion=s.boolean("occlusion", True),
        encoder_sigma_rad=s.number("encoder_sigma_rad", 0.0, 0.0, 0.1),
        time_skew_s=s.number("time_skew_s", 0.0, -0.1, 0.1),
        kinematic_sigma_m=s.number("kinematic_sigma_m", 0.0, 0.0, 0.01),
        kinematic_sigma_rad=s.number("kinematic_sigma_rad", 0.0, 0.0, 0.05),
        T_hand_eye_error=s.pose("hand_eye_error", np.eye(4)),
    )
    s.done()
    return n


def _parse_scan(s: _Section, sensor: SensorSpec) -> ScanSpec:
    region = s._get("region_m", None, "list", "[[xmin, ymin], [xmax, ymax]], min < max")
    if region is not None:
        ok = (isinstance(region, list) and len(region) == 2
              and all(isinstance(r, list) and len(r) == 2 and all(_is_number(v) for v in r) for r in region))
        if not ok or not (region[0][0] < region[1][0] and region[0][1] < region[1][1]):
            raise TwinError(f"scan.region_m must be [[xmin, ymin], [xmax, ymax]] with min < max, got {region!r}")
        region = ((float(region[0][0]), float(region[0][1])), (float(region[1][0]), float(region[1][1])))
    margin = s.number("margin_m", 0.003, 0.0, 1.0)
    spacing = s.number("line_spacing_m", 0.004, 0.0, 1.0, lo_open=True)
    speed = s.number("speed_m_s", 0.05, 0.0, 1.0, lo_open=True)
    transit = s.number("transit_speed_m_s", 0.10, 0.0, 1.0, lo_open=True)
    standoff = s.number("standoff_m", sensor.reference_m, 0.0, 10.0, lo_open=True)
    beam = s.choice("beam", "normal", ("normal", "fixed"))
    direction = s.vector("direction", [0.0, 0.0, -1.0], 3)
    retract = s.number("retract_m", 0.020, 0.0, 0.5)
    axis = s.choice("line_axis", "x", ("x", "y"))
    max_lines = s.integer("max_lines", 1000, 1, 100000)
    passes_raw = s._get("passes", None, "string or tables", '"auto" or a list of [[scan.passes]] tables')
    clearance = s.number("transit_clearance_m", 0.03, 0.0, 1.0)
    auto_keys = ("auto_tilts_deg", "auto_azimuths", "auto_max_passes", "auto_min_relative_eigenvalue")
    auto_given = [k for k in auto_keys if k in s.table]
    auto = _parse_auto(s)
    s.done()
    _check_standoff(standoff, sensor, "scan.standoff_m")
    norm = np.linalg.norm(direction)
    if norm < 1e-9:
        raise TwinError("scan.direction must be a non-zero vector")
    spec = ScanSpec(region, margin, spacing, speed, transit, standoff, beam, direction / norm,
                    retract, axis, max_lines, None, None, clearance)
    if passes_raw is None:
        if auto_given:
            raise TwinError(f"scan.{auto_given[0]} applies to scan.passes = \"auto\" only")
        return spec
    if passes_raw == "auto":
        return replace(spec, auto=auto)
    if auto_given:
        raise TwinError(f"scan.{auto_given[0]} applies to scan.passes = \"auto\" only")
    if not isinstance(passes_raw, list) or not passes_raw or not all(isinstance(p, dict) for p in passes_raw):
        raise TwinError('scan.passes must be "auto" or a non-empty list of [[scan.passes]] tables, '
                        f"got {passes_raw!r}")
    passes = tuple(_parse_pass(_Section(p, f"scan.passes[{i}]"), i, spec, sensor)
                   for i, p in enumerate(passes_raw))
    return replace(spec, passes=passes)


def _check_standoff(standoff: float, sensor: SensorSpec, where: str) -> None:
    lo, hi = sensor.window_m
    if not (lo <= standoff <= hi):
        raise TwinError(f"{where} = {standoff:g} m is outside the sensor window [{lo:g}, {hi:g}] m")


def _parse_auto(s: _Section) -> AutoPlanSpec:
    tilts = s._get("auto_tilts_deg", [30.0, 45.0, 60.0], "list", "tilts in (0, 80] deg")
    if (not isinstance(tilts, list) or not tilts or not all(_is_number(v) and np.isfinite(v) for v in tilts)
            or not all(0.0 < v <= 80.0 for v in tilts)):
        raise TwinError(f"scan.auto_tilts_deg must be a non-empty list of tilts in (0, 80] deg, got {tilts!r}")
    azimuths = s.integer("auto_azimuths", 8, 1, 72)
    max_passes = s.integer("auto_max_passes", 5, 1, 20)
    min_rel = s.number("auto_min_relative_eigenvalue", 1e-3, 0.0, 1.0, lo_open=True)
    return AutoPlanSpec(tuple(float(v) for v in tilts), azimuths, max_passes, min_rel)


_AXIS_NAMES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def _unit(v: np.ndarray, where: str) -> np.ndarray:
    norm = float(np.linalg.norm(v))
    if not norm > 1e-9:
        raise TwinError(f"{where} must be a non-zero vector, got {v.tolist()}")
    return v / norm


def _parse_pass(s: _Section, i: int, scan: ScanSpec, sensor: SensorSpec) -> PassSpec:
    where = s.where
    name = s.string("name", f"pass {i + 1}")
    beam_raw = s._get("beam", [0.0, 0.0, -1.0], "string or list", '"normal" or a direction [x, y, z]')
    view_raw = s._get("view", None, "list", "a direction [x, y, z]; beam = \"normal\" only")
    if beam_raw == "normal":
        beam = "normal"
        view = _unit(_vector(view_raw if view_raw is not None else [0.0, 0.0, -1.0], 3, f"{where}.view"),
                     f"{where}.view")
    else:
        if isinstance(beam_raw, str):
            raise TwinError(f"{where}.beam must be \"normal\" or a direction [x, y, z], got {beam_raw!r}")
        if view_raw is not None:
            raise TwinError(f"{where}.view applies to beam = \"normal\" only (a fixed beam is its own view)")
        beam = "fixed"
        view = _unit(_vector(beam_raw, 3, f"{where}.beam"), f"{where}.beam")
    box = "[[xmin, ymin, zmin], [xmax, ymax, zmax]] or [[xmin, ymin], [xmax, ymax]]"
    region = _parse_box(s._get("region_m", None, "list", box), f"{where}.region_m")
    axis_raw = s._get("line_axis", None, "string or list", '"x", "y", "z" or a direction [x, y, z]')
    if axis_raw is None:
        axis = np.array(_AXIS_NAMES["x"] if abs(view[0]) < 0.9 else _AXIS_NAMES["y"])
    elif isinstance(axis_raw, str):
        if axis_raw not in _AXIS_NAMES:
            raise TwinError(f"{where}.line_axis must be x, y, z or a direction [x, y, z], got {axis_raw!r}")
        axis = np.array(_AXIS_NAMES[axis_raw])
    else:
        axis = _unit(_vector(axis_raw, 3, f"{where}.line_axis"), f"{where}.line_axis")
    if abs(float(axis @ view)) > np.cos(np.radians(10.0)):
        raise TwinError(f"{where}.line_axis {axis.tolist()} is within 10 deg of the view direction "
                        f"{np.round(view, 3).tolist()}: the lines need a direction across the beam")
    spacing = s.number("line_spacing_m", scan.line_spacing_m, 0.0, 1.0, lo_open=True)
    speed = s.number("speed_m_s", scan.speed_m_s, 0.0, 1.0, lo_open=True)
    transit = s.number("transit_speed_m_s", scan.transit_speed_m_s, 0.0, 1.0, lo_open=True)
    standoff = s.number("standoff_m", scan.standoff_m, 0.0, 10.0, lo_open=True)
    retract = s.number("retract_m", scan.retract_m, 0.0, 0.5)
    edge = s.number("edge_margin_m", 0.001, 0.0, 0.1)
    max_lines = s.integer("max_lines", scan.max_lines, 1, 100000)
    s.done()
    _check_standoff(standoff, sensor, f"{where}.standoff_m")
    return PassSpec(name, beam, view, region, axis, spacing, speed, transit, standoff, retract, edge, max_lines)


def _parse_box(value: Any, where: str):
    """A box [[xmin, ymin, zmin], [xmax, ymax, zmax]] (or 2-D corners: z unbounded), or None."""
    if value is None:
        return None
    ok = (isinstance(value, list) and len(value) == 2
          and all(isinstance(r, list) and len(r) in (2, 3) and len(r) == len(value[0]) for r in value)
          and all(_is_number(v) and np.isfinite(v) for r in value for v in r))
    if not ok or not all(a < b for a, b in zip(value[0], value[1], strict=True)):
        raise TwinError(f"{where} must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] (or [[xmin, ymin], "
                        f"[xmax, ymax]]) with min < max, got {value!r}")
    return (tuple(float(v) for v in value[0]), tuple(float(v) for v in value[1]))


def default_tool_pose() -> np.ndarray:
    """Tool tip 100 mm along the flange z; tool z = -flange z (out of the surface, like eq. 11's normal)."""
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[2, 3] = 0.100
    return T


def _parse_path(s: _Section) -> PathSpec:
    T_ft = s.pose("tool", default_tool_pose())
    tip = s.number("tip_radius_m", 0.004, 0.0, 0.1)
    shank = s.number("shank_radius_m", 0.004, 0.0, 0.1)
    holder = s.number("holder_radius_m", 0.015, 0.0, 0.2)
    holder_len = s.number("holder_length_m", 0.050, 0.0, 1.0)
    feed = s.number("feed_m_s", 0.03, 0.0, 1.0, lo_open=True)
    transit = s.number("transit_speed_m_s", 0.05, 0.0, 1.0, lo_open=True)
    acc = s.number("acceleration_m_s2", 0.25, 0.0, 10.0, lo_open=True)
    acc_td = s.number("touchdown_acceleration_m_s2", 0.05, 0.0, 10.0, lo_open=True)
    point_spacing = s.number("point_spacing_m", 0.001, 1e-5, 0.1)
    line_spacing = s.number("line_spacing_m", 0.004, 0.0, 1.0, lo_open=True)
    margin = s.number("margin_m", 0.005, 0.0, 1.0)
    axis_name = s.choice("line_axis", "x", ("x", "y"))
    retract = s.number("retract_m", 0.02, 0.0, 0.5, lo_open=True)
    heading = s.choice("heading", "smooth", ("smooth", "fixed", "travel"))
    heading_dir = s.vector("heading_direction", [1.0, 0.0, 0.0], 3)
    axis = s.choice("axis", "normal", ("normal", "fixed"))
    axis_dir = s.vector("axis_direction", [0.0, 0.0, 1.0], 3)
    lead = s.number("lead_deg", 0.0, -60.0, 60.0)
    tilt = s.number("tilt_deg", 0.0, -60.0, 60.0)
    knots = s.number("knot_spacing_m", 0.002, 1e-5, 1.0)
    simplify = s.number("simplify_spacing_m", 0.0002, 1e-6, 0.1)
    window = s.number("outlier_window_m", 0.001, 1e-6, 0.1)
    k = s.number("outlier_k", 5.0, 1.0, 100.0)
    gap = s.number("max_gap_m", 0.002, 0.0, 1.0, lo_open=True)
    empty = s.choice("empty_lines", "error", ("error", "drop"))
    region_axis = s.vector("region_axis", [0.0, 0.0, 1.0], 3)
    cone = s.number("region_cone_deg", 60.0, 0.0, 90.0, lo_open=True)
    max_tilt = s.number("max_tilt_deg", 0.0, 0.0, 89.0)
    box = s._get("region_box_m", None, "list", "[[xmin, ymin, zmin], [xmax, ymax, zmax]]")
    features = s._get("region_features", [], "string or list", "named features of the part")
    s.done()
    if isinstance(features, str):
        features = [features]
    if not (isinstance(features, list) and all(isinstance(f, str) and f for f in features)):
        raise TwinError(f"path.region_features must be a feature name or a list of names, got {features!r}")
    if box is not None:
        ok = (isinstance(box, list) and len(box) == 2
              and all(isinstance(c, list) and len(c) == 3 and all(_is_number(v) for v in c) for c in box))
        if not ok or not all(box[0][i] < box[1][i] for i in range(3)):
            raise TwinError(f"path.region_box_m must be [[x, y, z], [x, y, z]] with min < max, got {box!r}")
        box = (tuple(float(v) for v in box[0]), tuple(float(v) for v in box[1]))
    for name, v in (("heading_direction", heading_dir), ("axis_direction", axis_dir), ("region_axis", region_axis)):
        if np.linalg.norm(v) < 1e-9:
            raise TwinError(f"path.{name} must be a non-zero vector")
    if max_tilt > 0 and (axis != "normal" or lead != 0 or tilt != 0):
        raise TwinError("path.max_tilt_deg chooses the tool axis itself: it needs axis = \"normal\" and "
                        f"lead_deg = tilt_deg = 0, got axis = {axis!r}, lead_deg = {lead:g}, tilt_deg = {tilt:g}")
    if np.linalg.norm(T_ft[:3, 3]) <= tip:
        raise TwinError(f"path.tool: the tool tip must lie farther from the flange than tip_radius_m = {tip:g} m")
    return PathSpec(T_ft, tip, shank, holder, holder_len, feed, transit, acc, acc_td, point_spacing, line_spacing,
                    margin, axis_name, retract, heading, heading_dir / np.linalg.norm(heading_dir), axis,
                    axis_dir / np.linalg.norm(axis_dir), lead, tilt, knots, simplify, window, k, gap, empty,
                    region_axis / np.linalg.norm(region_axis), cone, box, max_tilt, tuple(features))


def default_probe_mount() -> np.ndarray:
    """Probe 30 mm off the flange axis (opposite the laser), its stylus along the flange z."""
    T = np.eye(4)
    T[:3, 3] = [0.0, -0.030, 0.0]
    return T


def _parse_probe(s: _Section) -> ProbeSpec:
    T = s.pose("mount", default_probe_mount())
    body_r = s.number("body_radius_m", 0.0066, 0.0, 0.1, lo_open=True)
    body_len = s.number("body_length_m", 0.095, 0.0, 0.5, lo_open=True)
    stylus = s.number("stylus_length_m", 0.020, 0.0, 0.2, lo_open=True)
    stylus_r = s.number("stylus_radius_m", 0.0005, 0.0, 0.01, lo_open=True)
    ball = s.number("ball_radius_m", 0.001, 0.0, 0.02, lo_open=True)
    lateral = s.number("lateral_pretravel_m", 4.0e-6, 0.0, 1e-3)
    lobe = s.number("lobe_m", 0.6e-6, 0.0, 1e-3)
    phase = s.number("lobe_phase_deg", 0.0, -360.0, 360.0)
    axial = s.number("axial_pretravel_m", 5.4e-6, 0.0, 1e-3)
    ref_stylus = s.number("reference_stylus_m", 0.010, 0.0, 0.2, lo_open=True)
    rep = s.number("repeatability_2sigma_m", 0.35e-6, 0.0, 1e-4)
    approach = s.number("approach_m", 0.005, 0.0, 0.1, lo_open=True)
    search = s.number("search_m", 0.005, 0.0, 0.1, lo_open=True)
    speed = s.number("probing_speed_m_s", 0.008, 0.0, 0.1, lo_open=True)
    transit = s.number("transit_speed_m_s", 0.10, 0.0, 1.0, lo_open=True)
    stop = s.number("stop_deceleration_m_s2", 1.0, 0.0, 50.0, lo_open=True)
    clearance = s.number("clearance_m", 0.0002, 0.0, 0.05)
    safe = s.number("safe_height_m", 0.030, 0.0, 0.5, lo_open=True)
    sphere = s.vector("sphere_xyz_m", [0.30, -0.25, 0.10], 3)
    sphere_r = s.number("sphere_radius_m", 0.0125, 0.0, 0.1, lo_open=True)
    qual = s.integer("qualification_points", 24, 5, 200)
    points = s.integer("points", 12, 1, 200)
    edge = s.number("edge_margin_m", 0.003, 0.0, 0.1)
    spacing = s.number("candidate_spacing_m", 0.004, 1e-4, 0.1)
    s.done()
    if stylus <= ball:
        raise TwinError(f"probe.stylus_length_m = {stylus:g} m must be longer than probe.ball_radius_m = {ball:g} m")
    if stylus_r >= ball:
        raise TwinError(f"probe.stylus_radius_m = {stylus_r:g} m must be smaller than probe.ball_radius_m = {ball:g} m "
                        "(the stem would touch before the ball)")
    if lobe >= lateral > 0 or (lateral == 0 and lobe > 0):
        raise TwinError(f"probe.lobe_m = {lobe:g} m must be smaller than probe.lateral_pretravel_m = {lateral:g} m")
    if points < 6:
        raise TwinError(f"probe.points = {points} is too few: at least 6 points are needed to fix six pose directions")
    return ProbeSpec(T, body_r, body_len, stylus, stylus_r, ball, lateral, lobe, phase, axial, ref_stylus, rep,
                     approach, search, speed, transit, stop, clearance, safe, sphere, sphere_r, qual, points, edge,
                     spacing)


#: The head's A range (tilt from straight down) [deg], as a PH10M indexes (models/cmm/README.md).
HEAD_A_RANGE_DEG = (0.0, 105.0)


def _parse_tolerances(s: _Section) -> ToleranceSpec:
    d = ToleranceSpec()
    spec = ToleranceSpec(
        min_process_coverage=s.number("min_process_coverage", d.min_process_coverage, 0.0, 1.0),
        max_replay_deviation_m=s.number("max_replay_deviation_m", d.max_replay_deviation_m, 0.0, 0.1),
        max_tip_penetration_m=s.number("max_tip_penetration_m", d.max_tip_penetration_m, 0.0, 0.1),
        max_position_uncertainty_m=s.number("max_position_uncertainty_m", d.max_position_uncertainty_m, 0.0, 0.1,
                                            lo_open=True),
        max_rotation_uncertainty_rad=s.number("max_rotation_uncertainty_rad", d.max_rotation_uncertainty_rad, 0.0,
                                              0.5, lo_open=True),
        max_surface_deviation_m=s.number("max_surface_deviation_m", d.max_surface_deviation_m, 0.0, 0.1,
                                         lo_open=True),
    )
    s.done()
    return spec


def _parse_cmm(s: _Section) -> CmmSpec:
    raw = s._get("styli", {"S1": [0.0, 0.0]}, "table", "stylus name = [A_deg, B_deg]")
    if not isinstance(raw, dict) or not raw:
        raise TwinError("cmm.styli must be a table of stylus name = [A_deg, B_deg], e.g. { S1 = [0, 0] }")
    styli = {}
    for name, ab in raw.items():
        if not (name[:1].isalpha() and name.replace("_", "").isalnum() and len(name) <= 20):
            raise TwinError(f"cmm.styli: {name!r} is not a stylus label (a letter, then letters, digits, underscores)")
        v = _vector(ab, 2, f"cmm.styli.{name}")
        if not (HEAD_A_RANGE_DEG[0] <= v[0] <= HEAD_A_RANGE_DEG[1]) or not (-180.0 <= v[1] <= 180.0):
            raise TwinError(f"cmm.styli.{name} = {list(ab)}: A must lie in [0, 105] deg and B in [-180, 180] deg")
        styli[name] = (float(v[0]), float(v[1]))
    spec = CmmSpec(
        styli=styli,
        transit_speed_m_s=s.number("transit_speed_m_s", 0.15, 0.0, 1.0, lo_open=True),
        acceleration_m_s2=s.number("acceleration_m_s2", 1.0, 0.0, 20.0, lo_open=True),
        index_time_s=s.number("index_time_s", 1.5, 0.1, 10.0),
        clearance_m=s.number("clearance_m", 0.001, 0.0, 0.05, lo_open=True),
        encoder_sigma_m=s.number("encoder_sigma_m", 1e-7, 0.0, 1e-4),
    )
    s.done()
    return spec


def _parse_locate(s: _Section) -> LocateSpec:
    spec = LocateSpec(
        coarse=str(s.choice("coarse", "multistart", COARSE_METHODS)),
        coarse_line_spacing_m=s.number("coarse_line_spacing_m", 0.010, 0.0, 0.5, lo_open=True),
        coarse_speed_m_s=s.number("coarse_speed_m_s", 0.10, 0.0, 1.0, lo_open=True),
        coarse_margin_m=s.number("coarse_margin_m", 0.04, 0.0, 0.5),
        planner=str(s.choice("planner", "d_optimal", PROBE_PLANNERS)),
    )
    s.done()
    return spec
