"""docs/results.md and its dated notes quote the committed data rather than retyping it.

The page sets each of the paper's Tables II-VI beside ours, rebuilt here from the reproduce
output (`docs/data/paper-3m*/table-*/results.json`) and the paper's numbers (`pe_mjx.paper`);
its other tables are rows of the reports under `docs/data/`; and every decimal number on it is
one that a committed data file holds (or the paper's tables, or a mean of them).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from pe_mjx.eval_reports import code_provenance
from pe_mjx.paper import PAPER

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
DATA = DOCS / "data"
PAGE = DOCS / "results.md"
NOTES = DOCS / "experiments"
PAPER_TABLES_NOTE = NOTES / "2026-12-02-paper-tables.md"
LARGE_SCALE_NOTE = NOTES / "2026-12-03-large-scale.md"
# The reproduce output each of the page's tables is read from (3M env steps, seed 0).
PAGE_TABLES = {
    "II": "paper-3m-scales",
    "III": "paper-3m",
    "IV": "paper-3m-scales",
    "V": "paper-3m-scales",
    "VI": "paper-3m-scales",
}
METHODS = ("mix", "mean", "birnn", "mlp")
# Decimal numbers on the page that are not data: the spec's section numbers.
NOT_DATA = {"3.1"}
# The data files the page draws its numbers from (globs under docs/data).
SOURCES = (
    "paper-3m/**/*.json",
    "paper-3m-scales/**/*.json",
    "paper-10m/**/*.json",
    "best-responses-20-5-8/results.json",
    "pool-3m/results.json",
    "pool-3m/rating/leaderboard.json",
    "coev-seeds-3m/*/seeds.json",
    "paper-3m-seeds/seeds.json",
    "large-scale/summary.json",
    "transfer-240-60-120-3m/results.json",
    "arena-240-60-120/results.json",
    "recipe/recipe.json",
    "leaderboards/*/leaderboard.json",
    "flagship-seeds/seeds.json",
    "flagship-seeds/s*/results.json",
)
# Each report `pe-mjx reproduce` wrote, with the data directory that
# experiments/results/paper_findings.py read:
# the notes quote both.
REPORTS = {"paper_tables.md": "paper", "paper_tables-3m.md": "paper-3m"}
# Reports of the co-evolutions trained at the paper's other scales (Tables II and IV): quoted
# tables only, no findings file of their own.
SCALE_REPORTS = ("paper_tables-3m-scales.md",)
SCENE_ROW = re.compile(r"\| \d+-\d+-\d+ \| ")


def _table_rows(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("| ")]


def _section(text: str, heading: str) -> str:
    """The text under `heading` (a line) up to the next heading of any level."""
    body = text.split(f"\n{heading}\n", 1)[1]
    return re.split(r"\n#+ ", body, maxsplit=1)[0]


def _method(label: str) -> str:
    return re.match(r"[EP]_([A-Z]+)", label).group(1).lower()


def _expected_rows(table: str) -> list[str]:
    """The page's rows of `table`: the paper's cross pairings, ours beside the paper's numbers
    (ours with an MLP moved to another scene, which the paper has not, stay in the reports)."""
    results = json.loads(
        (DATA / PAGE_TABLES[table] / f"table-{table}" / "results.json").read_text()
    )
    cells = {}
    for pairing in results["pairings"]:
        pursuer, evader = pairing["pursuer"]["label"], pairing["evader"]["label"]
        if "scripted" in pursuer + evader or _method(pursuer) == _method(evader):
            continue
        cells[_method(evader), _method(pursuer)] = (pairing["summary"], pursuer.endswith("*"))
    rows = []
    for evader in METHODS:
        for pursuer in METHODS:
            if (evader, pursuer) not in cells:
                continue
            ours, moved = cells[evader, pursuer]
            paper = PAPER[table].get((evader, pursuer))
            if moved and paper is None:
                continue
            low, high = ours["per_evader_cost_ci95"]
            theirs = (
                ("-", "-", "-")
                if paper is None
                else (f"{paper[0]:.3f}", f"{paper[3]:.3f}", f"{paper[1]:.2f}")
            )
            rows.append(
                f"| {evader.upper()} | {pursuer.upper()}{'*' if moved else ''} "
                f"| {ours['success_rate']:.3f} ± {ours['success_rate_ci95']:.3f} | {theirs[0]} "
                f"| {ours['per_evader_cost']:.3f} [{low:.3f}, {high:.3f}] | {theirs[1]} "
                f"| {ours['travel_distance']:.2f} | {theirs[2]} |"
            )
    return rows


@pytest.mark.parametrize("table", sorted(PAGE_TABLES))
def test_each_paper_table_on_the_page_is_ours_beside_the_papers(table):
    page = PAGE.read_text()
    headings = re.findall(rf"^### Table {table}: .*$", page, flags=re.M)
    assert len(headings) == 1, headings
    rows = [r for r in _table_rows(_section(page, headings[0])) if not r.startswith("| Evader ")]
    expected = _expected_rows(table)
    assert len(expected) >= 9
    assert all("-" not in row.split("|")[4] for row in expected)  # the paper has each cell
    assert rows == expected


def test_the_pages_other_tables_are_rows_of_their_reports():
    """The seed tables quote experiments/results/seed_spread.py's reports, the 10M tables
    experiments/results/budget.py's, the best responses their evaluation's report, the
    240-60-120 table experiments/results/large_scale.py's summary, each row as written there."""
    page = PAGE.read_text()
    over = _section(page, "### Table III over three seeds (3M)")
    report = (DATA / "paper-3m-seeds" / "seeds.md").read_text()
    matrix = report.split("\nSuccess, evaders", 1)[1].split("\nPer-evader cost, evaders", 1)[0]
    quoted = [r for r in _table_rows(over) if r.startswith("| E_")]
    assert len(quoted) == 5
    assert quoted == [r for r in _table_rows(matrix) if r.startswith("| E_")]
    budget = _section(page, "### Table III at 10M env steps (MJX)")
    report = (DATA / "paper-10m" / "budget.md").read_text()
    quoted = [r for r in _table_rows(budget) if r.startswith("| E_")]
    assert len(quoted) == 5  # the success table; the cost table is in the linked report
    assert set(quoted) <= set(_table_rows(report))
    responses = _section(page, "### Best responses at 20-5-8 (10M, MJX)")
    report = (DATA / "best-responses-20-5-8" / "results.md").read_text()
    quoted = [r for r in _table_rows(responses) if not r.startswith(("|---", "| Evader"))]
    assert len(quoted) >= 4  # each best response against its policy, beside the headline pair
    assert set(quoted) <= set(_table_rows(report))
    pools = _section(page, "### Opponent pools at 20-5-8 (kinematic)")
    board = (DATA / "pool-3m" / "rating" / "leaderboard.md").read_text()
    quoted = [r for r in _table_rows(pools) if r.startswith("| ")]
    assert len(quoted) >= 6 and set(quoted) <= set(_table_rows(board))
    flagship = _section(page, "### The flagship over three seeds, against held-out evaders")
    report = (DATA / "flagship-seeds" / "seeds.md").read_text()
    quoted = [r for r in _table_rows(flagship) if r.startswith("| E_")]
    assert len(quoted) >= 5
    assert set(quoted) <= set(_table_rows(report))
    large = _section(page, "## 240-60-120 (beyond the paper)")
    summary = (DATA / "large-scale" / "summary.md").read_text()
    quoted = [r for r in _table_rows(large) if SCENE_ROW.match(r)]
    assert quoted and set(quoted) <= set(_table_rows(summary))


