"""A read program written back as plain DMIS 5.3: what it does, with its flow unrolled.

:func:`write_model` writes a :class:`~algorithms.probing.dmis.model.DmisModel` in program order:
loops, jumps, conditions, macros, variables and called files executed away, every value a
number in millimetres and decimal degrees, every ``PTMEAS`` with its ``i,j,k``, every probing
distance set where it changes. Coordinates are written in the alignment active where each
statement stood, as the original did, so the text reads back (:func:`~algorithms.probing.dmis.
reader.parse_program`) to the same features, touches, moves, alignments, tolerances and outputs
(to the 1 nm and 1e-12 the numbers are written with). Statements the reader skipped are not
written.
"""

from __future__ import annotations

import math

import numpy as np

from algorithms.probing.dmis.evaluation import alignment_frame
from algorithms.probing.dmis.model import DmisModel, Feature, Measurement, Move, StylusChange, Tolerance, Touch
from algorithms.probing.dmis.reader import SNSET_WORDS
from algorithms.probing.program import ProbeSettings

_AXIS = ("X", "Y", "Z")


def _fixed(x: float, decimals: int) -> str:
    """``x`` with ``decimals`` decimals, a zero always unsigned (so a written program is a fixed point)."""
    text = f"{x:.{decimals}f}"
    return text.lstrip("-") if float(text) == 0.0 else text


def _mm(x_m: float) -> str:
    return _fixed(x_m * 1e3, 6)


def _unit(c: float) -> str:
    return _fixed(c, 12)


