"""Each document's claims against the committed reports: the table a document page shows.

``docs/claims.toml`` lists every claim of the five documents (``[[claim]]``), each with the
document's own number and where our reports measure it. A measured claim names a ``report`` (a
committed study or benchmark report), the ``column`` that answers it and two selections of that
report's table rows: ``printed`` (the document's algorithm and setup) and ``ours`` (our
improvements). A selection is ``where`` (column -> value or list of values, every row matching),
optionally ``section`` (the first such table under the nearest heading containing this text, or
a list of such texts, a table under each), ``item`` (which
number of a cell ``"a / b"``) and ``over`` (a second selection, of this report or of its own
``report``: the value becomes the first's median over the second's, e.g. a time ratio); a
selection may name its own ``report``. A claim
where none of our improvements applies has ``no_ours`` (why) instead of ``ours``.
``holds`` is the claim's test on each selected value (``">= 100"``, ``"<= 1"``): the verdict is

* **reproduced**: every row of the as-printed selection holds;
* **partly**: some do, or only ours does (reproduced with our improvements, not as printed);
* **not reproduced**: no row holds in either;

with the numbers beside it. A claim that cannot be measured has ``untested`` (why) instead. The
numbers are read from the reports at build time (``<!-- twin:claims 000 -->``), each under the
commit its report names (:mod:`report_stamps`): none is typed into a page.
"""

from __future__ import annotations

import operator
import re
import statistics
import tomllib
from dataclasses import dataclass
from pathlib import Path

from report_stamps import ROOT, stamp

CLAIMS = ROOT / "docs" / "claims.toml"
DOCUMENTS = ("000", "001", "002", "003", "004")
_OPS = {">=": operator.ge, "<=": operator.le, ">": operator.gt, "<": operator.lt}
_HOLDS = re.compile(r"^\s*(>=|<=|>|<)\s*(-?[\d.eE+-]+)\s*$")
_OF = re.compile(r"^(\d+) of (\d+)")
_MARKER = re.compile(r"<!--\s*twin:report\s+(.*?)\s*-->")
_YES, _NO = {"same", "yes", "True"}, {"differs", "no", "False"}
_NUMBER = re.compile(r"^[-+]?\d+(\.\d+)?([eE][+-]?\d+)?")


@dataclass(frozen=True)
class Table:
    """One markdown table of a report: the heading above it, its column names, its rows."""

    heading: str
    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]


def tables(text: str) -> list[Table]:
    """Every markdown table of ``text``, with the nearest heading above it."""
    found, heading, lines = [], "", text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("#"):
            heading = line.lstrip("#").strip()
        if line.startswith("|") and i + 1 < len(lines) and re.match(r"^\|[\s:|-]+\|\s*$", lines[i + 1]):
            columns = tuple(c.strip().strip("`") for c in _cells(line))
            rows, i = [], i + 2
            while i < len(lines) and lines[i].startswith("|"):
                rows.append(tuple(_cells(lines[i])))
                i += 1
            found.append(Table(heading, columns, tuple(rows)))
            continue
        i += 1
    return found


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def number(cell: str) -> float | None:
    """A cell's value: ``"19 of 20 (95 %)"`` -> 95.0 (percent), ``"3.21"`` -> 3.21, a yes/no cell
    (``same``/``differs``, ``True``/``False``) -> 100.0 or 0.0 (percent), else None."""
    cell = cell.replace("**", "").strip()
    if cell in _YES or cell in _NO:
        return 100.0 if cell in _YES else 0.0
    of = _OF.match(cell)
    if of:
        return 100.0 * int(of.group(1)) / int(of.group(2)) if int(of.group(2)) else None
    m = _NUMBER.match(cell)
    return float(m.group(0)) if m else None


def _same(cell: str, wanted: object) -> bool:
    values = wanted if isinstance(wanted, list) else [wanted]
    for w in values:
        a, b = number(cell), number(str(w))
        if (a is not None and b is not None and a == b and re.fullmatch(r"[-\d.eE+]+", cell)) or cell == str(w):
            return True
    return False


def select(report_text: str, column: str, selection: dict) -> list[float | None]:
    """The values of ``column`` in the rows ``selection`` picks (its ``where``, ``section``; ``item``:
    which number of a cell like ``"0.075/0.073"``, the first by default)."""
    where, item = selection.get("where", {}), selection.get("item", 0)
    sections = selection.get("section", [""])
    sections = [sections] if isinstance(sections, str) else sections
    found: list[float | None] = []
    for section in sections:
        for table in tables(report_text):
            if section not in table.heading:
                continue
            if column not in table.columns or any(k not in table.columns for k in where):
                continue
            at = {c: i for i, c in enumerate(table.columns)}
            picked = [row for row in table.rows if all(_same(row[at[k]], v) for k, v in where.items())]
            if picked:
                found += [number(re.split(r"\s*/\s*", row[at[column]])[item]) for row in picked]
                break
        else:
            raise LookupError(f"no table row of column {column!r} matches {selection} under {section!r}")
    return found