def test_the_recipe_tables_are_rows_of_their_reports():
    """The recipe section quotes experiments/results/recipe.py's three tables row for row (their
    links rebased from docs/data/recipe/ to docs/), the compute table all but its last row."""
    page = PAGE.read_text()
    recipe = _section(page, "## Recipe: deviations, hyperparameters, compute")
    quoted = [r for r in _table_rows(recipe) if not r.startswith("|---")]
    for name, rows in (("deviations", 12), ("hyperparameters", 11), ("compute", 9)):
        report = (DATA / "recipe" / f"{name}.md").read_text().replace("](../../", "](")
        written = [r for r in _table_rows(report) if not r.startswith("|---")]
        on_page = [r for r in written if r in quoted]
        assert len(on_page) >= rows, (name, len(on_page))
        quoted = [r for r in quoted if r not in on_page]
    assert not quoted, quoted


def test_every_table_on_the_page_has_its_header_row_and_separator():
    """A table whose separator row is lost renders as text (the compute table's once was, when
    its rows were copied in again); each table of the page starts with a header row and
    `|---|`, one cell per column."""
    lines = re.sub(r"```.*?```", "", PAGE.read_text(), flags=re.S).splitlines()
    starts = [i for i, line in enumerate(lines) if line.startswith("|") and not lines[i - 1]]
    assert len(starts) >= 15
    for i in starts:
        columns = lines[i].count(" | ") + 1
        assert lines[i + 1] == "|---" * columns + "|", (i + 1, lines[i][:60])


