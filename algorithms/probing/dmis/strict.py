"""DMIS 5.3 text for measurement programs (:class:`~algorithms.probing.program.Program`): the
writer, and the strict reader of exactly what the writer writes (real programs from measurement
software are read by :mod:`algorithms.probing.dmis.reader`).

The subset, one statement per line (DMIS ``$$`` comment lines and blank lines are ignored;
statements may be upper or lower case, with spaces around commas)::

    DMISMN/'name',05.3                      the program's name; version 05.0 to 05.3 (or 5.0 to 5.3)
    FILNAM/'name',05.3                      optional: the name of the output file (ignored)
    UNITS/MM,ANGDEC                         or UNITS/INCH,ANGDEC (25.4 mm); MM until one is given
                                            (ANGDMS and ANGRAD too; ANGDEG, which earlier versions of
                                            this writer wrote and no DMIS reader knows, is still read)
    MODE/PROG,MAN                           also MODE/AUTO,PROG,MAN and MODE/MAN
    SNSET/APPRCH,d                          the four probing distances of ProbeSettings, each once,
    SNSET/RETRCT,d                          all before the first motion statement (SNSLCT, GOTO, MEAS)
    SNSET/SEARCH,d
    SNSET/CLRSRF,d
    SNSLCT/SA(stylus)                       SelectStylus
    GOTO/CART,x,y,z                         Goto (GOTO/x,y,z too)
    F(label)=FEAT/POINT,CART,x,y,z,i,j,k    MeasurePoint: the nominal point and its outward normal,
    MEAS/POINT,F(label),1                   measured by one touch whose PTMEAS repeats the nominal
    PTMEAS/CART,x,y,z,i,j,k                 point and normal (the normal gives the approach
    ENDMES                                  direction: the probe moves along -normal)
    ENDFIL

Nothing else is read: other DMIS statements (``CONST``, ``DATDEF``, ``TOL``, ``OUTPUT``, ...)
are refused, as are features other than points, and ``GOTO`` or ``SNSLCT`` inside a ``MEAS``
block. Every refusal is an :class:`~algorithms.errors.AlgorithmError` whose one-line message
starts with ``source:line: `` and says what was wrong and what is allowed.

Frame and units: all coordinates are in the part coordinate system. ``GOTO`` gives the sensor
position, i.e. the probe's ball centre; ``FEAT``/``PTMEAS`` give the nominal surface point. The
file carries millimetres (or inches, when ``UNITS/INCH`` says so), the
:class:`~algorithms.probing.program.Program` metres. The writer writes millimetres: positions
and ``SNSET`` distances with 6 decimals (1 nm, the grid a Program holds its positions on) and
normals with 9 decimals, so that ``parse_dmis(write_dmis(p)) == p``. ``SNSET`` distances read
are snapped to the same 1 nm grid.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import NoReturn

import numpy as np

from algorithms.arraytypes import FloatArray
from algorithms.errors import AlgorithmError
from algorithms.probing.dmis.lexer import read_bytes
from algorithms.probing.program import (
    LABEL_PATTERN,
    NORMAL_DECIMALS,
    POSITION_DECIMALS_MM,
    Goto,
    MeasurePoint,
    ProbeSettings,
    Program,
    SelectStylus,
    Statement,
)

#: The DMIS version the writer puts in ``DMISMN``.
DMIS_VERSION = "05.3"

#: The major words this subset runs, in the order a file uses them.
ACCEPTED_WORDS = ("DMISMN", "FILNAM", "UNITS", "MODE", "SNSET", "SNSLCT", "GOTO", "FEAT", "MEAS", "PTMEAS", "ENDMES",
                  "ENDFIL")

#: The ``SNSET`` words and the :class:`ProbeSettings` fields they set.
SNSET_WORDS = {"APPRCH": "approach_m", "RETRCT": "retract_m", "SEARCH": "search_m", "CLRSRF": "clearance_m"}

#: Millimetres per file unit, by ``UNITS`` statement.
UNITS_MM = {(length, angle): mm for length, mm in (("MM", 1.0), ("INCH", 25.4))
            for angle in ("ANGDEC", "ANGDMS", "ANGRAD", "ANGDEG")}

#: The accepted ``MODE`` statements.
MODES = {("PROG", "MAN"), ("AUTO", "PROG", "MAN"), ("MAN",)}

#: A PTMEAS may differ from its FEAT's nominal point by this much [m] ...
PTMEAS_POINT_TOL_M = 1e-6
#: ... and its unit normal from the FEAT's by this much (Euclidean).
PTMEAS_NORMAL_TOL = 1e-6

# Statements that move the machine: all four SNSET distances must be set before the first one.
_MOTION_WORDS = ("SNSLCT", "GOTO", "MEAS")

# DMIS 5 major words this subset does not run (for a clearer refusal than "unknown").
_OTHER_DMIS_WORDS = frozenset("""
    ACLRAT ALGDEF ASSIGN BADTST BOUND CALIB CALL CASE CLMPID CLMPSN CLOSE CMPNTGRP CNFRMRUL CONST
    CRGDEF CRMODE CROSCL CRSLCT CZONE CZSLCT DATDEF DATSET DATTRGDEF DECL DECPL DELETE DEVICE DFTCAS
    DISPLY DMEHW DMEID DMESWI DMESWV DMISMD DO ELSE ENDAS ENDCAS ENDDO ENDGO ENDIF ENDMAC ENDSEL
    ENDSIMREQT ENDX EQUATE ERROR EVAL EXTENS EXTFIL FEDRAT FILDEF FINPOS FIXTID FIXTSN FROM
    GEOALG GEOM GOHOME GOTARG GROUP IF INCLUD ITERAT JUMPTO KEYCHAR LITDEF LOCATE LOTID MACRO MFGDEV
    OBTAIN OPEN OPERID OUTPUT PAMEAS PARTID PARTRV PARTSN PLANID POP PRCOMP PREVOP PROCID PROMPT
    PSTHRU PTBUFF PUSH QISDEF RAPID READ RECALL REFMNT REPORT RESUME RMEAS ROTAB ROTATE ROTDEF ROTSET
    SAVE SCNMOD SCNSET SELECT SENSOR SIMREQT SNSDEF SNSGRP SNSMNT TECOMP TEXT THLDEF TOL TOOLDF TRANS
    VALUE VFORM WINDEF WKPLAN WRIST WRITE XTERN XTRACT
