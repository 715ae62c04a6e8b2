"""The repository stays a product, not a run archive (train/README.md, DEVELOPERS rules): a small
tracked tree, no TensorBoard events, one resumable checkpoint per run in progress and none of a
finished run's train state. Reads `git ls-files` of this checkout (tracked and staged files)."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

from pe_mjx.policy.ship import derived_source

ROOT = Path(__file__).resolve().parents[1]
MAX_TREE_BYTES = 25 * 10**6
MAX_FILES = 800
MAX_FILE_BYTES = 10**6


def tracked() -> dict[str, int]:
    """Tracked path -> its size in bytes as the tree stores it (a symlink is its target's name,
    as `du` counts it: the runs that link a shipped policy hold no second copy); paths deleted
    in the work tree are left out."""
    out = subprocess.run(
        ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True, timeout=60
    ).stdout.decode()
    paths = [p for p in out.split("\0") if p]
    sizes = {}
    for path in paths:
        file = ROOT / path
        if file.is_symlink() or file.is_file():
            sizes[path] = file.lstat().st_size
    return sizes


def _in_progress_checkpoint(path: str) -> bool:
    parts = Path(path).parts
    return parts[:2] == ("train", "unfinished") and "checkpoints" in parts


def test_the_tracked_tree_is_small():
    files = tracked()
    assert sum(files.values()) < MAX_TREE_BYTES, f"{sum(files.values()):,} bytes tracked"
    assert len(files) < MAX_FILES, f"{len(files)} files tracked"
    large = [p for p, n in files.items() if n > MAX_FILE_BYTES and not _in_progress_checkpoint(p)]
    assert large == [], "files over 1 MB outside the checkpoints of runs in progress"


def test_no_tensorboard_events_and_no_train_state_of_a_finished_run():
    files = tracked()
    assert [p for p in files if ".tfevents." in p] == []
    steps: dict[Path, set[str]] = {}
    for path in files:
        parts = Path(path).parts
        if parts[0] == "train" and "checkpoints" in parts:
            at = parts.index("checkpoints")
            run, step = Path(*parts[:at]), parts[at + 1]
            steps.setdefault(run, set()).add(step)
            if parts[1] != "unfinished":  # finished runs keep their policies only
                assert parts[at + 2] != "train", path
    for run, found in steps.items():
        if run.parts[1] == "unfinished":
            assert len(found) == 1, f"{run} tracks checkpoints {sorted(found)}: keep the latest"
    for run in {Path(*Path(p).parts[:3]) for p in files if Path(p).parts[1:2] == ("runs",)}:
        if run.name != "README.md":
            assert (ROOT / run / "config.json").is_file(), run
            source = derived_source(json.loads((ROOT / run / "config.json").read_text()))
            if source is not None:  # `pe-mjx ship --nearest-k` of a run here: its curves
                run = Path(source)
                assert run.parent == Path("train/runs"), source
            assert (ROOT / run / "curves.csv.xz").is_file(), run


_LINK = re.compile(r"\]\(([^)\s#]+)(?:#[^)]*)?\)")
_SCRIPT = re.compile(r"(?<![\w/.-])((?:tools|experiments|train|tests)/[\w/-]+\.py)\b")


def test_every_link_and_script_the_docs_name_exists():
    """A relative markdown link, or a script path (`tools/...py`, `experiments/...py`), in any
    tracked markdown file names a file that is here: scripts move, and the page that told a
    reader to run one must move with them."""
    broken = []
    for path in (p for p in tracked() if p.endswith(".md")):
        text = (ROOT / path).read_text(encoding="utf-8")
        for target in _LINK.findall(text):
            external = "://" in target or target.startswith("mailto:")
            if not external and not (ROOT / path).parent.joinpath(target).exists():
                broken.append(f"{path}: link {target}")
        broken += [f"{path}: {s}" for s in _SCRIPT.findall(text) if not (ROOT / s).exists()]
    assert broken == []
