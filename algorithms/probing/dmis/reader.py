"""The reader of real DMIS 5.3 part programs: a program executed statement by statement into a
:class:`~algorithms.probing.dmis.model.DmisModel` (what it measures, how it moves, what it
evaluates), without a machine.

It reads what measurement software writes (:mod:`~algorithms.probing.dmis.lexer` for encodings,
comments and continuation lines), and executes:

* flow: ``DECL``, ``ASSIGN``, expressions in any numeric field, ``IF/(cond)`` ... ``ELSE`` ...
  ``ENDIF``, ``JUMPTO/(label)`` to a ``(label)`` line, ``DO/var,start,end[,step]`` ... ``ENDDO``,
  ``M(name)=MACRO/'p1',...`` ... ``ENDMAC`` and ``CALL/M(name),args``, ``CALL/EXTERN,DMIS,'file'``
  (a path relative to the calling file), as :class:`~algorithms.probing.dmis.flow.Interpreter`
  follows them: at most ``MAX_STATEMENTS`` statements executed and ``MAX_CALL_DEPTH`` calls deep
  (:mod:`~algorithms.probing.dmis.flow`), so a loop that never ends is refused, not run forever;
* setup: ``DMISMN``, ``UNITS`` (MM, CM, M, INCH, FEET; ANGDEC, ANGRAD, ANGDMS), ``MODE``,
  ``SNSET/APPRCH|RETRCT|SEARCH|CLRSRF`` at any point (``DEPTH`` is noted), ``SNSLCT/S()|SA()``;
* motion and measurement: ``GOTO/[CART,]x,y,z`` and ``GOTO/INCR,d,i,j,k``, ``F()=FEAT`` and
  ``FA()=FEAT`` of points, planes, lines, circles, cylinders, spheres and cones, ``MEAS`` blocks
  with ``GOTO`` and ``PTMEAS/CART,x,y,z[,i,j,k]`` at their own targets (without ``i,j,k`` the
  normal is the feature's there), and points and circles measured with no ``PTMEAS`` (the touches
  spread on the nominal);
* evaluation: ``CONST`` (see :data:`~algorithms.probing.dmis.geometry.CONSTRUCTIONS`), ``DATDEF``,
  ``DATSET``, ``TRANS``, ``ROTATE``, ``SAVE``/``RECALL`` of alignments (``D()``/``DA()``), ``TOL``
  and ``OUTPUT``.

Everything else is listed in :attr:`DmisModel.notices` with its file, line and word: statements
that neither move the machine nor change what is measured are skipped there; one that does
(:data:`REFUSED_WORDS`, a ``MEAS`` of a kind with no touches given, a ``GOTO/POL``) is refused with
an :class:`~algorithms.errors.AlgorithmError` naming its file, line and word, as are an
undefined label, an unterminated block, a call to a missing file and an endless loop.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from algorithms.errors import AlgorithmError
from algorithms.probing.dmis import geometry, lexer
from algorithms.probing.dmis.flow import (
    REFUSED_WORDS,
    SKIPPED_WORDS,
    Body,
    Interpreter,
    read_file,
    split_macros,
    structure,
)
from algorithms.probing.dmis.model import (
    FEATURE_KINDS,
    AlignmentStep,
    Construction,
    DmisModel,
    Feature,
    Measurement,
    Move,
    Notice,
    OutputRequest,
    StylusChange,
    Tolerance,
    Touch,
    Where,
    unit,
)
from algorithms.probing.program import ProbeSettings

#: The most touches a point or circle measured without PTMEAS may ask for.
MAX_AUTO_TOUCHES = 1000

#: A direction whose length is within this of 1 is taken as written, not normalised again.
UNIT_AS_WRITTEN = 2e-9

#: Millimetres per length unit, radians per angle unit.
LENGTH_UNITS_MM = {"MM": 1.0, "CM": 10.0, "M": 1000.0, "INCH": 25.4, "FEET": 304.8}
ANGLE_UNITS_RAD = {"ANGDEC": math.pi / 180.0, "ANGRAD": 1.0, "ANGDMS": math.pi / 180.0}

#: The ``SNSET`` words that set the program's probing distances.
SNSET_WORDS = {"APPRCH": "approach_m", "RETRCT": "retract_m", "SEARCH": "search_m", "CLRSRF": "clearance_m"}

_LABEL = re.compile(r"([A-Za-z]+)\s*\(\s*([^()]*?)\s*\)")
_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
_AXES = {"XAXIS": 0, "YAXIS": 1, "ZAXIS": 2, "XDIR": 0, "YDIR": 1, "ZDIR": 2, "XORIG": 0, "YORIG": 1, "ZORIG": 2}


@dataclass
class _MeasBlock:
    feature: Feature
    requested: int
    where: Where
    touches: list[Touch] = field(default_factory=list)
    events: list = field(default_factory=list)


class Reader(Interpreter):
    """What each DMIS statement does (see the module docstring); the flow is :class:`Interpreter`'s.
    Use :func:`read_program`."""

    def __init__(self, encoding: str) -> None:
        super().__init__()
        self.model: DmisModel | None = None
        self.encoding = encoding
        self.mm_per_unit = 1.0
        self.settings = {name: getattr(ProbeSettings(), name) for name in SNSET_WORDS.values()}
        self.settings_set: set[str] = set()
        self.stylus: str | None = None
        self.alignment: int | None = None
        self.frames: dict[int | None, np.ndarray] = {None: np.eye(4)}
        self.saved: dict[str, int | None] = {}
        self.meas: _MeasBlock | None = None
        self.sources: list[str] = []
        self.pending_notices: list[Notice] = []

    # --- reporting --------------------------------------------------------------------------

    def notice(self, kind: str, message: str) -> None:
        assert self.st is not None
        n = Notice(self.where(), self.st.word, kind, message)
        if self.model is None:
            self.pending_notices.append(n)
        else:
            self.model.notices.append(n)

    def skip(self, why: str) -> None:
        self.notice("skipped", why)

    def event(self, e) -> None:
        """Record a move, stylus change or touch; the first one fixes the program's starting probing distances."""
        assert self.model is not None
        if not self.model.events:
            self.model.settings = ProbeSettings(**self.settings)
        self.model.events.append(e)

    # --- files and bodies ----------------------------------------------------------------------

    def load(self, path: Path, text: str | None = None) -> Body:
        """The body of a file (macros cut out and registered)."""
        source = os.fspath(path)
        if text is None:
            text, _ = read_file(path)
        self.sources.append(source)
        statements, free = lexer.statements(text, source)
        for line, content in free:
            n = Notice(Where(source, line), "", "skipped", f"not a DMIS statement (free text): {content[:40]!r}")
            (self.model.notices if self.model else self.pending_notices).append(n)
        kept, macros = split_macros(statements, source)
        self.macros.update(macros)
        return structure(kept, source)

    # --- values ---------------------------------------------------------------------------------

    def number(self, text: str, what: str) -> float:
        text = text.strip()
        if _NUMBER.fullmatch(text):
            v = float(text)
        else:
            if not text:
                self.fail(f"{what} is empty: a number is needed")
            got = self.value(text, what)
            if isinstance(got, str):
                self.fail(f"{what} must be a number, got the string {got!r}")
            v = got
        if not math.isfinite(v):
            self.fail(f"{what} {text!r} is not a finite number")
        return v

    def length_m(self, text: str, what: str) -> float:
        return self.number(text, what) * self.mm_per_unit / 1e3

    def angle_rad(self, text: str, what: str) -> float:
        text = text.strip()
        if self.rad_per_unit == ANGLE_UNITS_RAD["ANGDMS"] and ":" in text:
            parts = text.split(":")
            sign = -1.0 if parts[0].strip().startswith("-") else 1.0
            d = [abs(self.number(p, what)) for p in parts]
            return sign * (d[0] + (d[1] if len(d) > 1 else 0) / 60 + (d[2] if len(d) > 2 else 0) / 3600) * math.pi / 180
        return self.number(text, what) * self.rad_per_unit

    def xyz_m(self, fields: tuple[str, ...] | list[str], what: str) -> np.ndarray:
        """A point in the active coordinate system and file units, in the base frame [m]."""
        p = np.array([self.length_m(f, f"{what} {a}") for a, f in zip("xyz", fields, strict=True)])
        T = self.frame()
        return T[:3, :3] @ p + T[:3, 3]

    def ijk(self, fields: tuple[str, ...] | list[str], what: str) -> np.ndarray:
        """A direction in the active coordinate system, unit, in the base frame."""
        v = np.array([self.number(f, f"{what} {a}") for a, f in zip("ijk", fields, strict=True)])
        if abs(float(np.linalg.norm(v)) - 1.0) > UNIT_AS_WRITTEN:
            v = self.unit(v, what)  # a unit vector as written is kept as written (the twin's own read back exactly)
        return self.frame()[:3, :3] @ v

    def unit(self, v: np.ndarray, what: str) -> np.ndarray:
        try:
            return unit(v, what)
        except AlgorithmError as e:
            self.fail(str(e))

    def feature(self, text: str, what: str) -> Feature:
        """The nominal feature a field names (``F()``, ``FA()`` or a datum ``DAT()``)."""
        assert self.model is not None
        kind, name = self.label(text, ("F", "FA", "DAT"), what)
        key = name.upper()
        if kind == "DAT":
            if key not in self.model.datums:
                self.fail(f"DAT({name}) is not defined: define it first with DATDEF/F(feature),DAT({name})")
            key = self.model.datums[key].upper()
        f = self.model.features.get(key) or self.model.actuals.get(key)
        if f is None:
            self.fail(f"{what}: feature {name} is not defined (define it with F({name})=FEAT/... first)")
        return f

    def frame(self, index: int | None = -1) -> np.ndarray:
        """T_base_alignment of an alignment (default: the active one), from the nominal features."""
        if index == -1:
            index = self.alignment
        return self.frames[index]

    # --- statements -------------------------------------------------------------------------

    def statement(self, st: lexer.Statement) -> None:
        word = st.word
        if self.model is None and word != "DMISMN":
            if word in ("FILNAM",) or word in SKIPPED_WORDS:
                self.skip(SKIPPED_WORDS.get(word, "does not move the machine"))
                return
            self.fail(f"{word} before DMISMN: a DMIS program starts with DMISMN/'name',version")
        if self.meas is not None and word not in ("PTMEAS", "GOTO", "ENDMES", "SNSET", "FEDRAT", "TEXT", "PAUSE"):
            if word in REFUSED_WORDS or word in ("MEAS", "SNSLCT", "CALL", "ENDFIL"):
                self.fail(f"{word} inside the MEAS block of line {self.meas.where.line}: a MEAS block holds GOTO and "
                          "PTMEAS statements, closed by ENDMES")
        handler = getattr(self, "do_" + word.lower(), None)
        if handler is not None:
            handler(st)
        elif word in REFUSED_WORDS:
            self.fail(f"{word} {REFUSED_WORDS[word]}: this reader does not run it (remove it, or run the program on "
                      "the machine it was written for)")
        elif word in SKIPPED_WORDS:
            self.skip(SKIPPED_WORDS[word])
        else:
            self.skip("not a DMIS statement this reader knows; it is taken not to move the machine")

    def do_dmismn(self, st: lexer.Statement) -> None:
        if self.model is not None:
            if self.depth > 0:
                return  # a called file's own header
            self.fail("a second DMISMN: a file holds one program")
        m = re.fullmatch(r"'([^']*)'\s*(?:,\s*(\S+))?", st.rest.strip())
        if not m or not m.group(1):
            self.fail(f"DMISMN takes 'name',version, got {st.rest!r}")
        self.model = DmisModel(m.group(1), m.group(2) or "", self.encoding)
        self.model.notices.extend(self.pending_notices)
        self.pending_notices.clear()

    def do_endfil(self, st: lexer.Statement) -> None:
        if self.meas is not None:
            self.fail(f"ENDFIL inside the MEAS block of line {self.meas.where.line}: close it with ENDMES")
        self.ended = True

    def do_units(self, st: lexer.Statement) -> None:
        f = [x.upper() for x in st.fields]
        if not f or f[0] not in LENGTH_UNITS_MM or (len(f) > 1 and f[1] not in ANGLE_UNITS_RAD):
            self.fail(f"UNITS {st.rest!r} is not read: UNITS/length,angle with length one of "
                      f"{', '.join(LENGTH_UNITS_MM)} and angle one of {', '.join(ANGLE_UNITS_RAD)}")
        self.mm_per_unit = LENGTH_UNITS_MM[f[0]]
        if len(f) > 1:
            self.rad_per_unit = ANGLE_UNITS_RAD[f[1]]
        if len(f) > 2:
            self.notice("warning", f"temperature unit {st.fields[2]} noted; the twin's part is at 20 degC")

    def do_mode(self, st: lexer.Statement) -> None:
        self.notice("skipped", f"MODE/{st.rest}: the twin runs every program in automatic mode")

    def do_snset(self, st: lexer.Statement) -> None:
        if not st.fields:
            self.fail("SNSET takes word,value")
        word = st.fields[0].upper()
        if word in SNSET_WORDS:
            if len(st.fields) != 2:
                self.fail(f"SNSET/{word} takes one distance, got {st.rest!r}")
            v = self.length_m(st.fields[1], f"SNSET/{word} distance")
            if v <= 0:
                self.fail(f"SNSET/{word} distance {st.fields[1]} is not positive: probing distances are > 0")
            self.settings[SNSET_WORDS[word]] = v
            self.settings_set.add(word)
            return
        self.skip(f"SNSET/{word}: noted, not applied (touches go to their PTMEAS targets or the feature's nominal)")

    def do_snslct(self, st: lexer.Statement) -> None:
        assert self.model is not None
        _, name = self.label(st.fields[0] if st.fields else "", ("S", "SA"), "SNSLCT's sensor")
        self.stylus = name
        ev = StylusChange(name, self.where())
        self.event(ev)
        self.model.items.append(("stylus", ev))

    def do_goto(self, st: lexer.Statement) -> None:
        assert self.model is not None
        f = list(st.fields)
        head = f[0].upper() if f else ""
        if head == "POL":
            self.fail("GOTO/POL (polar coordinates) is not read: give GOTO/CART,x,y,z")
        if head == "INCR":
            if len(f) != 5:
                self.fail(f"GOTO/INCR takes distance,i,j,k, got {st.rest!r}")
            last = self.model.moves[-1].xyz_m if self.model.moves else None
            if last is None:
                self.fail("GOTO/INCR before any absolute GOTO: where the probe starts is not known")
            p = last + self.length_m(f[1], "GOTO/INCR distance") * self.ijk(f[2:5], "GOTO/INCR direction")
        else:
            if head == "CART":
                f = f[1:]
            if len(f) < 3:
                self.fail(f"GOTO takes CART,x,y,z or x,y,z, got {st.rest!r}")
            if len(f) > 3:
                self.notice("warning", "GOTO's probe direction i,j,k noted, not applied (the head does not turn)")
            p = self.xyz_m(f[:3], "GOTO coordinate")
        move = Move(p, self.where())
        self.event(move)
        if self.meas is not None:
            self.meas.events.append(move)
        else:
            self.model.items.append(("move", move))

    def do_feat(self, st: lexer.Statement) -> None:
        assert self.model is not None
        if st.label_kind not in ("F", "FA") or not st.label:
            self.fail(f"FEAT defines a feature: F(label)=FEAT/... or FA(label)=FEAT/..., got {st.text[:60]!r}")
        kind = st.fields[0].upper() if st.fields else ""
        if kind not in FEATURE_KINDS:
            self.skip(f"FEAT/{kind}: a feature type this reader does not measure or evaluate "
                      f"({', '.join(FEATURE_KINDS)} are)")
            return
        f = self.parse_feature(st, kind)
        store = self.model.features if st.label_kind == "F" else self.model.actuals
        if st.label.upper() in store and st.label_kind == "F":
            self.notice("warning", f"F({st.label}) defined again (first at line {store[st.label.upper()].where.line}): "
                                   "the new definition is used")
        store[st.label.upper()] = f
        self.model.items.append(("feature" if st.label_kind == "F" else "actual", f))

    def parse_feature(self, st: lexer.Statement, kind: str) -> Feature:
        f = list(st.fields[1:])
        inner: bool | None = None
        if kind in ("CIRCLE", "CYLNDR", "SPHERE", "CONE"):
            if not f or f[0].upper() not in ("INNER", "OUTER"):
                self.fail(f"FEAT/{kind} takes INNER or OUTER first, got {st.rest[:60]!r}")
            inner = f.pop(0).upper() == "INNER"
        bounded = None
        if kind == "LINE":
            if not f or f[0].upper() not in ("BND", "UNBND"):
                self.fail(f"FEAT/LINE takes BND or UNBND first, got {st.rest[:60]!r}")
            bounded = f.pop(0).upper() == "BND"
        if not f or f[0].upper() != "CART":
            self.fail(f"FEAT/{kind} coordinates must be CART (POL is not read), got {st.rest[:60]!r}")
        f.pop(0)
        sizes = {"POINT": (6,), "PLANE": (6,), "LINE": (9,), "CIRCLE": (7,), "CYLNDR": (7, 8), "SPHERE": (4, 7),
                 "CONE": (7,)}[kind]
        if len(f) not in sizes and not (kind == "CONE" and len(f) == 8):
            self.fail(f"FEAT/{kind} takes {' or '.join(str(n) for n in sizes)} numbers after CART, got {len(f)}")
        where = self.where()
        label = st.label or ""
        if kind == "SPHERE":
            centre = self.xyz_m(f[:3], "sphere centre")
            return Feature(label, kind, inner, centre, None, None, self.length_m(f[-1], "sphere diameter"), None, where)
        p = self.xyz_m(f[:3], f"{kind} point")
        if kind == "LINE":
            if bounded:
                q = self.xyz_m(f[3:6], "line end")
                d = self.unit(q - p, "a bounded line's direction (its ends coincide)")
                return Feature(label, kind, None, p, d, self.ijk(f[6:9], "line normal"), float(np.linalg.norm(q - p)),
                               None, where)
            return Feature(label, kind, None, p, self.ijk(f[3:6], "line direction"), self.ijk(f[6:9], "line normal"),
                           None, None, where)
        d = self.ijk(f[3:6], f"{kind} direction")
        if kind in ("POINT", "PLANE"):
            return Feature(label, kind, None, p, d, None, None, None, where)
        if kind == "CONE":
            return Feature(label, kind, inner, p, d, None, None, self.angle_rad(f[6], "cone angle"), where)
        size = self.length_m(f[6], f"{kind} diameter")
        if size <= 0:
            self.fail(f"FEAT/{kind} diameter {f[6]} is not positive")
        return Feature(label, kind, inner, p, d, None, size, None, where)

    def do_meas(self, st: lexer.Statement) -> None:
        if len(st.fields) < 2:
            self.fail(f"MEAS takes kind,F(label),n, got {st.rest!r}")
        kind = st.fields[0].upper()
        _, name = self.label(st.fields[1], ("F",), "MEAS's feature")
        assert self.model is not None
        feature = self.model.features.get(name.upper())
        if feature is None:
            self.fail(f"MEAS of F({name}), which no FEAT defines (or of a kind this reader does not measure): define "
                      f"it first with F({name})=FEAT/...")
        if kind != feature.kind:
            self.fail(f"MEAS/{kind} of F({name}), which is a {feature.kind}")
        n = 1
        if len(st.fields) > 2:
            n = int(round(self.number(st.fields[2], "MEAS point count")))
            if n < 1:
                self.fail(f"MEAS point count {st.fields[2]} must be at least 1")
        self.meas = _MeasBlock(feature, n, self.where())

    def do_ptmeas(self, st: lexer.Statement) -> None:
        if self.meas is None:
            self.fail("PTMEAS outside a MEAS block: a PTMEAS goes between MEAS/... and ENDMES")
        f = list(st.fields)
        if not f or f[0].upper() != "CART":
            self.fail(f"PTMEAS coordinates must be CART,x,y,z[,i,j,k] (POL is not read), got {st.rest[:60]!r}")
        f.pop(0)
        if len(f) not in (3, 6):
            self.fail(f"PTMEAS/CART takes x,y,z or x,y,z,i,j,k, got {len(f)} numbers")
        p = self.xyz_m(f[:3], "PTMEAS coordinate")
        if len(f) == 6:
            n = self.ijk(f[3:6], "PTMEAS normal")
        else:
            try:
                n = geometry.surface_normal(self.meas.feature, p)
            except AlgorithmError as e:
                self.fail(f"PTMEAS without i,j,k: {e}")
        self.add_touch(p, n)

    def add_touch(self, p: np.ndarray, n: np.ndarray) -> None:
        assert self.meas is not None and self.model is not None
        t = Touch(self.meas.feature.label, len(self.meas.touches), p, n, ProbeSettings(**self.settings), self.stylus,
                  self.where())
        self.meas.touches.append(t)
        self.meas.events.append(t)
        self.event(t)

    def do_endmes(self, st: lexer.Statement) -> None:
        assert self.model is not None
        m = self.meas
        if m is None:
            self.fail("ENDMES outside a MEAS block")
        if not m.touches:
            self.auto_touches(m)
        if len(m.touches) != m.requested:
            self.notice("warning", f"MEAS of F({m.feature.label}) asked for {m.requested} points and the block holds "
                                   f"{len(m.touches)}: all {len(m.touches)} are measured")
        measurement = Measurement(m.feature.label, m.requested, tuple(m.touches), m.where, self.alignment,
                                  tuple(m.events))
        self.model.measurements.append(measurement)
        self.model.items.append(("meas", measurement))
        self.meas = None

    def auto_touches(self, m: _MeasBlock) -> None:
        """The touches of a point or circle measured with no PTMEAS (:func:`geometry.nominal_touches`)."""
        if m.requested > MAX_AUTO_TOUCHES:
            self.fail(f"MEAS of F({m.feature.label}) asks for {m.requested} touches with no PTMEAS: at most "
                      f"{MAX_AUTO_TOUCHES} are generated")
        try:
            touches = geometry.nominal_touches(m.feature, m.requested)
        except AlgorithmError as e:
            self.fail(str(e))
        for p, n in touches:
            self.add_touch(p, n)

    def do_const(self, st: lexer.Statement) -> None:
        assert self.model is not None
        if len(st.fields) < 3:
            self.fail(f"CONST takes kind,F(label),method,F(...)..., got {st.rest!r}")
        kind = st.fields[0].upper()
        _, name = self.label(st.fields[1], ("F",), "CONST's feature")
        method = st.fields[2].upper()
        inputs = [self.feature(x, f"CONST/{kind},F({name}),{method}") for x in st.fields[3:] if _LABEL.fullmatch(x)]
        if f"{kind} {method}" not in geometry.CONSTRUCTIONS:
            self.skip(f"CONST/{kind},...,{method}: a construction this reader does not build "
                      f"({', '.join(geometry.CONSTRUCTIONS)} are); F({name}) is left undefined")
            return
        try:
            nominal = geometry.construct(name, kind, method, inputs, None, self.where())
        except AlgorithmError as e:
            self.fail(str(e))
        self.model.features[name.upper()] = nominal
        c = Construction(name, kind, method, tuple(f.label for f in inputs), self.where(), self.alignment)
        self.model.constructions.append(c)
        self.model.items.append(("const", c))

    def do_datdef(self, st: lexer.Statement) -> None:
        assert self.model is not None
        if len(st.fields) != 2:
            self.fail(f"DATDEF takes F(feature),DAT(x), got {st.rest!r}")
        f = self.feature(st.fields[0], "DATDEF's feature")
        _, letter = self.label(st.fields[1], ("DAT",), "DATDEF's datum")
        self.model.datums[letter.upper()] = f.label
        self.model.items.append(("datdef", (letter, f.label)))

    # --- alignments -------------------------------------------------------------------------

    def new_alignment(self, op: str, args: tuple, st: lexer.Statement) -> None:
        from algorithms.probing.dmis.evaluation import alignment_frame

        assert self.model is not None
        step = AlignmentStep(self.alignment, op, args, self.where())
        self.model.alignments.append(step)
        index = len(self.model.alignments) - 1
        try:
            self.frames[index] = alignment_frame(self.model.alignments, index, self.model.features, self.frames)
        except AlgorithmError as e:
            self.fail(str(e))
        self.alignment = index
        name = st.label if st.label_kind in ("D", "DA") and st.label else None
        if name:
            self.saved[name.upper()] = index
        self.model.items.append(("align", (index, name)))

    def do_datset(self, st: lexer.Statement) -> None:
        items: list[tuple[str, tuple[str, ...]]] = []
        for x in st.fields:
            if _LABEL.fullmatch(x):
                items.append((self.feature(x, "DATSET's datum").label, ()))
                continue
            role = x.upper()
            flip = role.startswith("-")
            if role.lstrip("-") not in _AXES or not items:
                self.fail(f"DATSET takes datums each followed by XDIR|YDIR|ZDIR and XORIG|YORIG|ZORIG, got {x!r}")
            items[-1] = (items[-1][0], (*items[-1][1], ("-" if flip else "") + role.lstrip("-")))
        if not items:
            self.fail("DATSET names no datum")
        self.new_alignment("datset", tuple(items), st)

    def do_trans(self, st: lexer.Statement) -> None:
        f = list(st.fields)
        if len(f) % 2 or not f:
            self.fail(f"TRANS takes pairs of XORIG|YORIG|ZORIG and a value or feature, got {st.rest!r}")
        args = []
        for axis, what in zip(f[::2], f[1::2], strict=True):
            a = axis.upper()
            if a not in ("XORIG", "YORIG", "ZORIG"):
                self.fail(f"TRANS axis must be XORIG, YORIG or ZORIG, got {axis!r}")
            args.append((_AXES[a], self.feature(what, "TRANS's feature").label if _LABEL.fullmatch(what)
                         else self.length_m(what, f"TRANS/{a} value")))
        self.new_alignment("trans", tuple(args), st)

    def do_rotate(self, st: lexer.Statement) -> None:
        if len(st.fields) != 2 or st.fields[0].upper() not in ("XAXIS", "YAXIS", "ZAXIS") or _LABEL.fullmatch(
                st.fields[1]):
            self.fail(f"ROTATE is read as ROTATE/XAXIS|YAXIS|ZAXIS,angle, got {st.rest!r}")
        self.new_alignment("rotate", (_AXES[st.fields[0].upper()], self.angle_rad(st.fields[1], "ROTATE angle")), st)

    def do_save(self, st: lexer.Statement) -> None:
        kind, name = self.label(st.fields[0] if st.fields else "", ("DA", "D", "SA", "S", "FA", "F", "T", "TA"),
                                "SAVE's item")
        if kind in ("DA", "D"):
            self.saved[name.upper()] = self.alignment
            assert self.model is not None
            self.model.items.append(("save", name))
        else:
            self.skip(f"SAVE/{kind}({name}): kept only for alignments (D/DA)")

    def do_recall(self, st: lexer.Statement) -> None:
        kind, name = self.label(st.fields[0] if st.fields else "", ("DA", "D", "SA", "S", "FA", "F", "T", "TA"),
                                "RECALL's item")
        if kind in ("SA", "S"):
            self.skip(f"RECALL/{kind}({name}): a sensor's stored calibration; the twin's styli are calibrated")
            return
        if kind not in ("DA", "D"):
            self.skip(f"RECALL/{kind}({name}): only alignments (D/DA) are recalled")
            return
        if name.upper() not in self.saved:
            self.fail(f"RECALL/{kind}({name}): no alignment {name} was saved or defined before")
        assert self.model is not None
        target = self.saved[name.upper()]
        self.model.alignments.append(AlignmentStep(target, "recall", (), self.where()))
        index = len(self.model.alignments) - 1
        self.frames[index] = self.frames[target]
        self.alignment = index
        self.model.items.append(("align", (index, name)))

    # --- tolerances and outputs -------------------------------------------------------------

    def do_tol(self, st: lexer.Statement) -> None:
        from algorithms.probing.dmis.evaluation import TOLERANCE_KINDS, tolerance_params

        assert self.model is not None
        if st.label_kind not in ("T", "TA") or not st.label:
            self.fail(f"TOL defines a tolerance: T(label)=TOL/..., got {st.text[:60]!r}")
        kind = st.fields[0].upper() if st.fields else ""
        if st.label_kind == "TA":
            self.skip(f"TA({st.label})=TOL/{kind}: a reported result, not a tolerance to evaluate")
            return
        if kind not in TOLERANCE_KINDS:
            self.skip(f"TOL/{kind}: a tolerance this reader does not evaluate ({', '.join(TOLERANCE_KINDS)} are)")
            return
        try:
            params = tolerance_params(kind, st.fields[1:], self)
        except AlgorithmError as e:
            self.fail(str(e))
        tol = Tolerance(st.label, kind, params, self.where())
        self.model.tolerances[st.label.upper()] = tol
        self.model.items.append(("tol", tol))

    def do_output(self, st: lexer.Statement) -> None:
        assert self.model is not None
        features, tols = [], []
        for x in st.fields:
            m = _LABEL.fullmatch(x)
            if not m:
                self.skip(f"OUTPUT item {x!r} is not a feature or tolerance label")
                continue
            kind, name = m.group(1).upper(), m.group(2)
            if kind in ("F", "FA"):
                self.feature(x, "OUTPUT's feature")
                features.append(self.feature(x, "OUTPUT's feature").label)
            elif kind in ("T", "TA"):
                if name.upper() not in self.model.tolerances:
                    self.fail(f"OUTPUT of T({name}), which no TOL defines (or one this reader does not evaluate)")
                tols.append(self.model.tolerances[name.upper()].label)
            else:
                self.skip(f"OUTPUT/{kind}({name}): only features and tolerances are reported")
        out = OutputRequest(tuple(features), tuple(tols), self.where(), self.alignment)
        self.model.outputs.append(out)
        self.model.items.append(("output", out))


