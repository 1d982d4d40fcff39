"""Numbers that cannot drift: every number a page types by hand must be found in the file it cites.

A page's prose (outside code, included reports and generated text) may hold a number only when
one of these holds:

- the block it stands in (a paragraph, a list item, a table row) cites a repository file (a link
  to it, or its path in backticks) that holds the same number;
- the page names the files its given values come from (``<!-- sources: a.toml, b.py -->``:
  scenario files, the code defining a default, a model's data) and one of them holds it;
- it is part of a name: document 001, Algorithm 5, eq. 11, Python 3.11, DMIS 5.3, UR5e ...

"The same number" allows the units the project writes: a figure in mm or um matches the file's
value in metres, a percentage its fraction. The number must be written as the file writes it
(3.6 matches 3.6 or 0.0036, not 3.61).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: A number as prose and files write it: 20,000 / 0.95 / 5e-6 / 1_000 / 10^4.
_NUMBER = re.compile(r"(?<![\w.^])(\d{1,3}(?:,\d{3})+|\d+(?:_\d+)*)(\.\d+)?(?:[eE]([-+]?\d+))?(?:\^(\d+))?"
                     r"(?![\w^]|\.\d)(?<!\d[xX])")
#: Words before a number that make it part of a name, not a quantity.
_NAME_WORDS = {"document", "documents", "doc", "algorithm", "algorithms", "eq", "eq.", "eqs", "equation", "equations",
               "section", "sections", "step", "steps", "table", "figure", "python", "dmis", "jcgm", "iso", "issue",
               "exit", "code", "codes", "status", "version", "part", "stage", "claim", "rule", "chapter", "page",
               "gum", "annex", "clause", "tier", "level", "appendix", "supplement", "eq.(", "documents'"}
#: Words that continue a list of names: documents 001 and 002, Algorithms 1-3.
_LIST_WORDS = {"and", "or", "to", "of"}
_FENCE = re.compile(r"^(```|~~~).*?^\1", re.MULTILINE | re.DOTALL)
_LIST_MARKER = re.compile(r"^\s*\d+\.(?= )", re.MULTILINE)
_INDENTED_CODE = re.compile(r"^(?: {4}|\t)(?![-*\d]).*$", re.MULTILINE)
_CODE = re.compile(r"`[^`]*`")
_COMMENT = re.compile(r"<!--.*?-->", re.DOTALL)
_LINK_TARGET = re.compile(r"\]\(([^)\s]+)\)")
_URL = re.compile(r"https?://\S+")
_PATH = re.compile(r"`([\w./-]+\.(?:md|toml|py|json|csv|txt|yaml|yml|dmi|step))`")
_SOURCES = re.compile(r"<!--\s*sources:\s*(.*?)\s*-->", re.DOTALL)
#: Unit factors between prose and files: as written, mm or um against metres, % against a fraction.
_SCALES = (1.0, 1e-3, 1e-6, 1e-2, 1e3, 1e6)


@dataclass(frozen=True)
class Problem:
    """A number not found where it should be."""

    page: str
    line: int
    number: str
    text: str
    cited: tuple[str, ...]

    def __str__(self) -> str:
        where = ", ".join(self.cited) if self.cited else "no file cited"
        return f"{self.page}:{self.line}: {self.number} is not in {where}: {self.text.strip()[:120]}"


def _value(m: re.Match) -> float:
    mantissa = float(m.group(1).replace(",", "").replace("_", "") + (m.group(2) or ""))
    if m.group(3):
        mantissa *= 10.0 ** int(m.group(3))
    if m.group(4):
        mantissa **= int(m.group(4))
    return mantissa


def file_numbers(path: Path) -> list[float]:
    """Every number a file writes (as magnitudes)."""
    text = path.read_text(encoding="utf-8", errors="replace")
    return sorted({_value(m) for m in _NUMBER.finditer(text)})


def _found(value: float, numbers: list[float]) -> bool:
    for scale in _SCALES:
        target = value * scale
        for n in numbers:
            if math.isclose(n, target, rel_tol=1e-9, abs_tol=0.0) or (n == 0.0 and value == 0.0):
                return True
    return False


def _blank(m: re.Match) -> str:
    """Text of the same shape with everything but line breaks blanked (line numbers stay right)."""
    return re.sub(r"[^\n]", " ", m.group(0))


def _prose(text: str) -> str:
    """The page with code, comments and link targets blanked out."""
    for pattern in (_FENCE, _COMMENT, _INDENTED_CODE, _LIST_MARKER):
        text = pattern.sub(_blank, text)
    text = _LINK_TARGET.sub(lambda m: "](" + " " * len(m.group(1)) + ")", text)
    return _CODE.sub(_blank, _URL.sub(_blank, text))


def _blocks(text: str) -> list[tuple[int, int]]:
    """(first line, end line) of each paragraph, list item and table row."""
    lines = text.split("\n")
    blocks, start = [], None
    for i, line in enumerate(lines + [""]):
        new_item = re.match(r"^\s*([-*+]|\d+\.|\|)\s", line) or line.startswith("|") or line.startswith("#")
        if not line.strip() or new_item:
            if start is not None:
                blocks.append((start, i))
            start = i if line.strip() else None
        elif start is None:
            start = i
    return blocks


def _cited(raw_block: str, page: Path) -> list[Path]:
    """The repository files a block cites: link targets and backticked paths that exist."""
    found = []
    for target in _LINK_TARGET.findall(raw_block) + _PATH.findall(raw_block):
        target = target.split("#")[0]
        if not target or target.startswith("http"):
            continue
        for base in (page.parent, ROOT):
            path = (base / target).resolve()
            if path.is_file():
                found.append(path)
                break
    return found


def _is_name(prose_line: str, start: int) -> bool:
    """A number that is part of a name (document 001, Algorithm 5, eq. (2), documents 001 and 002,
    UR5e, IL-065, DMIS 5.3)."""
    before = prose_line[:start]
    if re.search(r"[A-Za-z]-?$|[vV]$", before):
        return True
    for word in reversed(before.replace("(", " ").replace(",", " ").split()):
        word = word.lower().strip("*_")
        if word in _NAME_WORDS:
            return True
        if not (word in _LIST_WORDS or re.fullmatch(r"[\d.-]+", word)):
            return False
    return False


def check_page(page: Path, text: str | None = None) -> list[Problem]:
    """The numbers of ``page`` that are not found in what it cites."""
    text = page.read_text(encoding="utf-8") if text is None else text
    sources = [ROOT / s.strip() for m in _SOURCES.findall(text) for s in m.split(",") if s.strip()]
    missing = [s for s in sources if not s.is_file()]
    if missing:
        return [Problem(str(page), 1, "-", f"sources names a missing file: {missing[0]}", ())]
    raw_lines, prose_lines = text.split("\n"), _prose(text).split("\n")
    cache: dict[Path, list[float]] = {}
    problems = []
    for first, end in _blocks("\n".join(prose_lines)):
        cited = _cited("\n".join(raw_lines[first:end]), page)
        files = cited + sources
        for i in range(first, end):
            for m in _NUMBER.finditer(prose_lines[i]):
                if _is_name(prose_lines[i], m.start()):
                    continue
                numbers = [n for f in files for n in cache.setdefault(f, file_numbers(f))]
                if not _found(_value(m), numbers):
                    problems.append(Problem(_shown(page), i + 1, m.group(0), raw_lines[i],
                                            tuple(_shown(f) for f in files)))
    return problems


def _shown(path: Path) -> str:
    """A path as a message shows it: relative to the repository where it lies inside it."""
    path = path.resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def documentation_pages() -> list[Path]:
    """The hand-written pages: the README, every page of ``docs/`` and the folders' READMEs."""
    pages = [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md"))
    folders = ("scenarios", "studies", "benchmarks")
    pages += [ROOT / d / "README.md" for d in folders if (ROOT / d / "README.md").is_file()]
    return [p for p in pages if "_tools" not in p.parts]


def check_all() -> list[Problem]:
    """Every hand-typed number of the documentation that is not found in what it cites."""
    return [p for page in documentation_pages() for p in check_page(page)]


if __name__ == "__main__":
    import sys

    problems = check_all()
    print("\n".join(map(str, problems)) or "every number found in what it cites")
    sys.exit(1 if problems else 0)
