"""Trigger model of a kinematic touch-trigger probe: pre-travel and repeatability.

A kinematic probe triggers when the stylus has been deflected far enough to open one of the
three electrical contacts of its seat. The ball has then moved past the first contact with
the part by the *pre-travel*, which depends on the direction of the push: the three-contact
seat makes it vary with a three-lobed pattern around the stylus axis, and an axial push
(along the stylus, towards the body) needs a larger force, hence a larger deflection, than a
sideways one.

Probe frame: ``z`` is the stylus axis pointing from the probe body to the ball. ``u`` is the
unit direction in which the ball moves relative to the part at the touch (the machine's
motion). The probe senses pushes along ``+z`` (the surface pushes the ball back toward the
body) and sideways; ``u . z < 0`` (the ball driven toward the body's side, so that the
surface would pull the stylus out of its seat) is not a sense direction.

Model, with ``cos(theta) = u . z``, ``phi = atan2(u . y, u . x)`` and the stylus scale
``s = stylus_m / reference_stylus_m``::

    pretravel(u) = s * [(lateral_m + lobe_m cos(3 (phi - lobe_phase_rad))) sin^2(theta)
                        + axial_m cos^2(theta)]

The triggered ball has moved ``pretravel(u) + e`` past the contact, with ``e ~ N(0,
repeatability_sigma_m)`` drawn per touch (:meth:`PretravelModel.draw_m`).

Sources. Renishaw TP20 data sheet, standard-force module, test conditions 10 mm stylus at
480 mm/min: unidirectional repeatability 0.35 um (2 sigma), pre-travel variation in the
x-y plane (2D) +/-0.60 um, in 3D +/-1.00 um. These figures are quoted from the data sheet as
remembered and have not been checked against a copy in this repository. The data sheet
gives variations, not a mean; the mean sideways pre-travel (4.0 um) is an assumption of this
project, and the axial value (5.4 um) is chosen so that the 3D range, from the lowest lateral
value 4.0 - 0.6 = 3.4 um to the axial 5.4 um, is the data sheet's 2.0 um. That the axial
value exceeds the lateral ones agrees with the module's axial trigger force being about ten
times its lateral one. That pre-travel grows linearly with the stylus length (a longer lever
bends further for the same seat force and needs a larger ball displacement to tilt the seat
by the same angle) is also an assumption of this project.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray
from algorithms.errors import AlgorithmError

__all__ = ["PretravelModel"]

#: |u| may differ from 1 by this much (directions computed from normalised vectors).
UNIT_TOL = 1e-9
#: u . z below minus this is a pull, not a sense direction (leaves room for rounding).
PULL_TOL = 1e-9


@dataclass(frozen=True)
class PretravelModel:
    """Direction-dependent pre-travel of a kinematic touch-trigger probe (module docstring).

    Attributes:
        lateral_m: mean pre-travel for sideways motion at the reference stylus length [m]
            (assumed; not published).
        lobe_m: amplitude of the three-lobed variation around the stylus axis [m] (TP20 SF
            2D pre-travel variation +/-0.60 um).
        lobe_phase_rad: azimuth of the first lobe's maximum in the probe's x-y plane [rad].
        axial_m: pre-travel for motion along +z at the reference stylus length [m] (TP20 SF
            3D variation +/-1.00 um: 5.4 - (4.0 - 0.6) = 2.0 um range).
        reference_stylus_m: stylus length the numbers hold for [m] (the data sheet's 10 mm).
        stylus_m: this probe's stylus length [m].
        repeatability_sigma_m: standard deviation of one trigger about the mean [m]
            (unidirectional repeatability 0.35 um, 2 sigma).

    Raises:
        AlgorithmError: a non-finite field, a length that is not positive, a lobe amplitude
            outside [0, lateral_m) or a negative sigma.
    """

    lateral_m: float = 4.0e-6
    lobe_m: float = 0.6e-6
    lobe_phase_rad: float = 0.0
    axial_m: float = 5.4e-6
    reference_stylus_m: float = 0.010
    stylus_m: float = 0.010
    repeatability_sigma_m: float = 0.175e-6

    def __post_init__(self) -> None:
        for name in ("lateral_m", "lobe_m", "lobe_phase_rad", "axial_m", "reference_stylus_m", "stylus_m",
                     "repeatability_sigma_m"):
            if not np.isfinite(getattr(self, name)):
                raise AlgorithmError(f"{name} must be finite, got {getattr(self, name)}")
        for name in ("lateral_m", "axial_m", "reference_stylus_m", "stylus_m"):
            if not getattr(self, name) > 0:
                raise AlgorithmError(f"{name} must be a positive length [m], got {getattr(self, name)}")
        if not 0 <= self.lobe_m < self.lateral_m:
            raise AlgorithmError(f"lobe_m must be in [0, lateral_m = {self.lateral_m}) so that every "
                                 f"lateral pre-travel is positive, got {self.lobe_m}")
        if not self.repeatability_sigma_m >= 0:
            raise AlgorithmError(f"repeatability_sigma_m must be >= 0 [m], got {self.repeatability_sigma_m}")

    @property
    def scale(self) -> float:
        """Stylus scale ``stylus_m / reference_stylus_m`` (the assumed linear length law)."""
        return self.stylus_m / self.reference_stylus_m

    def pretravel_m(self, u_probe: ArrayLike) -> FloatArray | float:
        """Mean pre-travel [m] for motion directions in the probe frame.

        Args:
            u_probe: (N, 3) or (3,) unit directions of the ball's motion relative to the
                part, probe frame (z from the body to the ball); ``u . z >= 0``.

        Returns:
            (N,) [m], or a float for one direction.

        Raises:
            AlgorithmError: wrong shape, non-finite or non-unit directions, or pulls
                (``u . z < 0``), naming how many rows are bad.
        """
        u, single = _directions(u_probe)
        cos2 = u[:, 2] ** 2
        phi = np.arctan2(u[:, 1], u[:, 0])
        lateral = self.lateral_m + self.lobe_m * np.cos(3.0 * (phi - self.lobe_phase_rad))
        # sin^2 from the x-y components, not 1 - cos^2, so a lateral push stays exact
        sin2 = u[:, 0] ** 2 + u[:, 1] ** 2
        out = self.scale * (lateral * sin2 + self.axial_m * cos2)
        return float(out[0]) if single else out

    def draw_m(self, u_probe: ArrayLike, rng: np.random.Generator) -> FloatArray | float:
        """One trigger per direction: pre-travel plus Gaussian repeatability, clipped at 0.

        Args:
            u_probe: (N, 3) or (3,) unit motion directions, probe frame (see pretravel_m).
            rng: the random stream.

        Returns:
            (N,) [m], or a float for one direction.
        """
        if not isinstance(rng, np.random.Generator):
            raise AlgorithmError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        mean = np.atleast_1d(self.pretravel_m(u_probe))
        out = np.maximum(mean + rng.normal(0.0, self.repeatability_sigma_m, size=mean.shape), 0.0)
        return float(out[0]) if np.ndim(u_probe) == 1 else out

    def mean_m(self, u_probe: ArrayLike) -> float:
        """Mean pre-travel [m] over the given directions ((N, 3) or (3,), probe frame)."""
        return float(np.mean(self.pretravel_m(u_probe)))


def _directions(u_probe: ArrayLike) -> tuple[FloatArray, bool]:
    """Checked (N, 3) unit directions with u . z >= 0, and whether one (3,) was given."""
    u = np.asarray(u_probe, dtype=np.float64)
    single = u.ndim == 1
    u = np.atleast_2d(u)
    if u.ndim != 2 or u.shape[1] != 3 or len(u) == 0:
        raise AlgorithmError(f"u_probe must be (3,) or (N, 3) with N >= 1, got {np.shape(u_probe)}")
    finite = np.all(np.isfinite(u), axis=1)
    if not finite.all():
        raise AlgorithmError(f"u_probe must be finite: {int(np.sum(~finite))} of {len(u)} rows are not")
    bad = np.abs(np.linalg.norm(u, axis=1) - 1.0) > UNIT_TOL
    if bad.any():
        raise AlgorithmError(f"u_probe must be unit vectors (|u| within {UNIT_TOL} of 1): "
                             f"{int(bad.sum())} of {len(u)} rows are not")
    pull = u[:, 2] < -PULL_TOL
    if pull.any():
        raise AlgorithmError(f"u_probe must have u . z >= 0 (a push toward the probe body or sideways; a pull "
                             f"does not trigger the probe): {int(pull.sum())} of {len(u)} rows pull")
    return u, single
