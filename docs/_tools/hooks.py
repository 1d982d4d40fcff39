"""MkDocs hooks: the pages that must not drift are filled in at build time.

A page holds a marker where generated text goes:

- ``<!-- twin:commands -->``: every ``twin`` command, from its parser (``twin.cli.reference``);
- ``<!-- twin:scenario-keys -->``, ``<!-- twin:study-keys -->``: every key the validators accept
  (``twin.schema``), with the meaning the file-format pages give each;
- ``<!-- twin:report PATH [modules=A,B] -->``: a committed report, included as it is, under its
  stamp (the commit and date it was made from, and whether the code it measured, ``modules``
  and the benchmark or study its command names, has changed since: ``reports.py``);
- ``<!-- twin:reports -->``: the table of every report the site includes, with the same stamps;
- ``<!-- twin:claims 000 -->``: a document's claims, as printed and ours, with their verdicts,
  read from the reports ``docs/claims.toml`` names (``claims.py``).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from claims import claims_markdown  # noqa: E402
from report_stamps import ROOT, stamp, stamp_markdown  # noqa: E402

MARKER = re.compile(r"<!--\s*twin:([\w-]+)\s*(.*?)\s*-->")
_IMAGE = re.compile(r"!\[([^\]]*)\]\(([^)\s]+)\)")
_LINK = re.compile(r"(?<!!)\[([^\]]+)\]\(([^)\s]+)\)")
_HEADING = re.compile(r"^(#{1,5}) ", re.MULTILINE)
_ROW = re.compile(r"^\|\s*((?:`[^`]+`(?:,\s*)?)+)\s*\|(?:[^|]*\|)?\s*(.*?)\s*\|\s*$")
_SECTION = re.compile(r"^\|\s*\*\*\[{1,2}([\w.]+)\]{1,2}\*\*\s*\|[^|]*\|(.*)$")
_TABLE_HEADING = re.compile(r"^#{2,4} \[{1,2}([\w.]+)\]{1,2}(.*)$")

#: Images of included reports: (report path, image name) -> the file's place in the site.
_IMAGES: dict[tuple[str, str], str] = {}


def _report_markers(docs_dir: Path) -> list[tuple[Path, str, list[str]]]:
    """Every report marker of the site's pages: (page, report path, modules)."""
    found = []
    for page in sorted(docs_dir.rglob("*.md")):
        for name, args in MARKER.findall(page.read_text(encoding="utf-8")):
            if name == "report":
                path, modules = _report_args(args)
                found.append((page, path, modules))
    return found


def _report_args(args: str) -> tuple[str, list[str]]:
    parts = args.split()
    modules = [m for p in parts[1:] if p.startswith("modules=") for m in p.removeprefix("modules=").split(",")]
    return parts[0], modules


def on_files(files: Any, config: Any) -> Any:
    """Add the images of every included report to the site, under ``results/files/``."""
    from mkdocs.structure.files import File

    for _, report, _ in _report_markers(Path(config["docs_dir"])):
        text = (ROOT / report).read_text(encoding="utf-8")
        for _, target in _IMAGE.findall(text):
            source = (ROOT / report).parent / target
            if target.startswith("http") or not source.is_file():
                continue
            uri = "results/files/" + str(Path(report).parent).replace("/", "_") + "/" + Path(target).name
            if (report, target) not in _IMAGES:
                _IMAGES[(report, target)] = uri
                files.append(File.generated(config, uri, abs_src_path=str(source)))
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    """Replace each marker of the page with what it stands for."""
    depth = page.file.src_uri.count("/")

    def fill(match: re.Match) -> str:
        name, args = match.group(1), match.group(2)
        if name == "report":
            return include_report(*_report_args(args), depth)
        if name == "reports":
            return reports_table(Path(config["docs_dir"]), page.file.src_uri)
        if name == "claims":
            return claims_markdown(args.strip())
        return generated(name, Path(config["docs_dir"]))

    return MARKER.sub(fill, markdown)