def values(claim: dict, side: str) -> list[float | None]:
    """The measured values of one side (``printed`` or ``ours``) of a claim."""
    selection = claim[side]
    text = (ROOT / selection.get("report", claim["report"])).read_text(encoding="utf-8")
    got = select(text, claim["column"], selection)
    if "over" not in selection:
        return got
    over = selection["over"]
    over_text = (ROOT / over["report"]).read_text(encoding="utf-8") if "report" in over else text
    base = [v for v in select(over_text, claim["column"], over) if v is not None]
    top = [v for v in got if v is not None]
    if not base or not top or statistics.median(base) == 0:
        return [None]
    return [statistics.median(top) / statistics.median(base)]


def holds(test: str, value: float | None) -> bool:
    """Whether ``value`` passes the claim's test (``">= 100"``); a missing value never does."""
    m = _HOLDS.match(test)
    if not m:
        raise ValueError(f"holds = {test!r}: must be an operator (>=, <=, >, <) and a number")
    return value is not None and _OPS[m.group(1)](value, float(m.group(2)))


def verdict(test: str, printed: list[float | None], ours: list[float | None]) -> str:
    """reproduced / partly / not reproduced (module docstring)."""
    p = [holds(test, v) for v in printed]
    o = [holds(test, v) for v in ours]
    if p and all(p):
        return "reproduced"
    if any(p) or any(o):
        return "partly" if any(p) else "partly: with our improvements only"
    return "not reproduced"


def shown(vals: list[float | None], unit: str) -> str:
    """The values as a cell: one value, or the range over the selected rows."""
    known = [v for v in vals if v is not None]
    missing = len(vals) - len(known)
    if not known:
        return "n/a"
    lo, hi = min(known), max(known)
    text = f"{lo:.3g}" if lo == hi else f"{lo:.3g} to {hi:.3g}"
    text += f" {unit}" if unit else ""
    return text + (f" ({missing} n/a)" if missing else "")


def reports(claim: dict) -> list[str]:
    """Every report a claim's values are read from."""
    found = [claim["report"]]
    for side in ("printed", "ours"):
        sel = claim.get(side, {})
        found += [s["report"] for s in (sel, sel.get("over", {})) if "report" in s]
    return list(dict.fromkeys(found))


def modules_of(report: str) -> list[str]:
    """The code a report measured, as the site's include markers of it name (``modules=``)."""
    found: list[str] = []
    for page in sorted((ROOT / "docs").rglob("*.md")):
        for args in _MARKER.findall(page.read_text(encoding="utf-8")):
            parts = args.split()
            if parts and parts[0] == report:
                found += [m for p in parts[1:] if p.startswith("modules=") for m in p[8:].split(",")]
    return list(dict.fromkeys(found))


def _stamped(report: str) -> str:
    s = stamp(ROOT / report, modules_of(report))
    stale = f", **{s.changed_since} later commit(s) changed what it measured**" if s.changed_since else ""
    return f"`{report}` (commit `{s.commit}`{stale})"


def load(path: Path = CLAIMS) -> list[dict]:
    """The claims file's ``[[claim]]`` entries."""
    return tomllib.loads(path.read_text(encoding="utf-8"))["claim"]


def claims_markdown(document: str, path: Path = CLAIMS) -> str:
    """The claims table of one document (``"000"``), numbers read from the reports."""
    rows = ["| claim | the document | as printed | ours | verdict | measured by |", "|---|---|---|---|---|---|"]
    for c in (c for c in load(path) if c["document"] == document):
        if "untested" in c:
            rows.append(f"| {c['claim']} | {c['document_value']} | n/a | n/a | not tested: {c['untested']} | |")
            continue
        printed = values(c, "printed")
        ours = values(c, "ours") if "ours" in c else []
        unit = c.get("unit", "")
        where = "; ".join(_stamped(r) for r in reports(c)) + f": `{c['command']}`"
        quantity = f"the ratio of {c['column']}" if "over" in c["printed"] else c["column"]
        what = f"{quantity} {c['holds']}{' ' + unit if unit else ''}"
        why = f"; {c['why']}" if c.get("why") else ""
        ours_cell = shown(ours, unit) if "ours" in c else f"n/a: {c['no_ours']}"
        rows.append(f"| {c['claim']} | {c['document_value']} | {shown(printed, unit)} | {ours_cell} | "
                    f"**{verdict(c['holds'], printed, ours)}** ({what}){why} | {where} |")
    return "\n".join(rows) + "\n"
