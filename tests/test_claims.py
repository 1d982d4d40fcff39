"""The documents' claims tables: every claim of docs/claims.toml resolves against its committed
report (a report that names its commit), the verdict rule, the table reader, and each document
page shows its table."""

from __future__ import annotations

import sys

import pytest

from tests.helpers import ROOT

sys.path.insert(0, str(ROOT / "docs" / "_tools"))

import claims  # noqa: E402
from report_stamps import stamp  # noqa: E402

CLAIMS = claims.load()


def test_every_document_has_claims_and_every_claim_its_parts():
    for doc in claims.DOCUMENTS:
        assert sum(c["document"] == doc for c in CLAIMS) >= 2, doc
    for c in CLAIMS:
        assert c["document"] in claims.DOCUMENTS and c["claim"] and c["document_value"]
        if "untested" in c:
            assert len(c["untested"]) > 20  # a reason, not a placeholder
            continue
        assert {"report", "command", "column", "holds", "printed"} <= set(c)
        assert ("ours" in c) != ("no_ours" in c), c["claim"]
        claims.holds(c["holds"], 0.0)  # the test parses


@pytest.mark.parametrize("claim", [c for c in CLAIMS if "untested" not in c], ids=lambda c: c["claim"][:60])
def test_each_claim_reads_numbers_from_a_report_that_names_its_commit(claim):
    for report in claims.reports(claim):
        assert stamp(ROOT / report, []).stamped, f"{report} does not name the commit that made it"
    for side in ("printed", "ours"):
        if side in claim:
            values = claims.values(claim, side)
            assert values and any(v is not None for v in values), (claim["claim"], side)


def test_verdict_rule():
    assert claims.verdict(">= 100", [100.0, 100.0], [50.0]) == "reproduced"
    assert claims.verdict(">= 100", [50.0, 100.0], [100.0]) == "partly"
    assert claims.verdict(">= 100", [50.0], [100.0]) == "partly: with our improvements only"
    assert claims.verdict(">= 100", [50.0], [None]) == "not reproduced"
    assert claims.verdict("<= 1", [None], []) == "not reproduced"  # a missing value never holds
    with pytest.raises(ValueError, match="operator"):
        claims.holds("about 10", 3.0)


REPORT = """# A report

## First part

| method | ok | time [ms] |
|---|---|---|
| a | 19 of 20 (95 %) | 3.5 / 4.5 |
| b | 20 of 20 (100 %) | 7.0 / 8.0 |

## Second part

| method | ok | time [ms] |
|---|---|---|
| a | same | 1.0 |
"""


def test_table_reader_picks_rows_sections_and_items():
    assert claims.select(REPORT, "ok", {"where": {"method": "a"}}) == [95.0]
    assert claims.select(REPORT, "time [ms]", {"where": {"method": ["a", "b"]}, "item": 1}) == [4.5, 8.0]
    assert claims.select(REPORT, "ok", {"section": "Second", "where": {"method": "a"}}) == [100.0]
    assert claims.select(REPORT, "ok", {"section": ["First", "Second"], "where": {"method": "a"}}) == [95.0, 100.0]
    with pytest.raises(LookupError, match="no table row"):
        claims.select(REPORT, "ok", {"where": {"method": "c"}})


def test_every_document_page_shows_its_claims():
    for doc in claims.DOCUMENTS:
        page = (ROOT / "docs" / "results" / f"document-{doc}.md").read_text(encoding="utf-8")
        assert f"<!-- twin:claims {doc} -->" in page
        table = claims.claims_markdown(doc)
        assert table.count("\n") >= 3 and "| claim | the document | as printed | ours | verdict |" in table
