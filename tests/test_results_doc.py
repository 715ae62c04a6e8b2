"""docs/results.md quotes its tables from the generated reports rather than retyping them."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
# Each report `pe-mjx reproduce` wrote, with the data directory tools/paper_findings.py read.
REPORTS = {"paper_tables.md": "paper", "paper_tables-3m.md": "paper-3m"}
# Reports of the co-evolutions trained at the paper's other scales (Tables II and IV): quoted
# tables only, no findings file of their own.
SCALE_REPORTS = ("paper_tables-3m-scales.md",)


def _table_rows(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("| ")]


def test_the_paper_tables_in_results_md_are_those_reproduce_wrote():
    """Each 'Table N' heading and each ours / paper row of results.md is in a reproduce report.

    The copy in results.md is how a reader meets the tables; paper_tables*.md is what
    `pe-mjx reproduce` regenerates. A hand edit or a stale copy shows up here.
    """
    results = (DOCS / "results.md").read_text()
    report = "\n".join((DOCS / name).read_text() for name in (*REPORTS, *SCALE_REPORTS))
    headings = re.findall(r"^\*\*(Table [IVX]+: .*)\*\*$", results, flags=re.M)
    assert headings, "results.md quotes no paper table"
    assert len(headings) == len(set(headings)), f"a table is quoted twice: {headings}"
    for heading in headings:
        assert f"## {heading}" in report, heading
    report_rows = set(_table_rows(report))
    quoted = [row for row in _table_rows(results) if re.search(r"\| [\d.]+ / [\d.-]+ \|", row)]
    assert quoted
    stale = [row for row in quoted if row not in report_rows]
    assert not stale, stale


@pytest.mark.parametrize("data", sorted(REPORTS.values()))
def test_the_per_method_means_in_results_md_are_those_paper_findings_wrote(data):
    results = (DOCS / "results.md").read_text()
    table = json.loads((DOCS / "data" / data / "findings.json").read_text())["table-III"]
    assert len(table["pursuers"]) >= 3
    for method in table["pursuers"]:
        p, e = table["pursuers"][method], table["evaders"][method]
        row = (
            f"| {method.upper()} | {p['success']:.3f} | {p['per_evader_cost']:.3f} "
            f"| {p['travel']:.2f} | {e['success_conceded']:.3f} | {e['travel_forced']:.2f} |"
        )
        assert row in results.splitlines(), row


def test_the_large_scale_table_is_the_one_tools_large_scale_wrote():
    """Section 10 of results.md quotes docs/data/large-scale/summary.md row for row, and the
    summary is made of the per-pairing reports beside it."""
    results = (DOCS / "results.md").read_text()
    section = results.split("## 10. Beyond the paper: 240-60-120", 1)[1]
    summary_md = (DOCS / "data" / "large-scale" / "summary.md").read_text()
    scene_rows = re.compile(r"\| \d+-\d+-\d+ \| ")
    quoted = [row for row in _table_rows(section) if scene_rows.match(row)]
    assert quoted and quoted == [row for row in _table_rows(summary_md) if scene_rows.match(row)]
    summary = json.loads((DOCS / "data" / "large-scale" / "summary.json").read_text())
    for scene, rows in summary["scenes"].items():
        reports = sorted((DOCS / "data" / "large-scale" / scene).glob("*/results.json"))
        pairings = [p for r in reports for p in json.loads(r.read_text())["pairings"]]
        assert len(pairings) == len(rows), scene
        rates = sorted(round(p["summary"]["success_rate"], 3) for p in pairings)
        assert rates == sorted(r["success_rate"] for r in rows.values()), scene
