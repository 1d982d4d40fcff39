"""A scenario realized once: the workpiece mesh and its index, the truth, the random streams.

Every stage of the loop takes the :class:`Realized` scenario instead of re-deriving what it
needs: the mesh is generated (or loaded) once, the true cell's errors (kinematic parameters,
hand-eye) are drawn once, and each stage draws from its own named random stream. So the cell
that scans, the cell that replays and the cell a recording shows are the same true cell.

Random streams. ``Streams(seed).generator(name)`` is a fresh generator on the child of
``SeedSequence(seed)`` at the name's index in ``STREAM_NAMES``: the same name gives the same
numbers wherever it is used, and the streams are independent. New names are appended (never
inserted), so existing streams keep their numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose
from twin.errors import TwinError
from twin.parts import load_mesh, make_workpiece
from twin.robot import LINK_BODIES
from twin.scenario import Scenario, SensorSpec

#: The named random streams, in spawn order (append only).
STREAM_NAMES = ("kinematics", "sensor", "encoder", "localization", "probe", "probe_encoder", "coarse", "plan",
                "sensor_unit")


@dataclass(frozen=True)
class Streams:
    """Named, independent random streams of one seed (see the module docstring)."""

    seed: int

    def generator(self, name: str) -> np.random.Generator:
        if name not in STREAM_NAMES:
            raise KeyError(f"unknown random stream {name!r}; known: {', '.join(STREAM_NAMES)}")
        child = np.random.SeedSequence(self.seed).spawn(len(STREAM_NAMES))[STREAM_NAMES.index(name)]
        return np.random.default_rng(child)


@dataclass(frozen=True)
class Workpiece:
    """The part's CAD mesh in the workpiece frame [m] and its exact closest-point index."""

    mesh: trimesh.Trimesh
    index: MeshIndex


@dataclass(frozen=True)
class LinkError:
    """A perturbed kinematic parameter set of one link body: position offset [m] in the parent
    frame and a rotation applied after the body's own (``R_true = R_nominal @ dR``)."""

    body: str
    dpos_m: np.ndarray
    dR: np.ndarray


@dataclass(frozen=True)
class Truth:
    """What only the simulator and the evaluation know.

    Attributes:
        T_world_workpiece: (4, 4) the part's true pose.
        T_flange_sensor: (4, 4) the true hand-eye transform (nominal @ hand-eye error).
        link_errors: the drawn kinematic errors, one per moving link (empty when switched off).
        linearity_phase_deg: the phase of this sensor unit's linearity curve [deg] (the
            scenario's, or drawn uniform in [0, 360) where it says "random").
        linearity_m: this unit's curve amplitude [m]; None: the scenario's band (a study may draw
            it within the band; the estimator keeps the band the data sheet states).
    """

    T_world_workpiece: np.ndarray
    T_flange_sensor: np.ndarray
    link_errors: tuple[LinkError, ...]
    linearity_phase_deg: float = 0.0
    linearity_m: float | None = None


@dataclass(frozen=True)
class Realized:
    """A scenario with its workpiece, truth and random streams, made once."""

    scenario: Scenario
    workpiece: Workpiece
    truth: Truth
    streams: Streams

    @property
    def sensor(self) -> SensorSpec:
        """The scenario's sensor as this realization's unit (its linearity curve's phase and amplitude)."""
        amplitude = self.scenario.sensor.linearity_m if self.truth.linearity_m is None else self.truth.linearity_m
        return replace(self.scenario.sensor, linearity_phase_deg=self.truth.linearity_phase_deg, linearity_m=amplitude)

    @property
    def T_base_workpiece_true(self) -> np.ndarray:
        return inv_pose(self.scenario.T_world_base) @ self.truth.T_world_workpiece

    @property
    def T_base_workpiece_nominal(self) -> np.ndarray:
        return inv_pose(self.scenario.T_world_base) @ self.scenario.workpiece.T_world_workpiece_nominal


def load_workpiece_mesh(scenario: Scenario) -> trimesh.Trimesh:
    """The scenario's workpiece mesh in the workpiece frame [m] (generated or loaded)."""
    wp = scenario.workpiece
    if wp.shape is not None:
        return make_workpiece(wp.shape, **wp.params)
    if wp.mesh is None:
        raise TwinError("workpiece needs a shape or a mesh file")
    return load_mesh(wp.mesh, wp.units)


def draw_truth(scenario: Scenario, streams: Streams) -> Truth:
    """Draw the true cell's kinematic errors (each link in turn: position, then rotation; the
    ``kinematics`` stream) and, where the scenario leaves it unknown, the sensor unit's
    linearity phase (the ``sensor_unit`` stream)."""
    noise = scenario.noise
    rng = streams.generator("kinematics")
    errors = []
    if noise.kinematic_sigma_m > 0 or noise.kinematic_sigma_rad > 0:
        for name in LINK_BODIES[1:]:
            dpos = rng.normal(0.0, noise.kinematic_sigma_m, 3)
            dR = Rotation.from_rotvec(rng.normal(0.0, noise.kinematic_sigma_rad, 3)).as_matrix()
            errors.append(LinkError(name, dpos, dR))
    phase = scenario.sensor.linearity_phase_deg
    if phase is None:
        phase = float(streams.generator("sensor_unit").uniform(0.0, 360.0))
    return Truth(scenario.workpiece.T_world_workpiece_true.copy(),
                 scenario.sensor.T_flange_sensor @ noise.T_hand_eye_error, tuple(errors), phase)


def with_truth(realized: Realized, **changes) -> Realized:
    """The realization with parts of its truth replaced (a study's draws per trial: the sensor
    unit's curve, the link errors, the hand-eye transform, the placement; :class:`Truth`'s fields)."""
    return replace(realized, truth=replace(realized.truth, **changes))


def realize(scenario: Scenario, mesh: trimesh.Trimesh | None = None, workpiece: Workpiece | None = None) -> Realized:
    """Realize a scenario: build the part's mesh and its index (or take the ``mesh``, or the
    ``workpiece`` with its index, made for the same part), draw the truth."""
    if workpiece is None:
        mesh = load_workpiece_mesh(scenario) if mesh is None else mesh
        workpiece = Workpiece(mesh, MeshIndex(mesh))
    streams = Streams(scenario.seed)
    return Realized(scenario, workpiece, draw_truth(scenario, streams), streams)