def _numbers(value, out: set[str]) -> None:
    """Every float and int under `value`, as the page may print it, but the per-trial lists of
    an evaluation (so many numbers would let almost any value pass)."""
    if isinstance(value, dict):
        for key, v in value.items():
            if key != "trials" or not isinstance(v, dict):
                _numbers(v, out)
    elif isinstance(value, list):
        for v in value:
            _numbers(v, out)
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        out.update(f"{value:.{digits}f}" for digits in (1, 2, 3))


def _paper_means() -> set[str]:
    """The paper's own per-method means and evader duels, as
    experiments/results/paper_findings.py forms
    ours: a pursuer's mean over the other methods' evaders, an evader's mean success conceded to
    the other methods' pursuers, and two evaders' means over the pursuers both met."""
    out = set()
    for table in ("II", "III", "IV"):
        cells = PAPER[table]
        for method in METHODS:
            met = [e for e in METHODS if e != method]
            for column in (0, 3):
                out.add(f"{sum(cells[e, method][column] for e in met) / 3:.3f}")
            out.add(f"{sum(cells[method, p][0] for p in met) / 3:.3f}")
        for a in METHODS:
            for b in METHODS:
                common = [p for p in METHODS if p not in (a, b)]
                if a != b:
                    out.add(f"{sum(cells[a, p][0] for p in common) / len(common):.3f}")
    return out


def _clean(code_version: dict | None) -> bool:
    """Whether an evaluation recorded that it ran from a commit without uncommitted changes (as
    the compute table counts it, `pe_mjx.eval_reports.code_provenance`)."""
    return code_provenance([{"code_version": code_version}])["clean"] == 1


def _clean_large_scale() -> dict[str, dict[str, dict]]:
    """docs/data/large-scale/summary.json's rows (scene -> pairing -> numbers) of the parts
    played from a clean commit: the only ones the page may quote."""
    summary = json.loads((DATA / "large-scale" / "summary.json").read_text())
    clean = {part for part, version in summary["provenance"].items() if _clean(version)}
    return {
        scene: {key: row for key, row in rows.items() if f"{scene}/{row['part']}" in clean}
        for scene, rows in summary["scenes"].items()
    }


def test_every_evaluation_the_page_quotes_was_played_from_a_clean_commit():
    """Each table's evaluations (the compute table's provenance, from each report's
    `meta.code_version`), the single reports the page reads, and the 240-60-120 rows it quotes
    were played from a clean commit, so the code version in their data reproduces them."""
    tables = json.loads((DATA / "recipe" / "recipe.json").read_text())["compute"]["tables"]
    assert len(tables) >= 10
    for name, table in tables.items():
        assert table["provenance"]["clean"] > 0, name
        assert table["provenance"]["dirty"] == table["provenance"]["not_recorded"] == 0, name
    reports = [p for pattern in SOURCES for p in DATA.glob(pattern) if p.name == "results.json"]
    boards = sorted(DATA.glob("leaderboards/*/leaderboard.json"))
    assert len(boards) == 3
    for board in boards:  # every file a leaderboard on the page was fitted to
        reports += [ROOT / s["path"] for s in json.loads(board.read_text())["sources"]]
    assert len(reports) >= 30
    for path in reports:
        assert _clean(json.loads(path.read_text())["meta"].get("code_version")), path
    clean = _clean_large_scale()
    large = _section(PAGE.read_text(), "## 240-60-120 (beyond the paper)")
    quoted = [r.split(" | ") for r in _table_rows(large) if SCENE_ROW.match(r)]
    assert len(quoted) >= 10
    for cells in quoted:
        assert cells[2] in clean.get(cells[0].strip("| "), {}), cells[:3]


