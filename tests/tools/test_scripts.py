"""The scripts beside the package (tools/: benchmarks and stress runs; experiments/<page>/: what
regenerates a page's data) import only the installed package and libraries: never another
script, never a test, and no `sys.path` edits (so each runs from anywhere, as `python PATH`)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = sorted([*(ROOT / "tools").glob("*.py"), *(ROOT / "experiments").rglob("*.py")])
LOCAL = {p.stem for p in SCRIPTS} | {"tools", "experiments", "tests"}


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_a_script_imports_no_other_script_nor_a_test(path):
    tree = ast.parse(path.read_text())
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names if a.name.split(".")[0] in LOCAL]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module.split(".")[0] in LOCAL:
                found.append(node.module)
        elif (
            isinstance(node, ast.Attribute)
            and node.attr == "path"
            and isinstance(node.value, ast.Name)
            and node.value.id == "sys"
        ):
            found.append("sys.path")
    assert found == [], f"{path.relative_to(ROOT)} imports {found}"
