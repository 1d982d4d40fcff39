"""The uncertain inputs of a study (``[inputs]``): how each error source of the scenario enters
its trials, as JCGM 101 (GUM Supplement 1) asks a Monte Carlo study to state them.

Each source has a *treatment*:

* ``per_reading``: random, drawn afresh for every reading (the sensor's repeatability, its
  quantisation and incidence noise, the encoders' noise);
* ``per_trial``: an unknown systematic effect, common to every reading of a trial and redrawn
  each trial from its distribution (the laser's linearity curve: a sensor unit per trial; the
  time skew; the kinematic and hand-eye errors; the part's placement);
* ``fixed``: the scenario's value in every trial, a known correction: its effect is a bias of
  the estimate (the report gives the mean error, the correction is its negative), not in the
  coverage intervals;
* ``off``: switched off in the cell's scenario.

The default of a source the scenario has on is ``per_reading`` for the random ones and
``per_trial`` for the systematic ones (an unknown systematic effect is drawn); the part's
placement, the measurand, defaults to ``fixed``. ``kind = "fast"`` reuses one noise-free scan,
so it can draw only sensor-side effects per trial (the linearity curve, the time skew): a
robot-side effect the scenario has on must be declared ``fixed`` there (or the study made
``kind = "full"``), never left to a silent default.

Distributions of a per-trial draw, each of mean zero and ``width`` w: ``normal`` (standard
deviation w), ``uniform`` (on [-w, w]), ``arcsine`` (w sin of a uniform phase: the U-shaped law
of a sinusoidal effect), ``triangular`` (on [-w, w], mode 0). The linearity curve
``A sin(pi u + phase)`` draws its phase uniform on [0, 360) deg and its amplitude ``A`` uniform on
[0, band] (``amplitude = "uniform"``, the default: all that the data sheet states is the band) or
at the band's edge (``amplitude = "band"``).

A systematic per-trial draw comes from its own child of the trial's seed sequence (the fifth), so
``fixed`` and ``per_trial`` studies of one seed share their per-reading noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.geometry.se3 import make_pose
from twin.errors import TwinError
from twin.robot import LINK_BODIES

TREATMENTS = ("per_reading", "per_trial", "fixed", "off")
DISTRIBUTIONS = ("normal", "uniform", "arcsine", "triangular")
AMPLITUDES = ("uniform", "band")
#: E[A^2] / band^2 of the linearity amplitude: the law of propagation's share of the curve.
AMPLITUDE_SECOND_MOMENT = {"uniform": 1.0 / 3.0, "band": 1.0}


@dataclass(frozen=True)
class Source:
    """One error source: its label, allowed treatments, the kinds that can draw it per trial,
    its width keys (name -> the scenario key path its default is read from) and default distribution."""

    label: str
    treatments: tuple[str, ...]
    systematic: bool
    fast_per_trial: bool = True
    widths: tuple[str, ...] = ()
    distribution: str | None = None


SOURCES: dict[str, Source] = {
    "repeatability": Source("sensor repeatability", ("per_reading", "off"), False),
    "quantization": Source("sensor quantisation", ("per_reading", "off"), False),
    "incidence": Source("incidence noise", ("per_reading", "off"), False),
    "encoder_noise": Source("encoder noise", ("per_reading", "off"), False),
    "linearity": Source("linearity curve", ("per_trial", "fixed", "off"), True),
    "time_skew": Source("time skew", ("per_trial", "fixed", "off"), True, True, ("width_s",), "uniform"),
    "kinematics": Source("kinematic (link) errors", ("per_trial", "fixed", "off"), True, False,
                         ("width_m", "width_rad"), "normal"),
    "hand_eye": Source("hand-eye error", ("per_trial", "fixed", "off"), True, False, ("width_m", "width_rad"),
                       "normal"),
    "part_pose": Source("part placement (the measurand)", ("per_trial", "fixed"), True, False,
                        ("width_m", "width_rad"), "normal"),
}
#: The keys a source's table may hold besides ``treatment``.
_EXTRA_KEYS = {"linearity": ("amplitude",)}
#: The scenario keys whose value a per-trial draw replaces: a study that also sets one of them
#: (an override or a grid factor) would hold it both fixed and drawn.
DRAWN_KEYS = {"linearity": ("sensor.linearity_phase_deg",), "time_skew": ("noise.time_skew_s",),
              "kinematics": ("noise.kinematic_sigma_m", "noise.kinematic_sigma_rad"),
              "hand_eye": ("noise.hand_eye_error",), "part_pose": ("workpiece.true_pose",)}


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def parse_inputs(raw: Any) -> dict[str, dict]:
    """The study's ``[inputs]`` table, checked: source -> ``{"treatment": ..., ...}`` for each
    source it names (a plain string is the treatment). Raises TwinError (one line) on an unknown
    source, treatment, distribution or key, or a negative width."""
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise TwinError(f"study [inputs] must be a table of error sources, got {raw!r}")
    out = {}
    for name, value in raw.items():
        if name not in SOURCES:
            raise TwinError(f"unknown input {name!r} in [inputs]; allowed: {', '.join(SOURCES)}")
        out[name] = _parse_source(name, {"treatment": value} if isinstance(value, str) else value)
    return out


def _parse_source(name: str, table: Any) -> dict:
    src = SOURCES[name]
    if not isinstance(table, dict) or "treatment" not in table:
        raise TwinError(f"inputs.{name} must be a treatment ({', '.join(src.treatments)}) or a table with "
                        f"treatment = ..., got {table!r}")
    allowed = ("treatment",) + (("distribution",) if src.distribution else ()) + src.widths + _EXTRA_KEYS.get(name, ())
    bad = sorted(set(table) - set(allowed))
    if bad:
        keys = ", ".join(f"inputs.{name}.{k}" for k in bad)
        raise TwinError(f"unknown key(s) {keys}; allowed: {', '.join(allowed)}")
    t = table["treatment"]
    if t not in src.treatments:
        raise TwinError(f"inputs.{name}.treatment = {t!r} is refused: the {src.label} is one of "
                        f"{', '.join(src.treatments)}")
    if "distribution" in table and table["distribution"] not in DISTRIBUTIONS:
        raise TwinError(f"inputs.{name}.distribution = {table['distribution']!r} is not a known distribution; "
                        f"allowed: {', '.join(DISTRIBUTIONS)}")
    if "amplitude" in table and table["amplitude"] not in AMPLITUDES:
        raise TwinError(f"inputs.{name}.amplitude = {table['amplitude']!r} is refused: one of {', '.join(AMPLITUDES)}")
    for key in src.widths:
        if key in table and not (_is_number(table[key]) and table[key] >= 0):
            raise TwinError(f"inputs.{name}.{key} = {table[key]!r} is refused: a width is a number >= 0 "
                            "(the standard deviation of a normal, the half-width of the others)")
    if t != "per_trial" and set(table) - {"treatment"}:
        raise TwinError(f"inputs.{name}: {', '.join(sorted(set(table) - {'treatment'}))} describe a per-trial draw; "
                        f"treatment is {t!r}")
    return dict(table)


@dataclass(frozen=True)
class Resolved:
    """One source as a cell's trials treat it: the treatment, and for a per-trial draw its
    distribution and widths (in the source's units) or, for the linearity curve, its band and
    amplitude law."""

    name: str
    treatment: str
    distribution: str = "normal"
    widths: tuple[float, ...] = ()
    amplitude: str = "uniform"

    @property
    def label(self) -> str:
        return SOURCES[self.name].label


def _scenario_on(name: str, scenario) -> bool:
    n, s = scenario.noise, scenario.sensor
    return {"repeatability": n.gaussian, "quantization": n.quantization, "incidence": n.incidence,
            "encoder_noise": n.encoder_sigma_rad > 0, "linearity": n.linearity and s.linearity_m > 0,
            "time_skew": n.time_skew_s != 0.0, "kinematics": n.kinematic_sigma_m > 0 or n.kinematic_sigma_rad > 0,
            "hand_eye": not np.allclose(n.T_hand_eye_error, np.eye(4)), "part_pose": True}[name]


def _default_widths(name: str, scenario) -> tuple[float, ...]:
    """The widths the scenario states: the time skew's magnitude, the kinematic standard
    deviations, the largest component of the hand-eye error (translation [m], rotation [rad])."""
    n = scenario.noise
    if name == "time_skew":
        return (abs(n.time_skew_s),)
    if name == "kinematics":
        return (n.kinematic_sigma_m, n.kinematic_sigma_rad)
    if name == "hand_eye":
        E = n.T_hand_eye_error
        return (float(np.max(np.abs(E[:3, 3]))), float(np.max(np.abs(Rotation.from_matrix(E[:3, :3]).as_rotvec()))))
    return (0.0, 0.0)  # part_pose: a width must be declared


def _default_treatment(name: str, on: bool) -> str:
    """An unknown systematic effect is drawn per trial, a random one per reading; the placement,
    the measurand, is fixed; a source the scenario has off stays off."""
    if name == "part_pose":
        return "fixed"
    if not on:
        return "off"
    return "per_trial" if SOURCES[name].systematic else "per_reading"


def resolve(declared: dict[str, dict], scenario, kind: str) -> dict[str, Resolved]:
    """Every source of ``scenario`` as a ``kind`` trial treats it (declared or defaulted).

    Raises:
        TwinError: a per-trial draw ``kind`` cannot make (robot-side in fast trials, declared or
            by default), a linearity curve fixed where the scenario draws its phase, or a part
            placement drawn without widths.
    """
    out = {}
    for name, src in SOURCES.items():
        table = declared.get(name, {})
        explicit = any(table.get(k, 0) > 0 for k in src.widths)
        on = _scenario_on(name, scenario) or (table.get("treatment") == "per_trial" and explicit)
        t = table.get("treatment", _default_treatment(name, on))
        if t != "off" and not on and name != "part_pose":
            out[name] = Resolved(name, "off")  # nothing to draw or fix: the scenario has it off
            continue
        if t == "per_trial" and kind == "fast" and not src.fast_per_trial:
            how = "declared" if name in declared else "the default for an unknown systematic effect"
            raise TwinError(f"inputs.{name}: fast trials reuse one noise-free scan and cannot draw the {src.label} "
                            f"per trial ({how}); declare inputs.{name} = \"fixed\" (one value for the study, a bias) "
                            "or use kind = \"full\"")
        if name == "linearity" and t == "fixed" and scenario.sensor.linearity_phase_deg is None:
            raise TwinError('inputs.linearity = "fixed" but the scenario draws its phase (linearity_phase_deg = '
                            '"random"): give the phase, or draw the curve per trial')
        if t != "per_trial":
            out[name] = Resolved(name, t)
            continue
        widths = _default_widths(name, scenario)
        widths = tuple(float(table.get(k, w)) for k, w in zip(src.widths, widths, strict=False))
        if name == "part_pose" and not all(k in table for k in src.widths):
            raise TwinError("inputs.part_pose drawn per trial needs width_m and width_rad (the placement's spread)")
        out[name] = Resolved(name, t, table.get("distribution", src.distribution or "normal"), widths,
                             table.get("amplitude", "uniform"))
    return out


def check_not_both(declared: dict[str, dict], resolved: dict[str, Resolved], set_keys: set[str]) -> None:
    """Refuse a scenario key a study sets (``set_keys``: dotted paths of its overrides and grid
    factors) that a per-trial draw replaces: a value both fixed and drawn. A draw whose widths
    default to the scenario's value reads that key as its width (no conflict) unless the study
    declared the widths itself."""
    for name, r in resolved.items():
        if r.treatment != "per_trial":
            continue
        explicit = name == "linearity" or any(k in declared.get(name, {}) for k in SOURCES[name].widths)
        hit = [k for k in DRAWN_KEYS.get(name, ()) if k in set_keys]
        if explicit and hit:
            raise TwinError(f"{hit[0]} is set by the study (an override or a grid factor) and inputs.{name} draws it "
                            f"per trial: a value both fixed and drawn; declare inputs.{name} = \"fixed\" or drop "
                            f"{hit[0]}")


def off_overrides(declared: dict[str, dict]) -> dict:
    """The scenario tables that switch off the sources a study declares ``off``."""
    switch: dict[str, dict] = {"repeatability": {"gaussian": False}, "quantization": {"quantization": False},
              "incidence": {"incidence": False}, "encoder_noise": {"encoder_sigma_rad": 0.0},
              "linearity": {"linearity": False}, "time_skew": {"time_skew_s": 0.0},
              "kinematics": {"kinematic_sigma_m": 0.0, "kinematic_sigma_rad": 0.0},
              "hand_eye": {"hand_eye_error": {"xyz": [0.0, 0.0, 0.0], "rpy_deg": [0.0, 0.0, 0.0]}}}
    noise: dict = {}
    for name, table in declared.items():
        if table["treatment"] == "off" and name in switch:
            noise.update(switch[name])
    return {"noise": noise} if noise else {}


def unit_draw(distribution: str, rng: np.random.Generator, size: int | None = None):
    """A draw of mean zero and width 1 from ``distribution`` (module docstring)."""
    if distribution == "normal":
        return rng.standard_normal(size)
    if distribution == "uniform":
        return rng.uniform(-1.0, 1.0, size)
    if distribution == "arcsine":
        return np.sin(rng.uniform(0.0, 2.0 * np.pi, size))
    if distribution == "triangular":
        return rng.triangular(-1.0, 0.0, 1.0, size)
    raise ValueError(f"unknown distribution {distribution!r}")


@dataclass(frozen=True)
class Draw:
    """One trial's systematic effects (None: not drawn, the scenario's value stands).

    Attributes:
        linearity_phase_deg, linearity_m: this trial's sensor unit's curve.
        time_skew_s: the skew between distances and joints [s].
        link_errors: (link name, (3,) position error [m], (3, 3) rotation error) per moving link.
        T_hand_eye_error: (4, 4) the hand-eye error (true = nominal @ this).
        T_part_error: (4, 4) the placement's error (true = scenario's true pose @ this).
    """

    linearity_phase_deg: float | None = None
    linearity_m: float | None = None
    time_skew_s: float | None = None
    link_errors: tuple | None = None
    T_hand_eye_error: np.ndarray | None = None
    T_part_error: np.ndarray | None = None


def _twist_pose(r: Resolved, rng: np.random.Generator) -> np.ndarray:
    """A pose error: each of the three translations and rotations drawn with the source's widths."""
    t = r.widths[0] * unit_draw(r.distribution, rng, 3)
    w = r.widths[1] * unit_draw(r.distribution, rng, 3)
    return make_pose(Rotation.from_rotvec(w).as_matrix(), t)


