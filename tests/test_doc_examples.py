"""Every ```python block of README.md and docs/*.md runs, so documented usage cannot rot.

Blocks are found by their fence (```python or ```py), never by line numbers, and each runs on its
own, as written, in a fresh namespace, with the working directory a scratch directory that holds
what the docs' shell steps leave a reader with:

* `runs/mix-20-5-8`: the run `pe-mjx train --preset 20-5-8` writes (here a copy of the shipped
  policy of that name);
* `pursuer.jaxexport`: `pe-mjx export mix-20-5-8 --team pursuer --preset 4-2-2 -o ...`;
* `export_loader.py`: the stand-alone loader, copied next to it as the docs tell.

Only the scene sizes change: the paper's presets ("16-4-4", "20-5-8", "24-6-12", "240-60-120"
as string literals) are played at "4-1-2", so that the examples compile in seconds on a CPU.

A block that is a fragment on purpose is marked by an HTML comment on the line before its fence,
`<!-- not run: why -->`; `test_not_run_marks_are_rare_and_give_a_reason` keeps those few.
"""

from __future__ import annotations

import contextlib
import io
import re
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^(\s*)```+\s*(python|py)\s*$")
NOT_RUN = re.compile(r"^\s*<!--\s*not run:\s*(.*?)\s*-->\s*$")
SMALL = "4-1-2"
PAPER_PRESETS = ("16-4-4", "20-5-8", "24-6-12", "240-60-120")
MAX_NOT_RUN = 3


def blocks(path: Path) -> list[tuple[str, str, str | None]]:
    """(id, code, reason it is not run or None) of every python block of a Markdown file."""
    lines = path.read_text().splitlines()
    found: list[tuple[str, str, str | None]] = []
    i = 0
    while i < len(lines):
        match = FENCE.match(lines[i])
        if not match:
            i += 1
            continue
        indent = len(match.group(1))
        j = i + 1
        while j < len(lines) and not lines[j].strip().startswith("```"):
            j += 1
        code = "\n".join(line[indent:] for line in lines[i + 1 : j])
        previous = next((lines[k] for k in range(i - 1, -1, -1) if lines[k].strip()), "")
        not_run = NOT_RUN.match(previous)
        first = next((x.strip() for x in code.splitlines() if x.strip()), "")[:40]
        block_id = f"{path.relative_to(ROOT)}#{len(found) + 1}:{first}"
        found.append((block_id, code, not_run.group(1) if not_run else None))
        i = j + 1
    return found


ALL = [b for path in DOCS for b in blocks(path)]
RUN = [b for b in ALL if b[2] is None]


def small(code: str) -> str:
    """`code` with the paper's presets (string literals) played at `SMALL`."""
    for preset in PAPER_PRESETS:
        code = code.replace(f'"{preset}"', f'"{SMALL}"').replace(f"'{preset}'", f"'{SMALL}'")
    return code


@pytest.fixture(scope="module")
def reader_dir(tmp_path_factory) -> Path:
    """What the docs' shell steps leave in a reader's working directory (module docstring)."""
    from pe_mjx import cli
    from pe_mjx.policy.shipped import policies_dir

    work = tmp_path_factory.mktemp("reader")
    shutil.copytree(policies_dir() / "mix-20-5-8", work / "runs" / "mix-20-5-8")
    shutil.copy(ROOT / "pe_mjx" / "policy" / "export_loader.py", work / "export_loader.py")
    with contextlib.redirect_stdout(io.StringIO()):
        cli.main(
            [
                *("export", "mix-20-5-8", "--team", "pursuer", "--preset", "4-2-2"),
                *("-o", str(work / "pursuer.jaxexport")),
            ]
        )
    return work


def test_the_docs_have_python_examples():
    """The discovery itself: README.md has python blocks, and every block found is non-empty."""
    assert any(block_id.startswith("README.md#") for block_id, _, _ in RUN)
    assert all(code.strip() for _, code, _ in ALL)


def test_not_run_marks_are_rare_and_give_a_reason():
    marked = [(block_id, reason) for block_id, _, reason in ALL if reason is not None]
    assert all(len(reason) >= 10 for _, reason in marked), marked
    assert len(marked) <= MAX_NOT_RUN, marked


@pytest.mark.parametrize(("block_id", "code"), [(b[0], b[1]) for b in RUN], ids=[b[0] for b in RUN])
def test_python_example_runs(block_id, code, reader_dir, tmp_path, monkeypatch):
    work = tmp_path / "cwd"
    shutil.copytree(reader_dir, work)
    monkeypatch.chdir(work)
    monkeypatch.syspath_prepend(str(work))
    monkeypatch.delitem(sys.modules, "export_loader", raising=False)
    namespace = {"__name__": "__doc_example__"}
    with contextlib.redirect_stdout(io.StringIO()):
        exec(compile(small(code), block_id, "exec"), namespace)
