"""A DMIS program's flow, as the reader follows it (:class:`Interpreter`: statements in order,
IF/ELSE/ENDIF, JUMPTO, DO/ENDDO, DECL/ASSIGN, CALL of macros and files): the statements of a file or macro with
their jump targets and the matching ends of their IF and DO blocks, macro arguments put in
place, the text of a file; and the words the reader refuses or skips, with why."""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import NoReturn

from algorithms.errors import AlgorithmError
from algorithms.probing.dmis import expressions, lexer
from algorithms.probing.dmis.model import Where

#: The most statements one program may execute (loops and calls counted), and the deepest call.
MAX_STATEMENTS = 200_000
MAX_CALL_DEPTH = 32

_LABEL = re.compile(r"([A-Za-z]+)\s*\(\s*([^()]*?)\s*\)")
_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")

#: Words that move the machine or change what is measured, which this reader does not run.
REFUSED_WORDS = {
    "GOHOME": "moves the machine to its home position",
    "RMEAS": "measures relative to another feature",
    "PAMEAS": "measures along a scanning path",
    "ROTAB": "turns a rotary table the twin's CMM does not have",
    "ROTSET": "sets a rotary table the twin's CMM does not have",
    "CALIB": "calibrates the probe with touches on an artefact",
    "GOTARG": "moves the machine to a target in a separate motion mode",
    "WRIST": "turns a motorised wrist",
    "LOCATE": "moves the part's coordinate system from a fit the reader does not do",
    "SCNSET": "sets up scanning, which the twin's touch probe does not do",
    "SCNMOD": "turns scanning on, which the twin's touch probe does not do",
}


#: Words that neither move the machine nor change what is measured: skipped, each with why.
SKIPPED_WORDS = {w: "does not move the machine; not evaluated by the twin" for w in """
    FILNAM DMESWV DMESWI DMEHW DMEID DMISMD DECPL VFORM DISPLY PRCOMP CRMODE FEDRAT ACLRAT TEXT PROMPT
    PAUSE FLY WKPLAN PARTID PARTRV PARTSN PLANID OPERID LOTID PROCID MFGDEV QISDEF FIXTID FIXTSN DEVICE OPEN
    CLOSE READ WRITE GEOM EQUATE SNSDEF SNSMNT SNSGRP TECOMP THLDEF REPORT RAPID GEOALG CZONE CZSLCT LITDEF
    EXTFIL KEYCHAR ERROR INCLUD TOOLDF CLMPID CLMPSN CRGDEF CRSLCT DFTCAS EVAL EXTENS FINPOS GROUP ITERAT
    OBTAIN POP PUSH PREVOP PSTHRU PTBUFF REFMNT SELECT CASE ENDCAS ENDSEL DATTRGDEF CNFRMRUL CMPNTGRP ALGDEF
    BOUND WINDEF XTERN XTRACT VALUE ENDX ENDGO ENDAS BADTST FROM ROTDEF SIMREQT ENDSIMREQT
""".split()}
SKIPPED_WORDS.update({
    "PAUSE": "pauses for the operator; the twin does not stop",
    "FLY": "flies through moves (rounded corners); the twin's moves stop at each point",
    "DECPL": "sets the decimals of the output; the twin writes its own",
    "DISPLY": "sets where output goes; the twin writes its report files",
    "VFORM": "sets the output's columns; the twin writes nominal, actual, limits and deviation",
    "EQUATE": "equates two alignments; the twin keeps its own",
    "SNSDEF": "defines a sensor; the twin's styli come from its scenario",
    "FEDRAT": "sets speeds; the twin's CMM moves at its scenario's speeds",
})


@dataclass
class Body:
    """A list of statements executed together (a file or a macro), with its jump targets and the
    matching ends of its blocks."""

    statements: list[lexer.Statement]
    targets: dict[str, int] = field(default_factory=dict)
    match: dict[int, int] = field(default_factory=dict)  # IF -> ELSE or ENDIF, ELSE -> ENDIF, DO -> ENDDO