""".split())

_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
_INTEGER = re.compile(r"[+-]?\d+")
# The head of a statement (before "/"): an optional label assignment "F(label)=", then the major word.
_HEAD = re.compile(r"(?:([A-Za-z]+)\s*\(\s*([^()]*?)\s*\)\s*=\s*)?([A-Za-z][A-Za-z0-9]*)")
_LABEL_REF = re.compile(r"([A-Za-z]+)\s*\(\s*([^()]*?)\s*\)")
_DMISMN = re.compile(r"'([^']*)'\s*,\s*([^,]*?)")
_VERSION = re.compile(r"0?5\.[0-3]")


def _mm(x_m: float) -> str:
    """A length [m] as millimetres with 6 decimals."""
    return f"{round(x_m * 1e3, POSITION_DECIMALS_MM):.{POSITION_DECIMALS_MM}f}"


def _unit(c: float) -> str:
    """A normal component with 9 decimals."""
    return f"{c:.{NORMAL_DECIMALS}f}"


def _snap_m(x_m: float) -> float:
    """A length [m] on the 1 nm grid a file carries (as :class:`Program` snaps positions)."""
    return round(x_m * 1e3, POSITION_DECIMALS_MM) / 1e3


def _writable_label(label: str, what: str) -> str:
    # check_label's pattern ends in "$", which also lets a label with a trailing newline through.
    if not isinstance(label, str) or not LABEL_PATTERN.fullmatch(label):
        raise AlgorithmError(f"{what} label {label!r} cannot be written to DMIS: a label is a letter, then up to "
                             "19 letters, digits or underscores")
    return label


def write_dmis(program: Program) -> str:
    """The DMIS text of ``program`` (millimetres; see the module docstring).

    Positions and normals are on the grid the file carries, so they read back exactly;
    ProbeSettings are not snapped, and a setting off the 1 nm grid is written rounded to it. A
    point with its own settings is preceded by the ``SNSET`` statements that change them (such a
    program is read back by :func:`algorithms.probing.dmis.reader.parse_program`; this module's
    strict reader sets each distance once).
    """
    if not isinstance(program, Program):
        raise AlgorithmError(f"write_dmis takes a Program, got {type(program).__name__}")
    lines = [f"DMISMN/'{program.name}',{DMIS_VERSION}", f"FILNAM/'{program.name}',{DMIS_VERSION}", "UNITS/MM,ANGDEC",
             "MODE/PROG,MAN"]
    for word, name in SNSET_WORDS.items():
        value = getattr(program.settings, name)
        if _snap_m(value) <= 0.0:
            raise AlgorithmError(f"probe setting {name} = {value!r} m rounds to 0 on the 1 nm grid a DMIS file "
                                 "carries: settings must be at least 0.5 nm")
        lines.append(f"SNSET/{word},{_mm(value)}")
    in_force = program.settings
    for s in program.statements:
        if isinstance(s, MeasurePoint) and (s.settings or program.settings) != in_force:
            wanted = s.settings or program.settings
            lines += [f"SNSET/{word},{_mm(getattr(wanted, name))}" for word, name in SNSET_WORDS.items()
                      if getattr(wanted, name) != getattr(in_force, name)]
            in_force = wanted
        if isinstance(s, SelectStylus):
            lines.append(f"SNSLCT/SA({_writable_label(s.name, 'stylus')})")
        elif isinstance(s, Goto):
            lines.append("GOTO/CART," + ",".join(_mm(x) for x in s.xyz_m))
        elif isinstance(s, MeasurePoint):
            label = _writable_label(s.label, "feature")
            nominal = ",".join([*(_mm(x) for x in s.point_m), *(_unit(c) for c in s.normal)])
            lines += [f"F({label})=FEAT/POINT,CART,{nominal}", f"MEAS/POINT,F({label}),1", f"PTMEAS/CART,{nominal}",
                      "ENDMES"]
        else:
            raise AlgorithmError(f"program {program.name!r} holds a {type(s).__name__}: DMIS is written for Goto, "
                                 "SelectStylus and MeasurePoint statements")
    lines.append("ENDFIL")
    return "\n".join(lines) + "\n"


def write_dmis_file(program: Program, path: str | os.PathLike[str]) -> None:
    """Write ``program`` as DMIS (UTF-8, ``\\n`` line ends) to ``path``."""
    text = write_dmis(program)
    try:
        data = text.encode("utf-8")
    except UnicodeEncodeError as e:
        raise AlgorithmError(f"program {program.name!r} cannot be written as UTF-8: {e.reason}") from e
    try:
        Path(path).write_bytes(data)
    except OSError as e:
        raise AlgorithmError(f"cannot write DMIS file {os.fspath(path)!r}: {e.strerror or e}") from e


def read_dmis(path: str | os.PathLike[str]) -> Program:
    """The program in the DMIS file ``path`` (UTF-8, an optional byte-order mark)."""
    data = read_bytes(path)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise AlgorithmError(f"DMIS file {os.fspath(path)!r} is not UTF-8 text (byte {e.start}: {e.reason}): "
                             "DMIS files are read as UTF-8") from e
    return parse_dmis(text, source=os.fspath(path))


def parse_dmis(text: str, source: str = "program") -> Program:
    """The program in DMIS ``text``; refusals name ``source`` and the line (see the module docstring)."""
    if not isinstance(text, str):
        raise AlgorithmError(f"{source}: parse_dmis takes the DMIS text as a str, got {type(text).__name__}")
    return _Parser(source).parse(text)


@dataclass
class _Statement:
    """One statement line, split: its major word, its label assignment and its fields."""

    word: str
    label_kind: str | None
    label: str | None
    rest: str
    fields: list[str]


@dataclass
class _Feature:
    """A FEAT/POINT read: its MeasurePoint, its line and the line of its MEAS."""

    point: MeasurePoint
    line: int
    measured_line: int | None = None


@dataclass
class _Parser:
    source: str
    line: int = 0
    name: str | None = None
    ended: bool = False
    mm_per_unit: float = 1.0
    settings: dict[str, tuple[float, int]] = field(default_factory=dict)  # SNSET word -> (metres, line)
    features: dict[str, _Feature] = field(default_factory=dict)  # upper-case label -> feature
    meas: _Feature | None = None  # the feature of the open MEAS block
    meas_line: int = 0
    ptmeas_line: int | None = None
    statements: list[Statement] = field(default_factory=list)

    def fail(self, message: str, line: int | None = None) -> NoReturn:
        raise AlgorithmError(f"{self.source}:{self.line if line is None else line}: {message}")

    def parse(self, text: str) -> Program:
        lines = text.split("\n")
        if len(lines) > 1 and lines[-1] == "":
            lines.pop()
        for number, raw in enumerate(lines, start=1):
            self.line = number
            line = raw.strip()
            if not line or line.startswith("$$"):
                continue
            self.statement(self.split(line))
        self.line = len(lines)
        if self.name is None:
            self.fail("no DMISMN statement: a DMIS program starts with DMISMN/'name',05.0 and ends with ENDFIL")
        if not self.ended:
            still_open = f" (and the MEAS block of line {self.meas_line} is not closed by ENDMES)" if self.meas else ""
            self.fail(f"missing ENDFIL at the end of the file{still_open}: a DMIS program ends with ENDFIL")
        settings = ProbeSettings(**{SNSET_WORDS[w]: v for w, (v, _) in self.settings.items()})
        try:
            return Program(self.name, settings, tuple(self.statements))
        except AlgorithmError as e:  # pragma: no cover - the checks above refuse what Program refuses
            self.fail(str(e))

    # --- splitting ---------------------------------------------------------------------------

    def split(self, line: str) -> _Statement:
        """``line`` as a statement of an accepted major word, or a refusal."""
        head, slash, rest = line.partition("/")
        head = head.strip()
        m = _HEAD.match(head)
        if m is None:
            self.fail(f"{_show(line)} is not a statement: a statement is WORD/fields, with WORD one of "
                      f"{', '.join(ACCEPTED_WORDS)}; a line starting with $$ is a comment")
        word = m.group(3).upper()
        if word not in ACCEPTED_WORDS:
            kind = ("a DMIS statement this subset does not run" if word in _OTHER_DMIS_WORDS
                    else "not a statement this subset knows")
            self.fail(f"{word} is {kind}: the statements accepted are {', '.join(ACCEPTED_WORDS)}")
        alone = word in ("ENDMES", "ENDFIL")
        if alone:
            if slash or m.end() != len(head) or m.group(1):
                self.fail(f"{word} stands alone on its line, got {_show(line)}")
            return _Statement(word, None, None, "", [])
        if not slash:
            self.fail(f"missing '/' in {_show(line)}: a statement is {word}/fields")
        if m.end() != len(head):
            self.fail(f"{_show(head)} before '/' is not a major word: a statement is {word}/fields")
        label_kind = m.group(1).upper() if m.group(1) else None
        if word == "FEAT" and label_kind != "F":
            self.fail(f"FEAT must define a feature label, as F(label)=FEAT/POINT,CART,x,y,z,i,j,k; got "
                      f"{_show(line)}")
        if word != "FEAT" and label_kind is not None:
            self.fail(f"{word} takes no label assignment {m.group(1)}(...)=: only F(label)=FEAT/... does")
        return _Statement(word, label_kind, m.group(2), rest, [f.strip() for f in rest.split(",")])

    # --- fields --------------------------------------------------------------------------------

    def count(self, st: _Statement, n: int, form: str) -> None:
        if len(st.fields) != n:
            self.fail(f"{st.word} takes {n} field{'s' if n != 1 else ''} ({form}), got {len(st.fields)}: "
                      f"{_show(st.rest)}")

    def number(self, text: str, what: str, form: str) -> float:
        if not _NUMBER.fullmatch(text):
            self.fail(f"{what} must be a number ({form}), got {_show(text)}")
        value = float(text)
        if not np.isfinite(value):
            self.fail(f"{what} {text} is too large ({form})")
        return value

    def length_m(self, text: str, what: str, form: str) -> float:
        """A length field in the file's units, in metres."""
        value = self.number(text, what, form) * self.mm_per_unit / 1e3
        if not np.isfinite(value):
            self.fail(f"{what} {text} is too large ({form})")
        return value

    def label(self, label: str | None, what: str) -> str:
        if label is None or not LABEL_PATTERN.fullmatch(label):
            self.fail(f"{what} label {_show(label or '')} is not a DMIS label: a letter, then up to 19 letters, "
                      "digits or underscores")
        return label

    def point_and_normal(self, st: _Statement, first: int, form: str) -> tuple[FloatArray, FloatArray]:
        """The point [m] and the unit normal in ``st.fields[first:first + 6]``."""
        xyz = np.array([self.length_m(f, f"{st.word} coordinate {a}", form)
                        for a, f in zip("xyz", st.fields[first:first + 3], strict=True)])
        ijk = np.array([self.number(f, f"{st.word} normal component {a}", form)
                        for a, f in zip("ijk", st.fields[first + 3:first + 6], strict=True)])
        norm = float(np.linalg.norm(ijk))
        if norm == 0.0:
            self.fail(f"{st.word} has a zero normal: i,j,k is the outward surface normal, a nonzero vector")
        if not np.isfinite(norm):
            self.fail(f"{st.word} normal {_show(','.join(st.fields[first + 3:first + 6]))} is too large to "
                      "normalize: i,j,k is the outward surface normal, best a unit vector")
        return xyz, ijk

    # --- statements ----------------------------------------------------------------------------

    def statement(self, st: _Statement) -> None:
        if self.ended:
            self.fail(f"{st.word} after ENDFIL: nothing but comments and blank lines may follow ENDFIL")
        if self.name is None and st.word != "DMISMN":
            self.fail(f"{st.word} before DMISMN: a DMIS program starts with DMISMN/'name',05.0 (only comments "
                      "and blank lines may come before it)")
        if self.meas is not None and st.word not in ("PTMEAS", "ENDMES"):
            self.fail(f"{st.word} inside the MEAS block of line {self.meas_line}: a MEAS block holds one PTMEAS, "
                      "then ENDMES")
        if st.word in _MOTION_WORDS:
            missing = [w for w in SNSET_WORDS if w not in self.settings]
            if missing:
                self.fail(f"{st.word} before {', '.join('SNSET/' + w for w in missing)}: all four of "
                          f"{', '.join(SNSET_WORDS)} must be set by SNSET before the first motion statement")
        getattr(self, "do_" + st.word.lower())(st)

    def do_dmismn(self, st: _Statement) -> None:
        if self.name is not None:
            self.fail("a second DMISMN: a file holds one program")
        m = _DMISMN.fullmatch(st.rest.strip())
        if not m:
            self.fail("DMISMN takes 'name',version (a name in single quotes, with no quote in it, then 05.0 to "
                      f"05.3), got {_show(st.rest)}")
        name, version = m.groups()
        if not name:
            self.fail("DMISMN has an empty name: give the program a name, as DMISMN/'name',05.0")
        if not _VERSION.fullmatch(version):
            self.fail(f"DMIS version {_show(version)} is not read: this parser reads versions 05.0 to 05.3 "
                      "(or 5.0 to 5.3)")
        self.name = name

    def do_units(self, st: _Statement) -> None:
        units = tuple(f.upper() for f in st.fields)
        if units not in UNITS_MM:
            self.fail(f"UNITS {_show(st.rest)} is not read: the units accepted are UNITS/MM or UNITS/INCH, with "
                      "ANGDEC, ANGDMS or ANGRAD")
        self.mm_per_unit = UNITS_MM[units]  # type: ignore[index]

    def do_mode(self, st: _Statement) -> None:
        if tuple(f.upper() for f in st.fields) not in MODES:
            self.fail(f"MODE {_show(st.rest)} is not read: the modes accepted are MODE/PROG,MAN, "
                      "MODE/AUTO,PROG,MAN and MODE/MAN")

    def do_snset(self, st: _Statement) -> None:
        form = "SNSET/word,distance"
        self.count(st, 2, form)
        word = st.fields[0].upper()
        if word not in SNSET_WORDS:
            self.fail(f"SNSET word {_show(st.fields[0])} is not read: the SNSET words accepted are "
                      f"{', '.join(SNSET_WORDS)}")
        if word in self.settings:
            self.fail(f"a second SNSET/{word} (the first on line {self.settings[word][1]}): a program has one "
                      "set of probing distances, so each SNSET word is set once")
        value = self.length_m(st.fields[1], f"SNSET/{word} distance", form)
        if value <= 0.0:
            self.fail(f"SNSET/{word} distance {st.fields[1]} is not positive: probing distances are > 0")
        snapped = _snap_m(value)
        if snapped <= 0.0:
            self.fail(f"SNSET/{word} distance {st.fields[1]} is below the 1 nm a program carries: probing "
                      "distances are at least 0.5 nm")
        self.settings[word] = (snapped, self.line)

    def do_snslct(self, st: _Statement) -> None:
        self.count(st, 1, "SNSLCT/SA(stylus)")
        m = _LABEL_REF.fullmatch(st.fields[0])
        if not m or m.group(1).upper() != "SA":
            self.fail(f"SNSLCT takes a stylus as SA(label), got {_show(st.fields[0])}")
        self.statements.append(SelectStylus(self.label(m.group(2), "stylus")))

    def do_filnam(self, st: _Statement) -> None:
        if not re.fullmatch(r"'[^']*'\s*(,.*)?", st.rest.strip()):
            self.fail(f"FILNAM takes 'name',version, got {_show(st.rest)}")

    def do_goto(self, st: _Statement) -> None:
        form = "GOTO/CART,x,y,z or GOTO/x,y,z"
        fields = st.fields[1:] if st.fields and st.fields[0].upper() == "CART" else st.fields
        if len(fields) != 3:
            self.fail(f"GOTO takes 3 coordinates ({form}), got {_show(st.rest)}")
        xyz = [self.length_m(f, f"GOTO coordinate {a}", form) for a, f in zip("xyz", fields, strict=True)]
        self.statements.append(Goto(tuple(xyz)))  # type: ignore[arg-type]

    def do_feat(self, st: _Statement) -> None:
        form = "F(label)=FEAT/POINT,CART,x,y,z,i,j,k"
        label = self.label(st.label, "feature")
        if st.fields[0].upper() != "POINT":
            self.fail(f"FEAT type {_show(st.fields[0])} is not read: this subset defines point features only "
                      f"({form})")
        self.count(st, 8, form)
        if st.fields[1].upper() != "CART":
            self.fail(f"FEAT/POINT coordinates {_show(st.fields[1])} are not read: points are given in CART "
                      f"coordinates ({form})")
        key = label.upper()
        if key in self.features:
            self.fail(f"feature F({label}) is defined twice (first on line {self.features[key].line}): each "
                      "feature label is defined once")
        xyz, ijk = self.point_and_normal(st, 2, form)
        self.features[key] = _Feature(_measure_point(label, xyz, ijk), self.line)

    def do_meas(self, st: _Statement) -> None:
        form = "MEAS/POINT,F(label),1"
        self.count(st, 3, form)
        if st.fields[0].upper() != "POINT":
            self.fail(f"MEAS type {_show(st.fields[0])} is not read: this subset measures point features only "
                      f"({form})")
        m = _LABEL_REF.fullmatch(st.fields[1])
        if not m or m.group(1).upper() != "F":
            self.fail(f"MEAS takes the feature as F(label), got {_show(st.fields[1])} ({form})")
        label = self.label(m.group(2), "feature")
        if not _INTEGER.fullmatch(st.fields[2]):
            self.fail(f"MEAS point count must be a whole number, got {_show(st.fields[2])} ({form})")
        if int(st.fields[2]) != 1:
            self.fail(f"MEAS count {int(st.fields[2])}: this subset measures a point with exactly 1 touch ({form})")
        feature = self.features.get(label.upper())
        if feature is None:
            self.fail(f"MEAS of F({label}), which no FEAT defines: define it first with "
                      "F(label)=FEAT/POINT,CART,x,y,z,i,j,k")
        if feature.measured_line is not None:
            self.fail(f"F({label}) is measured twice (first by the MEAS of line {feature.measured_line}): each "
                      "feature is measured once")
        feature.measured_line = self.line
        self.meas, self.meas_line, self.ptmeas_line = feature, self.line, None

    def do_ptmeas(self, st: _Statement) -> None:
        form = "PTMEAS/CART,x,y,z,i,j,k"
        if self.meas is None:
            self.fail("PTMEAS outside a MEAS block: a PTMEAS goes between MEAS/POINT,F(label),1 and ENDMES")
        if self.ptmeas_line is not None:
            self.fail(f"a second PTMEAS in the MEAS block of line {self.meas_line} (the first on line "
                      f"{self.ptmeas_line}): a MEAS/POINT block holds exactly one PTMEAS")
        self.count(st, 7, form)
        if st.fields[0].upper() != "CART":
            self.fail(f"PTMEAS coordinates {_show(st.fields[0])} are not read: points are given in CART coordinates "
                      f"({form})")
        xyz, ijk = self.point_and_normal(st, 1, form)
        feature = self.meas
        off = float(np.linalg.norm(np.array([_snap_m(float(x)) for x in xyz]) - np.asarray(feature.point.point_m)))
        if off > PTMEAS_POINT_TOL_M:
            self.fail(f"PTMEAS is {off * 1e3:.6f} mm from the nominal point of F({feature.point.label}) (line "
                      f"{feature.line}): a PTMEAS repeats its FEAT's point to within 0.001 mm")
        turn = float(np.linalg.norm(ijk / np.linalg.norm(ijk) - np.asarray(feature.point.normal)))
        if turn > PTMEAS_NORMAL_TOL:
            self.fail(f"PTMEAS normal differs by {turn:.3g} from the normal of F({feature.point.label}) (line "
                      f"{feature.line}): a PTMEAS repeats its FEAT's normal to within 1e-6")
        self.ptmeas_line = self.line

    def do_endmes(self, st: _Statement) -> None:
        feature = self.meas
        if feature is None:
            self.fail("ENDMES outside a MEAS block: ENDMES closes a MEAS/POINT,F(label),1 block")
        if self.ptmeas_line is None:
            self.fail(f"the MEAS block of line {self.meas_line} ends without a PTMEAS: a MEAS/POINT block holds "
                      "exactly one PTMEAS")
        self.statements.append(feature.point)
        self.meas = None

    def do_endfil(self, st: _Statement) -> None:
        for feature in self.features.values():
            if feature.measured_line is None:
                self.fail(f"F({feature.point.label}) is defined but not measured before ENDFIL (line {self.line}): "
                          "every FEAT/POINT is measured by a MEAS/POINT block", line=feature.line)
        missing = [w for w in SNSET_WORDS if w not in self.settings]
        if missing:
            self.fail(f"ENDFIL before {', '.join('SNSET/' + w for w in missing)}: a program sets all four of "
                      f"{', '.join(SNSET_WORDS)}")
        self.ended = True


def _measure_point(label: str, point_m: FloatArray, normal: FloatArray) -> MeasurePoint:
    """The MeasurePoint of a file's point and normal, keeping a normal that is already unit to the
    file's 9 decimals as written.

    (MeasurePoint divides by the norm and rounds again, which can move the last decimal of a
    normal that was already rounded; a file written from a program must read back equal.)
    """
    mp = MeasurePoint(label, tuple(float(x) for x in point_m), tuple(float(c) for c in normal))  # type: ignore[arg-type]
    written = tuple(float(c) for c in normal)
    on_grid = all(round(c, NORMAL_DECIMALS) == c for c in written)
    if on_grid and max(abs(a - b) for a, b in zip(written, mp.normal, strict=True)) <= 1.5 * 10.0**-NORMAL_DECIMALS:
        object.__setattr__(mp, "normal", written)
    return mp


def _show(text: str, limit: int = 60) -> str:
    """``text`` quoted for a one-line message, cut to ``limit`` characters."""
    return repr(text if len(text) <= limit else text[:limit] + "...")