def draw(resolved: dict[str, Resolved], band_m: float, rng: np.random.Generator) -> Draw:
    """This trial's per-trial systematic effects, in a fixed order (linearity, time skew,
    kinematics, hand-eye, placement): a source's draw does not depend on which later ones run."""
    fields: dict[str, Any] = {}
    lin = resolved.get("linearity")
    if lin is not None and lin.treatment == "per_trial":
        phase = float(rng.uniform(0.0, 360.0))
        amp = float(rng.uniform(0.0, 1.0)) if lin.amplitude == "uniform" else 1.0
        fields.update(linearity_phase_deg=phase, linearity_m=amp * band_m)
    skew = resolved.get("time_skew")
    if skew is not None and skew.treatment == "per_trial":
        fields["time_skew_s"] = float(skew.widths[0] * unit_draw(skew.distribution, rng))
    kin = resolved.get("kinematics")
    if kin is not None and kin.treatment == "per_trial":
        links = []
        for body in LINK_BODIES[1:]:
            dpos = kin.widths[0] * unit_draw(kin.distribution, rng, 3)
            dR = Rotation.from_rotvec(kin.widths[1] * unit_draw(kin.distribution, rng, 3)).as_matrix()
            links.append((body, dpos, dR))
        fields["link_errors"] = tuple(links)
    for name, key in (("hand_eye", "T_hand_eye_error"), ("part_pose", "T_part_error")):
        r = resolved.get(name)
        if r is not None and r.treatment == "per_trial":
            fields[key] = _twist_pose(r, rng)
    return Draw(**fields)