def generated(name: str, docs_dir: Path) -> str:
    """The generated text of a reference marker."""
    if name == "commands":
        from twin.cli.reference import commands_markdown

        return commands_markdown()
    from twin.schema import keys_markdown, scenario_keys, study_keys

    if name == "scenario-keys":
        return keys_markdown(scenario_keys(), meanings(docs_dir / "concepts" / "scenario-files.md"))
    if name == "study-keys":
        return keys_markdown(study_keys(), meanings(docs_dir / "concepts" / "study-files.md"))
    raise ValueError(f"unknown documentation marker twin:{name}")


def meanings(page: Path) -> dict[tuple[str, str], str]:
    """What each key means, from the key tables of a file-format page: rows ``| `key` | default |
    meaning |`` under a section row ``| **[table]** |`` or a heading ``### [table]: what it is``;
    a dotted key (``localize.method``) names its table, a ``[table]`` key the table itself."""
    out: dict[tuple[str, str], str] = {}
    table = ""
    for line in page.read_text(encoding="utf-8").splitlines():
        section = _SECTION.match(line) or _TABLE_HEADING.match(line)
        if section:
            table = section.group(1).replace("scan.passes", "scan.passes[]")
            what = section.group(2).strip(" |:")
            out[("", table)] = what or f"the `[{table}]` table"
            continue
        row = _ROW.match(line)
        if row:
            for key in re.findall(r"`([^`]+)`", row.group(1)):
                out[_key_of(table, key)] = row.group(2)
    return out


def _key_of(table: str, key: str) -> tuple[str, str]:
    """(table, key) of a key as a page writes it: ``kind``, ``localize.method``, ``[grid]``."""
    if key.startswith("["):
        return "", key.strip("[]")
    if table:
        return table, key
    where, _, name = key.rpartition(".")
    return where, name


def include_report(report: str, modules: list[str], depth: int) -> str:
    """A committed report under its stamp: headings one level down, its images from the site,
    its links to repository files as plain paths."""
    path = ROOT / report
    text = path.read_text(encoding="utf-8")
    up = "../" * depth

    def image(m: re.Match) -> str:
        uri = _IMAGES.get((report, m.group(2)))
        return f"![{m.group(1)}]({up}{uri})" if uri else m.group(0)

    def link(m: re.Match) -> str:
        target = m.group(2)
        if target.startswith(("http://", "https://", "#")):
            return m.group(0)
        return f"{m.group(1)} (`{(path.parent / target).resolve().relative_to(ROOT)}`)"

    text = _demote(_LINK.sub(link, _IMAGE.sub(image, text)))
    return stamp_markdown(stamp(path, modules), report) + "\n" + text


def _demote(text: str) -> str:
    """Headings two levels down (a report's title under the page's section), code left alone."""
    out, fenced = [], False
    for line in text.split("\n"):
        if line.startswith(("```", "~~~")):
            fenced = not fenced
        elif not fenced and _HEADING.match(line):
            hashes = len(line) - len(line.lstrip("#"))
            line = "#" * min(hashes + 2, 6) + line[hashes:]
        out.append(line)
    return "\n".join(out)


def reports_table(docs_dir: Path, here: str) -> str:
    """Every report the site includes: the page it is on, its commit and date, fresh or stale."""
    rows = ["| report | page | commit | date | code measured since |", "|---|---|---|---|---|"]
    for page, report, modules in _report_markers(docs_dir):
        s = stamp(ROOT / report, modules)
        rel = page.relative_to(docs_dir)
        link = "../" * here.count("/") + str(rel)
        since = f"**changed** ({s.changed_since} commits)" if s.changed_since else "unchanged"
        rows.append(f"| `{report}` | [{rel.stem}]({link}) | `{s.commit}` | {s.date} | {since} |")
    return "\n".join(rows) + "\n"