def _finish(reader: Reader, source: str) -> DmisModel:
    model = reader.model
    if model is None:
        raise AlgorithmError(f"{source}: no DMISMN statement: a DMIS program starts with DMISMN/'name',version")
    if reader.meas is not None:
        raise AlgorithmError(f"{reader.meas.where}: the MEAS block is not closed by ENDMES before the end of the file")
    if not reader.ended:
        model.notices.append(Notice(Where(source, 0), "ENDFIL", "warning", "the file ends without ENDFIL"))
    model.sources = reader.sources
    model.statements_executed = reader.executed
    for word in SNSET_WORDS:
        if word not in reader.settings_set and model.touches:
            model.notices.append(Notice(Where(source, 0), "SNSET", "warning",
                                        f"SNSET/{word} is never set: the twin's default "
                                        f"{1e3 * getattr(ProbeSettings(), SNSET_WORDS[word]):g} mm is used"))
    return model


def parse_program(text: str, source: str = "program", encoding: str = "utf-8") -> DmisModel:
    """The model of DMIS program ``text`` (a ``CALL/EXTERN`` is looked up next to ``source``).

    Raises:
        AlgorithmError: one line, ``source:line: message``, for what is refused (module docstring).
    """
    if not isinstance(text, str):
        raise AlgorithmError(f"{source}: parse_program takes the DMIS text as a str, got {type(text).__name__}")
    reader = Reader(encoding)
    body = reader.load(Path(source), text)
    reader.run(body)
    return _finish(reader, source)


def read_program(path: str | os.PathLike[str]) -> DmisModel:
    """The model of the DMIS program in file ``path`` (UTF-8 with or without a byte-order mark, or Latin-1)."""
    p = Path(path)
    text, encoding = read_file(p)
    return parse_program(text, os.fspath(path), encoding)