def describe(r: Resolved, scenario) -> str:
    """How the report names a source's treatment."""
    if r.treatment == "off":
        return "off"
    if r.treatment == "per_reading":
        return "random per reading"
    if r.treatment == "fixed":
        if r.name == "part_pose":
            return "fixed: the scenario's true placement"
        value = {"linearity": lambda: f"phase {scenario.sensor.linearity_phase_deg:g} deg, amplitude the band",
                 "time_skew": lambda: f"{scenario.noise.time_skew_s:g} s",
                 "kinematics": lambda: "one draw for the study (the scenario's seed)",
                 "hand_eye": lambda: "the scenario's error"}[r.name]()
        return f"fixed ({value}) in every trial: a bias of the estimate, not in the intervals"
    if r.name == "linearity":
        amp = "uniform on [0, band]" if r.amplitude == "uniform" else "the band"
        return f"drawn per trial: a sensor unit (phase uniform on [0, 360) deg, amplitude {amp})"
    units = {"time_skew": ("s",), "kinematics": ("m", "rad"), "hand_eye": ("m", "rad"), "part_pose": ("m", "rad")}
    widths = ", ".join(f"{w:g} {u}" for w, u in zip(r.widths, units[r.name], strict=True))
    per = " per component" if r.name != "time_skew" else ""
    return f"drawn per trial: {r.distribution}, width {widths}{per}"