@dataclass
class Macro:
    params: list[str]
    body: Body
    where: Where


def split_macros(statements: list[lexer.Statement], source: str) -> tuple[list[lexer.Statement], dict[str, Macro]]:
    """The statements outside ``M(name)=MACRO/...`` ... ``ENDMAC`` blocks, and the macros by upper-case name.

    Raises:
        AlgorithmError: a MACRO without ENDMAC or a label, an ENDMAC without MACRO.
    """
    kept: list[lexer.Statement] = []
    macros: dict[str, Macro] = {}
    k = 0
    while k < len(statements):
        st = statements[k]
        if st.word == "MACRO":
            end = next((j for j in range(k + 1, len(statements)) if statements[j].word == "ENDMAC"), None)
            if end is None:
                raise AlgorithmError(f"{st.where()}: MACRO {st.label!r} is not closed by ENDMAC")
            if st.label_kind != "M" or not st.label:
                raise AlgorithmError(f"{st.where()}: a macro is defined as M(name)=MACRO/'p1',..., got {st.text!r}")
            params = [f.strip().strip("'").upper() for f in st.fields if f.strip()]
            body = structure(statements[k + 1:end], source)
            macros[st.label.upper()] = Macro(params, body, Where(st.source, st.line))
            k = end + 1
            continue
        if st.word == "ENDMAC":
            raise AlgorithmError(f"{st.where()}: ENDMAC without MACRO")
        kept.append(st)
        k += 1
    return kept, macros


def structure(statements: list[lexer.Statement], source: str) -> Body:
    """The body of ``statements``: jump targets and matching IF/ELSE/ENDIF and DO/ENDDO (macros are
    cut out by the caller)."""
    body = Body(statements)
    stack: list[tuple[str, int]] = []
    for k, st in enumerate(statements):
        if st.word == "(":
            body.targets[(st.label or "").upper()] = k
        elif st.word in ("IF", "DO"):
            stack.append((st.word, k))
        elif st.word == "ELSE":
            if not stack or stack[-1][0] != "IF":
                raise AlgorithmError(f"{st.where()}: ELSE without IF")
            body.match[stack[-1][1]] = k
            stack[-1] = ("ELSE", k)
        elif st.word in ("ENDIF", "ENDDO"):
            opener = "DO" if st.word == "ENDDO" else "IF"
            if not stack or stack[-1][0] not in ((opener,) if opener == "DO" else ("IF", "ELSE")):
                raise AlgorithmError(f"{st.where()}: {st.word} without {opener}")
            _, k0 = stack.pop()
            body.match[k0] = k
    if stack:
        word, k0 = stack[-1]
        st = statements[k0]
        raise AlgorithmError(f"{st.where()}: the {'IF' if word == 'ELSE' else word} block is not closed by "
                             f"{'ENDDO' if word == 'DO' else 'ENDIF'} before the end of {source}")
    return body


def substitute(body: Body, params: dict[str, str]) -> Body:
    """``body`` with each macro parameter name replaced by its argument, statement by statement."""
    if not params:
        return body
    pattern = re.compile(r"(?<![A-Za-z0-9_'])(" + "|".join(re.escape(p) for p in params) + r")(?![A-Za-z0-9_'])",
                         re.IGNORECASE)
    out = []
    for st in body.statements:
        text = st.text if st.word == "(" else pattern.sub(lambda m: params[m.group(1).upper()].strip("'"), st.text)
        new = lexer.statement(text, st.line, st.source)
        out.append(new if new is not None else st)
    return Body(out, body.targets, body.match)


def read_file(path: Path) -> tuple[str, str]:
    """The text of a DMIS file and its encoding (:func:`~algorithms.probing.dmis.lexer.decode`)."""
    return lexer.decode(lexer.read_bytes(path), os.fspath(path))