def test_every_decimal_number_on_the_page_is_in_a_committed_file():
    """A guard against numbers from nowhere (a typo, a number of an older run), not a proof
    that each sits in the right sentence: with a few hundred pairings, about half of all
    three-decimal values in [0, 1] are some datum. The tables are checked row by row above;
    of the 240-60-120 summary, only the rows played from a clean commit count."""
    allowed = set(NOT_DATA) | _paper_means()
    for path in (path for pattern in SOURCES for path in DATA.glob(pattern)):
        is_summary = path.name == "summary.json"
        _numbers(_clean_large_scale() if is_summary else json.loads(path.read_text()), allowed)
    _numbers([list(cells) for table in PAPER.values() for cells in table.values()], allowed)
    page = re.sub(r"```.*?```", "", PAGE.read_text(), flags=re.S)  # commands, not results
    page = re.sub(r"\([^()\s]*\.(?:png|npz|md)\)", "", page)  # link targets
    # with its sign where one stands before it ("-2.97", a rating below the anchor's; not the
    # dash of a range such as "0.980-1.000")
    numbers = re.findall(r"(?<![\w.])-?\d+\.\d+(?![\w.])", page)
    assert len(numbers) > 300
    unknown = sorted(set(numbers) - allowed)
    assert not unknown, unknown


@pytest.mark.parametrize("note", [PAPER_TABLES_NOTE])
def test_the_paper_tables_in_the_notes_are_those_reproduce_wrote(note):
    """Each 'Table N' heading and each ours / paper row the dated note quotes is in a
    reproduce report (paper_tables*.md is what `pe-mjx reproduce` regenerates)."""
    text = note.read_text()
    report = "\n".join((DOCS / name).read_text() for name in (*REPORTS, *SCALE_REPORTS))
    headings = re.findall(r"^\*\*(Table [IVX]+: .*)\*\*$", text, flags=re.M)
    assert headings
    assert len(headings) == len(set(headings)), f"a table is quoted twice: {headings}"
    for heading in headings:
        assert f"## {heading}" in report, heading
    quoted = [row for row in _table_rows(text) if re.search(r"\| [\d.]+ / [\d.-]+ \|", row)]
    assert quoted
    stale = [row for row in quoted if row not in set(_table_rows(report))]
    assert not stale, stale


@pytest.mark.parametrize("data", sorted(REPORTS.values()))
def test_the_per_method_means_in_the_notes_are_those_paper_findings_wrote(data):
    text = PAPER_TABLES_NOTE.read_text()
    table = json.loads((DATA / data / "findings.json").read_text())["table-III"]
    assert len(table["pursuers"]) >= 3
    for method in table["pursuers"]:
        p, e = table["pursuers"][method], table["evaders"][method]
        row = (
            f"| {method.upper()} | {p['success']:.3f} | {p['per_evader_cost']:.3f} "
            f"| {p['travel']:.2f} | {e['success_conceded']:.3f} | {e['travel_forced']:.2f} |"
        )
        assert row in text.splitlines(), row


def test_the_large_scale_rows_are_those_tools_large_scale_wrote():
    """The note quotes docs/data/large-scale/summary.md rows as written, and the summary is
    made of the per-pairing reports beside it."""
    summary_md = (DATA / "large-scale" / "summary.md").read_text()
    quoted = [r for r in _table_rows(LARGE_SCALE_NOTE.read_text()) if SCENE_ROW.match(r)]
    summary_rows = [r for r in _table_rows(summary_md) if SCENE_ROW.match(r)]
    assert quoted and set(quoted) <= set(summary_rows)
    summary = json.loads((DATA / "large-scale" / "summary.json").read_text())
    for scene, rows in summary["scenes"].items():
        reports = sorted((DATA / "large-scale" / scene).glob("*/results.json"))
        pairings = [p for r in reports for p in json.loads(r.read_text())["pairings"]]
        assert len(pairings) == len(rows), scene
        rates = sorted(round(p["summary"]["success_rate"], 3) for p in pairings)
        assert rates == sorted(r["success_rate"] for r in rows.values()), scene
