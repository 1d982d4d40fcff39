"""DMIS output: a run's results as the ``FA()`` and ``TA()`` statements a CMM writes to its
output file (``.dmo``), in millimetres and decimal degrees, with the nominal, limits and deviation
of each tolerance in a ``$$`` comment above its ``TA()`` line.

``FA(label)=FEAT/...`` gives the actual feature in the alignment active at its ``OUTPUT``;
``TA(label)=TOL/kind,value,INTOL|OUTOL`` the tolerance's deviation (the zone's value for form,
orientation and position tolerances), or ``$$ TA(label) not evaluated: why``. Reading the file
back with :func:`~algorithms.probing.dmis.reader.parse_program` gives the actuals as ``FA``
features.
"""

from __future__ import annotations

import numpy as np

from algorithms.probing.dmis.evaluation import Evaluation, ToleranceResult
from algorithms.probing.dmis.model import DmisModel, Feature

#: Decimals of millimetre values and of unit-vector components in the output.
MM_DECIMALS = 4
UNIT_DECIMALS = 6


def _mm(x_m: float) -> str:
    return f"{x_m * 1e3:.{MM_DECIMALS}f}"


def _vec_mm(v) -> str:
    return ",".join(_mm(float(x)) for x in v)


def _vec(v) -> str:
    return ",".join(f"{float(x):.{UNIT_DECIMALS}f}" for x in v)


def feature_statement(prefix: str, f: Feature) -> str:
    """``prefix(label)=FEAT/...`` of feature ``f`` (its frame, mm)."""
    head = f"{prefix}({f.label})=FEAT/{f.kind},"
    side = "" if f.inner is None else ("INNER," if f.inner else "OUTER,")
    if f.kind == "SPHERE":
        return f"{head}{side}CART,{_vec_mm(f.point_m)},{_mm(f.size_m or 0.0)}"
    if f.kind == "LINE":
        assert f.direction is not None
        normal = f.normal if f.normal is not None else np.zeros(3)
        if f.size_m is not None:
            return f"{head}BND,CART,{_vec_mm(f.point_m)},{_vec_mm(f.point_m + f.size_m * f.direction)},{_vec(normal)}"
        return f"{head}UNBND,CART,{_vec_mm(f.point_m)},{_vec(f.direction)},{_vec(normal)}"
    assert f.direction is not None
    tail = ""
    if f.kind in ("CIRCLE", "CYLNDR"):
        tail = f",{_mm(f.size_m or 0.0)}"
    elif f.kind == "CONE":
        tail = f",{np.degrees(f.angle_rad or 0.0):.{UNIT_DECIMALS}f}"
    return f"{head}{side}CART,{_vec_mm(f.point_m)},{_vec(f.direction)}{tail}"


def write_output(model: DmisModel, ev: Evaluation) -> str:
    """The DMIS output text of ``model``'s run (see the module docstring)."""
    lines = [f"DMISMN/'{model.name}',05.3", "UNITS/MM,ANGDEC", f"$$ verdict: {ev.verdict}"]
    for out in ev.outputs:
        lines.append(f"$$ OUTPUT at {out.request.where}")
        for label, nominal, actual in out.features:
            lines.append(feature_statement("F", nominal))
            result = ev.features.get(label.upper())
            lines.append(feature_statement("FA", actual) if actual is not None
                         else f"$$ FA({label}) has no actual: {result.note if result else 'it is not measured'}")
        for t in out.tolerances:
            lines += tolerance_lines(t)
    lines.append("ENDFIL")
    return "\n".join(lines) + "\n"


def tolerance_lines(t: ToleranceResult) -> list[str]:
    """The ``$$`` comment and ``TA()`` statement of one tolerance result."""
    on = ",".join(t.features)
    if t.in_tolerance is None:
        return [f"$$ TA({t.label}) on {on} not evaluated: {t.note}"]
    assert t.nominal_m is not None and t.actual_m is not None and t.lower_m is not None and t.upper_m is not None
    return [f"$$ TA({t.label}) on {on}: nominal {_mm(t.nominal_m)}, actual {_mm(t.actual_m)}, limits "
            f"{_mm(t.lower_m)} to {_mm(t.upper_m)} mm" + (f"; {t.note}" if t.note else ""),
            f"TA({t.label})=TOL/{t.kind},{_mm(t.deviation_m or 0.0)},{'INTOL' if t.in_tolerance else 'OUTOL'}"]
