"""A DMIS program's results from its measured points: the actual features, the alignments rebuilt
from the measured datums, each tolerance an ``OUTPUT`` asks for with its nominal, actual, limits,
deviation and in/out, and the program's verdict.

How each value is taken (what a CMM's software does, and what this module chose where DMIS leaves
it to the software):

* features: least-squares fits of the compensated touch points
  (:func:`~algorithms.probing.dmis.geometry.fitted`); a circle lies in the plane normal to its
  nominal axis through the points' mean;
* alignments: ``DATSET`` (3-2-1: the first direction, the second made perpendicular to it, the
  third their cross product; each origin the datum's point along that axis), ``TRANS`` and
  ``ROTATE`` rebuilt from the actual datums. Nominals are compared in the alignment built from the
  nominal datums, actuals in the one built from the measured datums, so a part set up 0.1 mm off
  is judged in its own frame, as on a CMM;
* ``FLAT`` and ``CIRLTY``: the minimum zone (ISO 1101's default), not the least-squares range;
* ``POS``: twice the distance of the actual centre from the nominal, normal to the nominal axis
  (``2D``) or in space (``3D``), with no bonus for a material condition (RFS);
* ``PARLEL``/``PERP``: the zone of the measured points (plane) or of the axis over the measured
  length (line, cylinder) about the datum's direction;
* ``DISTWRT``/``DISTB``: along ``XAXIS``/``YAXIS``/``ZAXIS`` of the output's alignment, or point to
  point (``PT2PT``); to a plane, along its normal; ``MIN``/``MAX`` over the measured points,
  ``AVG`` from the fitted feature.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from algorithms.arraytypes import FloatArray
from algorithms.errors import AlgorithmError
from algorithms.probing.dmis import geometry
from algorithms.probing.dmis.model import AlignmentStep, DmisModel, Feature, OutputRequest, Tolerance, Where

#: The tolerances evaluated.
TOLERANCE_KINDS = ("DISTWRT", "DISTB", "FLAT", "CIRLTY", "DIAM", "POS", "PARLEL", "PERP", "CORTOL")

_AXIS_WORDS = {"XAXIS": 0, "YAXIS": 1, "ZAXIS": 2, "PT2PT": "PT2PT", "RADIAL": "RADIAL"}


# --- alignments ---------------------------------------------------------------------------------


def _rotation(axis: int, angle: float) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _datset(parent: FloatArray, items: tuple, features: Mapping[str, Feature], where: Where) -> FloatArray:
    R = parent[:3, :3].copy()
    o = parent[:3, 3].copy()
    axes: dict[int, FloatArray] = {}
    for label, roles in items:
        f = features[label.upper()]
        for role in roles:
            name = role.lstrip("-")
            if not name.endswith("DIR"):
                continue
            if f.direction is None:
                raise AlgorithmError(f"{where}: DATSET takes a direction ({name}) from {label}, a {f.kind} without one")
            v = -f.direction if role.startswith("-") else f.direction
            for a in axes.values():
                v = v - (v @ a) * a
            n = float(np.linalg.norm(v))
            if n < 1e-9:
                raise AlgorithmError(f"{where}: DATSET's {name} from {label} is parallel to an axis already set")
            axes["XYZ".index(name[0])] = v / n
    if len(axes) == 1:
        (i, a), = axes.items()
        j = (i + 1) % 3
        v = R[:, j] - (R[:, j] @ a) * a
        if np.linalg.norm(v) < 1e-9:
            j = (i + 2) % 3
            v = R[:, j] - (R[:, j] @ a) * a
        axes[j] = v / np.linalg.norm(v)
    if len(axes) == 2:
        (i, a), (j, b) = sorted(axes.items())
        k = 3 - i - j
        axes[k] = np.cross(a, b) if (j - i) % 3 == 1 else -np.cross(a, b)  # right-handed
    if len(axes) == 3:
        R = np.column_stack([axes[0], axes[1], axes[2]])
        if np.linalg.det(R) < 0:
            raise AlgorithmError(f"{where}: DATSET's axes form a left-handed frame")
    for label, roles in items:
        f = features[label.upper()]
        for role in roles:
            if role.lstrip("-").endswith("ORIG"):
                e = R[:, "XYZ".index(role.lstrip("-")[0])]
                o = o + ((f.point_m - o) @ e) * e
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, o
    return T


def alignment_frame(steps: list[AlignmentStep], index: int, features: Mapping[str, Feature],
                    frames: dict[int | None, FloatArray]) -> FloatArray:
    """T_base_alignment of alignment step ``index``, its parents taken from ``frames`` (filled as
    computed) and its datums from ``features`` (upper-case labels)."""
    if index in frames:
        return frames[index]
    step = steps[index]
    parent = frames[None] if step.parent is None else alignment_frame(steps, step.parent, features, frames)
    if step.op == "recall":
        T = parent
    elif step.op == "datset":
        T = _datset(parent, step.args, features, step.where)
    elif step.op == "rotate":
        axis, angle = step.args
        T = parent.copy()
        T[:3, :3] = parent[:3, :3] @ _rotation(axis, angle)
    else:  # trans
        T = parent.copy()
        for axis, what in step.args:
            e = T[:3, axis]
            if isinstance(what, str):
                T[:3, 3] = T[:3, 3] + ((features[what.upper()].point_m - T[:3, 3]) @ e) * e
            else:
                T[:3, 3] = T[:3, 3] + what * e
    frames[index] = T
    return T


def in_frame(f: Feature, T: FloatArray) -> Feature:
    """``f`` (base frame) expressed in the frame ``T`` = T_base_frame."""
    R, o = T[:3, :3], T[:3, 3]
    return replace(f, point_m=R.T @ (f.point_m - o),
                   direction=None if f.direction is None else R.T @ f.direction,
                   normal=None if f.normal is None else R.T @ f.normal)


# --- tolerance parameters -----------------------------------------------------------------------


def _zone_params(kind: str, f: list[str], words: list[str], reader: Any) -> dict:
    """FLAT, CIRLTY: zone; POS: 2D|3D,zone[,MMC|LMC|RFS]...; PARLEL, PERP: zone,DAT(x)."""
    if kind == "POS":
        if len(f) < 2 or words[0] not in ("2D", "3D"):
            raise AlgorithmError("TOL/POS takes 2D|3D,zone[,MMC|LMC|RFS][,DAT(x)...]")
        return {"dim": words[0], "zone_m": _positive(reader.length_m(f[1], "TOL/POS zone"), kind),
                "modifier": next((w for w in words[2:] if w in ("MMC", "LMC", "RFS")), "RFS")}
    if len(f) < 1:
        raise AlgorithmError(f"TOL/{kind} takes its zone")
    params: dict[str, Any] = {"zone_m": _positive(reader.length_m(f[0], f"TOL/{kind} zone"), kind)}
    if kind in ("PARLEL", "PERP"):
        refs = [x for x in f[1:] if "(" in x]
        if not refs:
            raise AlgorithmError(f"TOL/{kind} takes zone,DAT(x) (or FA(x))")
        params["datum"] = reader.feature(refs[0], f"TOL/{kind}'s datum").label
    return params


def _limit_params(kind: str, f: list[str], words: list[str], reader: Any) -> dict:
    """DIAM: lotol,uptol; CORTOL: XAXIS|YAXIS|ZAXIS|RADIAL,lotol,uptol."""
    if kind == "DIAM":
        if len(f) < 2:
            raise AlgorithmError("TOL/DIAM takes lotol,uptol")
        return {"lower_m": reader.length_m(f[0], "TOL/DIAM lower"), "upper_m": reader.length_m(f[1], "TOL/DIAM upper")}
    if len(f) < 3 or words[0] not in ("XAXIS", "YAXIS", "ZAXIS", "RADIAL"):
        raise AlgorithmError("TOL/CORTOL takes XAXIS|YAXIS|ZAXIS|RADIAL,lotol,uptol")
    return {"axis": _AXIS_WORDS[words[0]], "lower_m": reader.length_m(f[1], "TOL/CORTOL lower"),
            "upper_m": reader.length_m(f[2], "TOL/CORTOL upper")}


def _distance_params(kind: str, f: list[str], words: list[str], reader: Any) -> dict:
    """DISTWRT, DISTB: [NOMINL,value,]lotol,uptol, then the reference (DISTWRT), the axis and
    AVG|MIN|MAX in any order."""
    nominal = None
    if words and words[0] == "NOMINL":
        if len(f) < 2:
            raise AlgorithmError(f"TOL/{kind},NOMINL takes its value")
        nominal = reader.length_m(f[1], f"TOL/{kind} nominal")
        f, words = f[2:], words[2:]
    if len(f) < 2:
        raise AlgorithmError(f"TOL/{kind} takes [NOMINL,distance,]lotol,uptol,...")
    params: dict[str, Any] = {"nominal_m": nominal, "lower_m": reader.length_m(f[0], f"TOL/{kind} lower"),
                              "upper_m": reader.length_m(f[1], f"TOL/{kind} upper"), "axis": "PT2PT", "mode": "AVG",
                              "reference": None}
    for x, w in zip(f[2:], words[2:], strict=True):
        if w in _AXIS_WORDS:
            params["axis"] = _AXIS_WORDS[w]
        elif w in ("AVG", "MIN", "MAX"):
            params["mode"] = w
        elif "(" in x and kind == "DISTWRT":
            params["reference"] = reader.feature(x, "TOL/DISTWRT's reference").label
    if kind == "DISTWRT" and params["reference"] is None:
        raise AlgorithmError("TOL/DISTWRT takes its reference feature or datum (FA(x) or DAT(x))")
    return params


def tolerance_params(kind: str, fields: tuple[str, ...] | list[str], reader: Any) -> dict:
    """The parameters of ``T(label)=TOL/kind,fields`` (lengths [m]); ``reader`` converts units and
    resolves labels (:class:`~algorithms.probing.dmis.reader.Reader`)."""
    f = [x.strip() for x in fields]
    words = [x.upper() for x in f]
    if kind in ("FLAT", "CIRLTY", "POS", "PARLEL", "PERP"):
        return _zone_params(kind, f, words, reader)
    if kind in ("DIAM", "CORTOL"):
        return _limit_params(kind, f, words, reader)
    return _distance_params(kind, f, words, reader)


def _positive(v: float, kind: str) -> float:
    if v <= 0:
        raise AlgorithmError(f"TOL/{kind} zone must be positive, got {v * 1e3:g} mm")
    return v


# --- results ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FeatureResult:
    """A feature's nominal and actual (base frame), its measured points and residuals [m], its form
    (the minimum zone for planes and circles, else the residuals' range) [m], or why it has no actual."""

    label: str
    nominal: Feature
    actual: Feature | None
    points_m: FloatArray
    residuals_m: FloatArray
    form_m: float | None
    note: str = ""


@dataclass(frozen=True)
class ToleranceResult:
    """One tolerance on one feature (or pair): values in metres (radians for none here).

    ``lower``/``upper``: the limits of ``actual``; ``deviation``: actual - nominal (the zone value
    itself for form, orientation and position); ``in_tolerance``: None when it could not be evaluated
    (``note`` says why)."""

    label: str
    kind: str
    features: tuple[str, ...]
    nominal_m: float | None
    actual_m: float | None
    lower_m: float | None
    upper_m: float | None
    deviation_m: float | None
    in_tolerance: bool | None
    note: str
    where: Where


@dataclass(frozen=True)
class OutputResult:
    """What one ``OUTPUT`` reports: each feature (label, nominal, actual or None) in the output's
    alignment, and each tolerance's result."""

    request: OutputRequest
    features: tuple[tuple[str, Feature, Feature | None], ...]
    tolerances: tuple[ToleranceResult, ...]


@dataclass
class Evaluation:
    """The results of a run: each feature, and what each OUTPUT reports, in program order."""

    features: dict[str, FeatureResult] = field(default_factory=dict)
    outputs: list[OutputResult] = field(default_factory=list)

    @property
    def tolerances(self) -> list[ToleranceResult]:
        return [t for o in self.outputs for t in o.tolerances]

    @property
    def verdict(self) -> str:
        """``PASS``: every tolerance asked for evaluated and in; ``FAIL``: one out; ``INCOMPLETE``: one not
        evaluated (and none out)."""
        results = [t.in_tolerance for t in self.tolerances]
        if any(r is False for r in results):
            return "FAIL"
        return "INCOMPLETE" if any(r is None for r in results) else "PASS"


def _actual_features(model: DmisModel, measured: list[FloatArray | None]) -> dict[str, FeatureResult]:
    index = {id(t): k for k, t in enumerate(model.touches)}
    results: dict[str, FeatureResult] = {}
    for m in model.measurements:
        nominal = model.features[m.feature.upper()]
        pts = [measured[index[id(t)]] for t in m.touches]
        got = np.array([p for p in pts if p is not None]).reshape(-1, 3)
        missed = sum(p is None for p in pts)
        try:
            actual, res = geometry.fitted(nominal, got)
            note = f"{missed} of {len(pts)} touches missed" if missed else ""
        except AlgorithmError as e:
            actual, res = None, np.zeros(0)
            note = str(e) + (f" ({missed} of {len(pts)} touches missed)" if missed else "")
        form = None
        if actual is not None and len(got) >= geometry.MIN_POINTS[nominal.kind] + 1:
            if nominal.kind == "PLANE":
                form = geometry.min_zone_flatness(got, geometry.direction_of(actual))
            elif nominal.kind == "CIRCLE":
                form = _roundness(actual, got)
            elif nominal.kind != "POINT":
                form = float(np.ptp(res))
        results[m.feature.upper()] = FeatureResult(nominal.label, nominal, actual, got, res, form, note)
    for label, given in model.actuals.items():
        if label in model.features and label not in results:
            results[label] = FeatureResult(given.label, model.features[label], given, np.zeros((0, 3)), np.zeros(0),
                                           None, "given in the program as FA()")
    for c in model.constructions:
        nominal = model.features[c.label.upper()]
        inputs = [results.get(x.upper()) for x in c.inputs]
        missing = [x for x, r in zip(c.inputs, inputs, strict=True) if r is None or r.actual is None]
        if missing:
            results[c.label.upper()] = FeatureResult(c.label, nominal, None, np.zeros((0, 3)), np.zeros(0), None,
                                                     f"built from {', '.join(missing)}, which has no actual")
            continue
        try:
            actual = geometry.construct(c.label, c.kind, c.method, [r.actual for r in inputs], nominal, c.where)  # type: ignore[union-attr,misc]
            results[c.label.upper()] = FeatureResult(c.label, nominal, actual, np.zeros((0, 3)), np.zeros(0), None)
        except AlgorithmError as e:
            results[c.label.upper()] = FeatureResult(c.label, nominal, None, np.zeros((0, 3)), np.zeros(0), None,
                                                     str(e))
    return results


def _roundness(actual: Feature, pts: FloatArray) -> float:
    assert actual.direction is not None
    u, v = geometry.plane_frame(actual.direction)
    uv = np.column_stack([(pts - actual.point_m) @ u, (pts - actual.point_m) @ v])
    return geometry.min_zone_roundness(uv, np.zeros(2))


def evaluate(model: DmisModel, measured_m: list[FloatArray | None]) -> Evaluation:
    """The results of ``model`` run with ``measured_m``: one compensated surface point [m] (base
    frame) or None (a miss) per touch, in the order of ``model.touches``."""
    if len(measured_m) != len(model.touches):
        raise AlgorithmError(f"evaluate takes one measured point per touch: {len(model.touches)} touches, "
                             f"{len(measured_m)} points")
    ev = Evaluation(_actual_features(model, measured_m))
    nominal_features = model.features
    actual_features = {k: r.actual for k, r in ev.features.items() if r.actual is not None}
    nominal_frames: dict[int | None, FloatArray] = {None: np.eye(4)}
    actual_frames: dict[int | None, FloatArray] = {None: np.eye(4)}
    for out in model.outputs:
        T_nom = nominal_frames[None] if out.alignment is None else alignment_frame(
            model.alignments, out.alignment, nominal_features, nominal_frames)
        unaligned = _unmeasured_datums(model, out.alignment, actual_features)
        T_act = T_nom if unaligned else actual_frames[None] if out.alignment is None else alignment_frame(
            model.alignments, out.alignment, actual_features, actual_frames)
        reported = []
        for label in out.features:
            r = ev.features.get(label.upper())
            nominal = in_frame(nominal_features[label.upper()], T_nom)
            reported.append((label, nominal, None if r is None or r.actual is None else in_frame(r.actual, T_act)))
        results = [res for t in out.tolerances
                   for res in _tolerance(model.tolerances[t.upper()], out, ev, nominal_features, T_nom, T_act)]
        if unaligned:  # a result in an alignment whose datums were not all measured is no result
            notes = [ev.features[x.upper()].note for x in unaligned if x.upper() in ev.features]
            why = (f"the alignment of this OUTPUT is built on {', '.join(unaligned)}, which has no actual "
                   f"({'; '.join(n for n in notes if n) or 'not measured'})")
            results = [replace(r, actual_m=None, deviation_m=None, in_tolerance=None, note=why) for r in results]
        ev.outputs.append(OutputResult(out, tuple(reported), tuple(results)))
    return ev


def _unmeasured_datums(model: DmisModel, index: int | None, actuals: Mapping[str, Feature]) -> list[str]:
    """The features alignment ``index`` (and its parents) is built on that have no actual."""
    out: list[str] = []
    while index is not None:
        step = model.alignments[index]
        if step.op == "datset":
            out += [label for label, _ in step.args if label.upper() not in actuals]
        elif step.op == "trans":
            out += [what for _, what in step.args if isinstance(what, str) and what.upper() not in actuals]
        index = step.parent
    return list(dict.fromkeys(out))


def _missing(tol: Tolerance, labels: tuple[str, ...], why: str) -> ToleranceResult:
    return ToleranceResult(tol.label, tol.kind, labels, None, None, None, None, None, None, why, tol.where)


def _tolerance(tol: Tolerance, out: OutputRequest, ev: Evaluation, nominals: Mapping[str, Feature],
               T_nom: FloatArray, T_act: FloatArray) -> list[ToleranceResult]:
    labels = out.features
    if not labels:
        return [_missing(tol, (), "the OUTPUT names no feature for this tolerance")]
    if tol.kind == "DISTB":
        if len(labels) < 2:
            return [_missing(tol, labels, "TOL/DISTB is reported on two features: OUTPUT/FA(a),FA(b),TA(t)")]
        return [_one(tol, (labels[0], labels[1]), ev, nominals, T_nom, T_act)]
    return [_one(tol, (label,), ev, nominals, T_nom, T_act) for label in labels]


def _one(tol: Tolerance, labels: tuple[str, ...], ev: Evaluation, nominals: Mapping[str, Feature],
         T_nom: FloatArray, T_act: FloatArray) -> ToleranceResult:
    results = [ev.features.get(x.upper()) for x in labels]
    for x, r in zip(labels, results, strict=True):
        if r is None:
            return _missing(tol, labels, f"{x} is not measured or constructed")
        if r.actual is None:
            return _missing(tol, labels, f"{x} has no actual: {r.note}")
    rs: list[FeatureResult] = results  # type: ignore[assignment]
    nom = [in_frame(r.nominal, T_nom) for r in rs]
    act = [in_frame(r.actual, T_act) for r in rs]  # type: ignore[arg-type]
    pts = [(r.points_m - T_act[:3, 3]) @ T_act[:3, :3] for r in rs]
    try:
        if tol.kind in ("FLAT", "CIRLTY", "DIAM", "POS", "CORTOL"):
            return _feature_tolerance(tol, labels, rs[0], nom[0], act[0])
        if tol.kind in ("PARLEL", "PERP"):
            return _orientation(tol, labels, act[0], pts[0], ev, T_act)
        return _distance_tolerance(tol, labels, ev, nominals, nom, act, pts, T_nom, T_act)
    except AlgorithmError as e:
        return _missing(tol, labels, str(e))


def _feature_tolerance(tol: Tolerance, labels: tuple[str, ...], r: FeatureResult, nom: Feature, act: Feature
                       ) -> ToleranceResult:
    """FLAT, CIRLTY (the feature's minimum zone), DIAM, POS and CORTOL of one feature."""
    p, kind = tol.params, tol.kind
    if kind in ("FLAT", "CIRLTY"):
        want = "PLANE" if kind == "FLAT" else "CIRCLE"
        if r.nominal.kind != want or r.form_m is None:
            return _missing(tol, labels, f"TOL/{kind} applies to a {want} with more than "
                                         f"{geometry.MIN_POINTS[want]} points")
        return _zone(tol, labels, r.form_m, p["zone_m"], "minimum zone")
    if kind == "DIAM":
        if nom.size_m is None or r.nominal.kind not in ("CIRCLE", "CYLNDR", "SPHERE"):
            return _missing(tol, labels, "TOL/DIAM applies to a circle, cylinder or sphere")
        return _limits(tol, labels, nom.size_m, act.size_m, p["lower_m"], p["upper_m"])
    d = act.point_m - nom.point_m
    if kind == "POS":
        if p["dim"] == "2D" and nom.direction is not None:
            d = d - (d @ nom.direction) * nom.direction
        note = "RFS: no bonus" + (f" ({p['modifier']} given)" if p["modifier"] != "RFS" else "")
        return _zone(tol, labels, 2 * float(np.linalg.norm(d)), p["zone_m"], note)
    if p["axis"] == "RADIAL":
        value_nom, value_act = float(np.hypot(*nom.point_m[:2])), float(np.hypot(*act.point_m[:2]))
    else:
        value_nom, value_act = float(nom.point_m[p["axis"]]), float(nom.point_m[p["axis"]] + d[p["axis"]])
    return _limits(tol, labels, value_nom, value_act, p["lower_m"], p["upper_m"])


def _distance_tolerance(tol: Tolerance, labels: tuple[str, ...], ev: Evaluation, nominals: Mapping[str, Feature],
                        nom: list[Feature], act: list[Feature], pts: list[FloatArray], T_nom: FloatArray,
                        T_act: FloatArray) -> ToleranceResult:
    """DISTWRT (to its reference) and DISTB (between the OUTPUT's two features)."""
    p = tol.params
    if tol.kind == "DISTWRT":
        ref = ev.features.get(p["reference"].upper())
        if ref is None or ref.actual is None:
            return _missing(tol, labels, f"the reference {p['reference']} is not measured")
        ref_nom, ref_act = in_frame(nominals[p["reference"].upper()], T_nom), in_frame(ref.actual, T_act)
    else:
        ref_nom, ref_act = nom[1], act[1]
    nom_value = _distance(nom[0], np.zeros((0, 3)), ref_nom, p["axis"], "AVG")
    act_value = _distance(act[0], pts[0], ref_act, p["axis"], p["mode"])
    if p["nominal_m"] is None:
        return _limits(tol, labels, nom_value, act_value, p["lower_m"], p["upper_m"])
    r = _limits(tol, labels, p["nominal_m"], act_value, p["lower_m"], p["upper_m"])
    if abs(p["nominal_m"] - nom_value) > 1e-6:
        r = replace(r, note=f"the TOL's nominal {p['nominal_m'] * 1e3:.4f} mm is used; the features' is "
                            f"{nom_value * 1e3:.4f} mm")
    return r


def _zone(tol: Tolerance, labels: tuple[str, ...], value: float, zone: float, note: str) -> ToleranceResult:
    return ToleranceResult(tol.label, tol.kind, labels, 0.0, value, 0.0, zone, value, bool(value <= zone), note,
                           tol.where)


def _limits(tol: Tolerance, labels: tuple[str, ...], nominal: float, actual: float | None, lo: float, up: float
            ) -> ToleranceResult:
    if actual is None:
        return _missing(tol, labels, "no actual value")
    ok = nominal + lo <= actual <= nominal + up
    return ToleranceResult(tol.label, tol.kind, labels, nominal, actual, nominal + lo, nominal + up, actual - nominal,
                           bool(ok), "", tol.where)


def _distance(f: Feature, pts: FloatArray, ref: Feature, axis, mode: str) -> float:
    """The distance of ``f`` from ``ref`` (both in the output's frame), see the module docstring."""
    samples = pts if mode in ("MIN", "MAX") and len(pts) else f.point_m[None]
    if axis in (0, 1, 2):
        values = np.abs(samples[:, axis] - ref.point_m[axis])
    elif ref.kind == "PLANE" and ref.direction is not None:
        values = np.abs((samples - ref.point_m) @ ref.direction)
    elif f.kind == "PLANE" and f.direction is not None and mode == "AVG":
        values = np.abs((ref.point_m - f.point_m) @ f.direction)[None]
    else:
        values = np.linalg.norm(samples - ref.point_m, axis=1)
    return float({"MIN": values.min, "MAX": values.max}.get(mode, values.mean)())


def _orientation(tol: Tolerance, labels: tuple[str, ...], act: Feature, pts: FloatArray, ev: Evaluation,
                 T_act: FloatArray) -> ToleranceResult:
    """PARLEL and PERP of a plane (its measured points) or an axis (over its measured length)."""
    p = tol.params
    datum = ev.features.get(p["datum"].upper())
    if datum is None or datum.actual is None:
        return _missing(tol, labels, f"the datum {p['datum']} is not measured")
    dref = in_frame(datum.actual, T_act)
    if dref.direction is None or act.direction is None:
        return _missing(tol, labels, f"the datum {p['datum']} or {labels[0]} has no direction")
    ref: FloatArray = dref.direction
    datum_is_plane = dref.kind in ("PLANE", "POINT")  # ref is its normal; else ref is its axis
    d: FloatArray = act.direction
    if act.kind == "PLANE" and len(pts) >= 3:
        # the direction across the zone: the datum's normal (parallel to a plane), or the plane's own
        # normal made perpendicular to the datum's normal (perpendicular to a plane) or axis (parallel to it)
        if tol.kind == "PARLEL" and datum_is_plane:
            across = ref
        elif tol.kind == "PERP" and not datum_is_plane:
            across = ref
        else:
            across = d - (d @ ref) * ref
        across = across / np.linalg.norm(across)
        return _zone(tol, labels, float(np.ptp(pts @ across)), p["zone_m"], "zone of the measured points")
    if act.kind in ("LINE", "CYLNDR", "CONE") and len(pts) >= 2:
        length = float(np.ptp((pts - act.point_m) @ d))
        if (tol.kind == "PARLEL") == datum_is_plane:  # the axis should lie perpendicular to ref
            tilt = abs(float(d @ ref))
        else:  # the axis should lie along ref
            tilt = float(np.linalg.norm(d - (d @ ref) * ref))
        return _zone(tol, labels, length * tilt, p["zone_m"], f"axis over its measured length {length * 1e3:.3f} mm")
    return _missing(tol, labels, f"TOL/{tol.kind} is evaluated on planes, lines and axes with measured points")