class Interpreter:
    """Executes a program's statements in order, following its flow; :class:`~algorithms.probing.
    dmis.reader.Reader` adds what each DMIS statement does (``statement``), how a file is loaded
    (``load``) and where skipped statements are listed (``skip``)."""

    def __init__(self) -> None:
        self.st: lexer.Statement | None = None
        self.executed = 0
        self.depth = 0
        self.ended = False
        self.variables: dict[str, expressions.Value] = {}
        self.macros: dict[str, Macro] = {}
        self.rad_per_unit = math.pi / 180.0

    def statement(self, st: lexer.Statement) -> None:
        raise NotImplementedError

    def load(self, path: Path, text: str | None = None) -> Body:
        raise NotImplementedError

    def skip(self, why: str) -> None:
        raise NotImplementedError

    def where(self) -> Where:
        assert self.st is not None
        return Where(self.st.source, self.st.line)

    def fail(self, message: str) -> NoReturn:
        raise AlgorithmError(f"{self.where()}: {message}")

    def label(self, text: str, kinds: tuple[str, ...], what: str) -> tuple[str, str]:
        m = _LABEL.fullmatch(text.strip())
        if not m or m.group(1).upper() not in kinds or not m.group(2):
            self.fail(f"{what} must be {' or '.join(k + '(label)' for k in kinds)}, got {text.strip()[:40]!r}")
        return m.group(1).upper(), m.group(2)

    def run(self, body: Body) -> None:
        k = 0
        while k < len(body.statements):
            self.st = st = body.statements[k]
            self.executed += 1
            if self.executed > MAX_STATEMENTS:
                self.fail(f"more than {MAX_STATEMENTS} statements executed: a loop that never ends? (JUMPTO, DO and "
                          "CALL are followed as the program says)")
            if self.ended and st.word != "(":
                self.skip("after ENDFIL: not read")
                k += 1
                continue
            if st.word == "ENDFIL" and self.depth > 0:
                return  # the end of a called file
            if st.word == "IF":
                if self.truth(st):
                    k += 1
                else:
                    k = body.match[k] + 1  # past ELSE (into its branch) or ENDIF
                continue
            if st.word == "ELSE":  # the end of the IF's true branch
                k = body.match[k] + 1
                continue
            if st.word == "DO":
                k = self.loop(body, k)
                continue
            if st.word == "JUMPTO":
                k = self.jump(body, st)
                continue
            if st.word in ("ENDIF", "ENDDO", "("):
                k += 1
                continue
            self.statement(st)
            k += 1

    def truth(self, st: lexer.Statement) -> bool:
        value = self.value(st.rest, "IF condition")
        return bool(value)

    def jump(self, body: Body, st: lexer.Statement) -> int:
        m = re.fullmatch(r"\(\s*([^()]+?)\s*\)", st.rest.strip())
        if not m:
            self.fail(f"JUMPTO takes a (label), got {st.rest!r}")
        target = body.targets.get(m.group(1).upper())
        if target is None:
            self.fail(f"JUMPTO/({m.group(1)}): no ({m.group(1)}) label in the same file or macro")
        return target + 1

    def loop(self, body: Body, k: int) -> int:
        st = body.statements[k]
        if len(st.fields) not in (3, 4):
            self.fail(f"DO takes var,start,end[,step], got {st.rest!r}")
        name = st.fields[0].upper()
        start, stop = (self.value(f, "DO bound") for f in st.fields[1:3])
        step = self.value(st.fields[3], "DO step") if len(st.fields) == 4 else 1.0
        if not all(isinstance(v, float) for v in (start, stop, step)) or step == 0.0:
            self.fail(f"DO bounds and step are numbers and the step is not zero, got {st.rest!r}")
        end = body.match[k]
        inner = Body(body.statements[k + 1:end], {t: j - k - 1 for t, j in body.targets.items() if k < j < end},
                      {a - k - 1: b - k - 1 for a, b in body.match.items() if k < a < end})
        i = start
        while (step > 0 and i <= stop) or (step < 0 and i >= stop):  # type: ignore[operator]
            self.variables[name] = i
            self.run(inner)
            self.executed += 1
            if self.executed > MAX_STATEMENTS:
                self.fail(f"more than {MAX_STATEMENTS} statements executed in the DO loop of line {st.line}")
            i = i + step  # type: ignore[operator]
        self.st = st
        return end + 1

    def value(self, text: str, what: str) -> expressions.Value:
        try:
            return expressions.evaluate(text, self.variables, self.rad_per_unit)
        except AlgorithmError as e:
            self.fail(f"{what}: {e}")

    # --- variables, calls -------------------------------------------------------------------

    def do_decl(self, st: lexer.Statement) -> None:
        f = [x.upper() for x in st.fields]
        while f and f[0] in ("COMMON", "GLOBAL", "LOCAL", "EXTERN"):
            f.pop(0)
        if not f:
            self.fail(f"DECL takes [scope,]type,name..., got {st.rest!r}")
        vtype = f.pop(0)
        if vtype == "CHAR" and f and _NUMBER.fullmatch(f[0]):
            f.pop(0)
        for name in f:
            base = re.sub(r"\[.*\]$", "", name)
            if not re.fullmatch(r"[A-Z_][A-Z0-9_]*", base):
                self.fail(f"DECL variable name {name!r} is not a name")
            self.variables.setdefault(base, "" if vtype == "CHAR" else 0.0)

    def do_assign(self, st: lexer.Statement) -> None:
        name, eq, expr = st.rest.partition("=")
        name = name.strip().upper()
        if not eq or not re.fullmatch(r"[A-Z_][A-Z0-9_]*", name):
            self.fail(f"ASSIGN takes name=expression, got {st.rest!r}")
        if name not in self.variables:
            self.fail(f"ASSIGN to {name}, which no DECL declares")
        self.variables[name] = self.value(expr, f"ASSIGN/{name}")

    def do_call(self, st: lexer.Statement) -> None:
        if not st.fields:
            self.fail("CALL takes M(macro),args or EXTERN,DMIS,'file'")
        head = st.fields[0].upper()
        if head == "EXTERN":
            self.call_file(st)
            return
        _, name = self.label(st.fields[0], ("M",), "CALL's macro")
        macro = self.macros.get(name.upper())
        if macro is None:
            self.fail(f"CALL/M({name}): no macro M({name}) is defined (M({name})=MACRO/... ENDMAC)")
        args = [a.strip() for a in st.fields[1:]]
        if len(args) != len(macro.params):
            self.fail(f"CALL/M({name}) gives {len(args)} argument(s); the macro takes {len(macro.params)}")
        body = substitute(macro.body, dict(zip(macro.params, args, strict=True)))
        self.enter(body)

    def call_file(self, st: lexer.Statement) -> None:
        f = st.fields
        if len(f) < 3 or f[1].upper() != "DMIS":
            self.skip(f"CALL/EXTERN,{f[1] if len(f) > 1 else ''}: only DMIS files are called (EXTERN,DMIS,'file'); "
                      "an external program is not run")
            return
        name = f[2].strip().strip("'")
        path = Path(st.source).parent / name
        if not path.is_file():
            self.fail(f"CALL/EXTERN,DMIS,'{name}': no such file next to {Path(st.source).name} ({os.fspath(path)})")
        body = self.load(path)
        self.enter(body)

    def enter(self, body: Body) -> None:
        caller = self.st
        self.depth += 1
        if self.depth > MAX_CALL_DEPTH:
            self.fail(f"calls nested more than {MAX_CALL_DEPTH} deep: a macro or file that calls itself?")
        self.run(body)
        self.depth -= 1
        self.st = caller
