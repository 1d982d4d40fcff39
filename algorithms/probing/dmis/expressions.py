"""DMIS expressions: the values of ``ASSIGN``, the conditions of ``IF``, and variables in fields.

Numbers, quoted strings, declared variables, ``+ - * / **``, parentheses, the relational and
logical operators ``.EQ. .NE. .LT. .LE. .GT. .GE. .AND. .OR. .NOT.``, and the functions ``ABS
SQRT SIN COS TAN ASIN ACOS ATAN ATAN2 EXP LN LOG INT NINT MOD MAX MIN`` (angles in the program's
angle unit, which the caller converts). Booleans are numbers (1 true, 0 false), as DMIS ``BOOL``
variables compare.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping

from algorithms.errors import AlgorithmError

Value = float | str

_TOKEN = re.compile(r"""\s*(?:
    (?P<number>(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?)
  | (?P<string>'[^']*')
  | (?P<dotop>\.(?:EQ|NE|LT|LE|GT|GE|AND|OR|NOT)\.)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<op>\*\*|[-+*/(),])
)""", re.VERBOSE | re.IGNORECASE)

_FUNCTIONS: dict[str, tuple[int, Callable[..., float]]] = {
    "ABS": (1, abs), "SQRT": (1, math.sqrt), "EXP": (1, math.exp), "LN": (1, math.log), "LOG": (1, math.log10),
    "INT": (1, lambda x: float(math.trunc(x))), "NINT": (1, lambda x: float(round(x))), "MOD": (2, math.fmod),
    "MAX": (2, max), "MIN": (2, min),
}
_ANGLE_IN = {"SIN": math.sin, "COS": math.cos, "TAN": math.tan}
_ANGLE_OUT = {"ASIN": math.asin, "ACOS": math.acos, "ATAN": math.atan}


def tokens(text: str) -> list[tuple[str, str]]:
    """(kind, text) tokens of an expression; kinds: number, string, dotop, name, op."""
    out: list[tuple[str, str]] = []
    pos = 0
    text = text.rstrip()
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None or m.end() == pos:
            raise AlgorithmError(f"{text!r} is not an expression: unexpected {text[pos:].strip()[:12]!r}")
        kind = m.lastgroup
        assert kind is not None
        out.append((kind, m.group(kind).upper() if kind in ("dotop", "name") else m.group(kind)))
        pos = m.end()
    return out


class _Parser:
    def __init__(self, text: str, variables: Mapping[str, Value], radians_per_unit: float) -> None:
        self.text = text
        self.toks = tokens(text)
        self.k = 0
        self.vars = variables
        self.rad = radians_per_unit

    def fail(self, message: str) -> AlgorithmError:
        return AlgorithmError(f"expression {self.text.strip()!r}: {message}")

    def peek(self) -> tuple[str, str] | None:
        return self.toks[self.k] if self.k < len(self.toks) else None

    def take(self, text: str | None = None) -> tuple[str, str]:
        t = self.peek()
        if t is None or (text is not None and t[1] != text):
            raise self.fail(f"expected {text or 'a value'}, got {t[1] if t else 'the end'}")
        self.k += 1
        return t

    def parse(self) -> Value:
        v = self.logical_or()
        if self.peek() is not None:
            raise self.fail(f"unexpected {self.peek()[1]!r}")  # type: ignore[index]
        return v

    def logical_or(self) -> Value:
        v = self.logical_and()
        while self.peek() == ("dotop", ".OR."):
            self.take()
            w = self.logical_and()
            v = float(bool(v) or bool(w))
        return v

    def logical_and(self) -> Value:
        v = self.logical_not()
        while self.peek() == ("dotop", ".AND."):
            self.take()
            w = self.logical_not()
            v = float(bool(v) and bool(w))
        return v

    def logical_not(self) -> Value:
        if self.peek() == ("dotop", ".NOT."):
            self.take()
            return float(not self.logical_not())
        return self.relation()

    def relation(self) -> Value:
        v = self.sum()
        t = self.peek()
        if t is not None and t[0] == "dotop" and t[1] not in (".AND.", ".OR.", ".NOT."):
            self.take()
            w = self.sum()
            if isinstance(v, str) != isinstance(w, str) and t[1] not in (".EQ.", ".NE."):
                raise self.fail(f"{t[1]} compares a string with a number")
            ops = {".EQ.": v == w, ".NE.": v != w}
            if t[1] in ops:
                return float(ops[t[1]])
            a, b = v, w
            return float({".LT.": a < b, ".LE.": a <= b, ".GT.": a > b, ".GE.": a >= b}[t[1]])  # type: ignore[operator]
        return v

    def sum(self) -> Value:
        v = self.product()
        while self.peek() in (("op", "+"), ("op", "-")):
            op = self.take()[1]
            w = self.product()
            if isinstance(v, str) or isinstance(w, str):
                if op == "+" and isinstance(v, str) and isinstance(w, str):
                    v = v + w
                    continue
                raise self.fail(f"{op} of a string")
            v = v + w if op == "+" else v - w
        return v

    def product(self) -> Value:
        v = self.power()
        while self.peek() in (("op", "*"), ("op", "/")):
            op = self.take()[1]
            w = self.power()
            a, b = self.numeric(v), self.numeric(w)
            if op == "/" and b == 0.0:
                raise self.fail("division by zero")
            v = a * b if op == "*" else a / b
        return v

    def power(self) -> Value:
        v = self.unary()
        if self.peek() == ("op", "**"):
            self.take()
            w = self.power()
            try:
                return float(self.numeric(v) ** self.numeric(w))
            except (OverflowError, ZeroDivisionError, ValueError):
                raise self.fail("the power is not a real number") from None
        return v

    def unary(self) -> Value:
        if self.peek() in (("op", "-"), ("op", "+")):
            sign = -1.0 if self.take()[1] == "-" else 1.0
            return sign * self.numeric(self.unary())
        return self.atom()

    def numeric(self, v: Value) -> float:
        if isinstance(v, str):
            raise self.fail(f"the string {v!r} is used as a number")
        return v

    def atom(self) -> Value:
        kind, text = self.take()
        if kind == "number":
            return float(text)
        if kind == "string":
            return text[1:-1]
        if kind == "op" and text == "(":
            v = self.logical_or()
            self.take(")")
            return v
        if kind == "name":
            if self.peek() == ("op", "("):
                return self.call(text)
            if text not in self.vars:
                raise self.fail(f"{text} is not a declared variable (declare it with DECL and set it with ASSIGN)")
            return self.vars[text]
        raise self.fail(f"unexpected {text!r}")

    def call(self, name: str) -> float:
        self.take("(")
        args = [self.numeric(self.logical_or())]
        while self.peek() == ("op", ","):
            self.take()
            args.append(self.numeric(self.logical_or()))
        self.take(")")
        try:
            if name in _ANGLE_IN and len(args) == 1:
                return _ANGLE_IN[name](args[0] * self.rad)
            if name in _ANGLE_OUT and len(args) == 1:
                return _ANGLE_OUT[name](args[0]) / self.rad
            if name == "ATAN2" and len(args) == 2:
                return math.atan2(args[0], args[1]) / self.rad
            if name in _FUNCTIONS and len(args) == _FUNCTIONS[name][0]:
                return float(_FUNCTIONS[name][1](*args))
        except (ValueError, OverflowError, ZeroDivisionError):
            raise self.fail(f"{name}({', '.join(f'{a:g}' for a in args)}) is not a real number") from None
        known = sorted([*_FUNCTIONS, *_ANGLE_IN, *_ANGLE_OUT, "ATAN2"])
        raise self.fail(f"{name} with {len(args)} argument(s) is not a function this reader evaluates: "
                        f"{', '.join(known)}")


def evaluate(text: str, variables: Mapping[str, Value], radians_per_unit: float = math.pi / 180.0) -> Value:
    """The value of the DMIS expression ``text`` (variables by upper-case name).

    Raises:
        AlgorithmError: a syntax error, an undeclared variable, a string used as a number, a
            division by zero or a function outside the list above.
    """
    return _Parser(text, variables, radians_per_unit).parse()