class _Writer:
    def __init__(self, model: DmisModel) -> None:
        self.model = model
        self.frames: dict[int | None, np.ndarray] = {None: np.eye(4)}
        self.alignment: int | None = None
        self.settings = ProbeSettings()
        self.lines = [f"DMISMN/'{model.name}',05.3", "UNITS/MM,ANGDEC"]
        self.lines += [f"SNSET/{w},{_mm(getattr(self.settings, n))}" for w, n in SNSET_WORDS.items()]

    def frame(self) -> np.ndarray:
        if self.alignment not in self.frames:
            alignment_frame(self.model.alignments, self.alignment, self.model.features, self.frames)  # type: ignore[arg-type]
        return self.frames[self.alignment]

    def point(self, p: np.ndarray) -> str:
        T = self.frame()
        return ",".join(_mm(x) for x in T[:3, :3].T @ (p - T[:3, 3]))

    def direction(self, d: np.ndarray) -> str:
        return ",".join(_unit(x) for x in self.frame()[:3, :3].T @ d)

    def feature(self, prefix: str, f: Feature) -> str:
        head = f"{prefix}({f.label})=FEAT/{f.kind},"
        side = "" if f.inner is None else ("INNER," if f.inner else "OUTER,")
        if f.kind == "SPHERE":
            return f"{head}{side}CART,{self.point(f.point_m)},{_mm(f.size_m or 0.0)}"
        assert f.direction is not None
        if f.kind == "LINE":
            assert f.normal is not None
            if f.size_m is not None:
                end = f.point_m + f.size_m * f.direction
                return f"{head}BND,CART,{self.point(f.point_m)},{self.point(end)},{self.direction(f.normal)}"
            return f"{head}UNBND,CART,{self.point(f.point_m)},{self.direction(f.direction)},{self.direction(f.normal)}"
        tail = ""
        if f.kind in ("CIRCLE", "CYLNDR"):
            tail = f",{_mm(f.size_m or 0.0)}"
        elif f.kind == "CONE":
            tail = "," + _fixed(math.degrees(f.angle_rad or 0.0), 12)
        return f"{head}{side}CART,{self.point(f.point_m)},{self.direction(f.direction)}{tail}"

    def touch(self, t: Touch) -> list[str]:
        out = [f"SNSET/{w},{_mm(getattr(t.settings, n))}" for w, n in SNSET_WORDS.items()
               if getattr(t.settings, n) != getattr(self.settings, n)]
        self.settings = t.settings
        return out + [f"PTMEAS/CART,{self.point(t.point_m)},{self.direction(t.normal)}"]

    def measurement(self, m: Measurement) -> None:
        kind = self.model.features[m.feature.upper()].kind
        body: list[str] = []
        for e in m.events:
            if isinstance(e, Touch):
                body += self.touch(e)
            elif isinstance(e, Move):
                body.append(f"GOTO/CART,{self.point(e.xyz_m)}")
        self.lines += [f"MEAS/{kind},F({m.feature}),{m.requested}", *body, "ENDMES"]

    def alignment_step(self, index: int, name: str | None) -> None:
        step = self.model.alignments[index]
        head = f"D({name})=" if name and step.op != "recall" else ""
        if step.op == "recall":
            self.lines.append(f"RECALL/D({name})" if name else "$$ RECALL of the base frame")
        elif step.op == "datset":
            parts = []
            for label, roles in step.args:
                parts += [f"FA({label})", *roles]
            self.lines.append(f"{head}DATSET/{','.join(parts)}")
        elif step.op == "trans":
            parts = []
            for axis, what in step.args:
                parts += [f"{_AXIS[axis]}ORIG", f"FA({what})" if isinstance(what, str) else _mm(what)]
            self.lines.append(f"{head}TRANS/{','.join(parts)}")
        else:
            axis, angle = step.args
            self.lines.append(f"{head}ROTATE/{_AXIS[axis]}AXIS,{_fixed(math.degrees(angle), 12)}")
        self.alignment = index

    def tolerance(self, t: Tolerance) -> str:
        p = t.params
        head = f"T({t.label})=TOL/{t.kind},"
        if t.kind in ("FLAT", "CIRLTY"):
            return head + _mm(p["zone_m"])
        if t.kind == "DIAM":
            return head + f"{_mm(p['lower_m'])},{_mm(p['upper_m'])}"
        if t.kind == "POS":
            return head + f"{p['dim']},{_mm(p['zone_m'])},{p['modifier']}"
        if t.kind in ("PARLEL", "PERP"):
            return head + f"{_mm(p['zone_m'])},FA({p['datum']})"
        if t.kind == "CORTOL":
            axis = p["axis"] if isinstance(p["axis"], str) else f"{_AXIS[p['axis']]}AXIS"
            return head + f"{axis},{_mm(p['lower_m'])},{_mm(p['upper_m'])}"
        axis = p["axis"] if isinstance(p["axis"], str) else f"{_AXIS[p['axis']]}AXIS"
        nominal = "" if p["nominal_m"] is None else f"NOMINL,{_mm(p['nominal_m'])},"
        ref = f",FA({p['reference']})" if p.get("reference") else ""
        return head + f"{nominal}{_mm(p['lower_m'])},{_mm(p['upper_m'])}{ref},{axis},{p['mode']}"

    def write(self) -> str:
        m = self.model
        for kind, item in m.items:
            if kind in ("feature", "actual"):
                self.lines.append(self.feature("F" if kind == "feature" else "FA", item))
            elif kind == "stylus":
                assert isinstance(item, StylusChange)
                self.lines.append(f"SNSLCT/SA({item.name})")
            elif kind == "move":
                assert isinstance(item, Move)
                self.lines.append(f"GOTO/CART,{self.point(item.xyz_m)}")
            elif kind == "meas":
                self.measurement(item)
            elif kind == "const":
                self.lines.append(f"CONST/{item.kind},F({item.label}),{item.method},"
                                  + ",".join(f"FA({x})" for x in item.inputs))
            elif kind == "datdef":
                letter, label = item
                self.lines.append(f"DATDEF/FA({label}),DAT({letter})")
            elif kind == "align":
                self.alignment_step(*item)
            elif kind == "save":
                self.lines.append(f"SAVE/D({item})")
            elif kind == "tol":
                self.lines.append(self.tolerance(item))
            elif kind == "output":
                self.lines.append("OUTPUT/" + ",".join([*(f"FA({x})" for x in item.features),
                                                        *(f"TA({x})" for x in item.tolerances)]))
        self.lines.append("ENDFIL")
        return "\n".join(self.lines) + "\n"


def write_model(model: DmisModel) -> str:
    """``model`` as plain DMIS 5.3 text (see the module docstring)."""
    return _Writer(model).write()
