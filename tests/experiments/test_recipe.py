"""experiments/results/recipe.py: the committed recipe tables are what it writes, every deviation
names ours and the paper's value, and the training-time rule on small made-up curves."""

from __future__ import annotations

import gzip
import json
import subprocess
import sys

from pe_mjx.eval_reports import code_provenance
from pe_mjx.experiment import default_config
from pe_mjx.paper import SETTINGS, hyperparameters
from tests.tool_modules import ROOT, load_experiment

RECIPE = ROOT / "docs" / "data" / "recipe"
FILES = ("recipe.json", "deviations.md", "hyperparameters.md", "compute.md")


def _load():
    return load_experiment("results", "recipe")


def test_the_committed_files_are_what_the_script_writes(tmp_path):
    subprocess.run(
        [sys.executable, "-m", "experiments.results.recipe", "--out", str(tmp_path)],
        check=True,
        capture_output=True,
        cwd=ROOT,
    )
    for name in FILES:
        assert (tmp_path / name).read_bytes() == (RECIPE / name).read_bytes(), (
            f"docs/data/recipe/{name} is stale: run `python -m experiments.results.recipe`"
        )


def test_every_deviation_names_ours_and_the_papers_value():
    data = json.loads((RECIPE / "recipe.json").read_text())
    values = {value for value, _ in SETTINGS.values()}
    rows = [r for r in (RECIPE / "deviations.md").read_text().splitlines() if r.startswith("| ")]
    assert len(data["deviations"]) >= 12
    assert len(rows) == len(data["deviations"]) + 1  # and the header
    for deviation, row in zip(data["deviations"], rows[1:], strict=True):
        assert all(deviation[key].strip() for key in ("what", "ours", "paper", "why", "measured"))
        assert any(deviation["paper"].startswith(value) for value in values), deviation
        assert row.split(" | ")[1:3] == [deviation["ours"], deviation["paper"]]
    for key, (value, says) in SETTINGS.items():
        assert value and (says is None or says.strip()), key


def test_the_tables_follow_the_config():
    config = default_config("20-5-8").override(
        {"evader.learning_rate": 5e-4, "ppo.gamma": 0.9, "env.reward.capture": 70.0}
    )
    rows = {r["setting"]: r for r in hyperparameters(config, env_steps=4096)}
    step = rows["Adam step size"]
    assert (step["pursuers"], step["evaders"]) == ("1e-3", "5e-4")
    assert rows["Discount γ / GAE λ"]["pursuers"] == "0.9 / 0.95"
    assert "r_s 70" in rows["Rewards"]["pursuers"]
    assert rows["Budget"]["pursuers"] == "4,096 env steps"


def _curves(run, wall_times):
    run.mkdir(parents=True)
    lines = ["env_steps,wall_time,episode/length"]
    lines += [f"{2048 * (i + 1)},{t},1" for i, t in enumerate(wall_times)]
    with gzip.open(run / "curves.csv.gz", "wt") as f:
        f.write("\n".join(lines) + "\n")


def test_a_pause_between_resumed_chunks_counts_as_one_median_interval(tmp_path, monkeypatch):
    module = _load()
    monkeypatch.setattr(module, "RUNS", tmp_path)
    # two chunks of 6-minute iterations, one with a 9-minute evaluation, 5 hours apart
    first = [0.0, 360.0, 720.0, 1260.0, 1620.0]
    _curves(tmp_path / "r", first + [1620.0 + 5 * 3600 + 360.0 * i for i in range(3)])
    time = module.training_time("r")
    assert (time["pauses"], time["median_interval_s"], time["longest_counted_s"]) == (1, 360, 540)
    # six intervals counted (2,340 s) and the pause as one median interval
    assert time["hours"] == 0.75
    assert time["paused_h"] == 5.0
    assert time["env_steps"] == 8 * 2048


def test_provenance_counts_each_reports_code_version():
    recipe = _load()
    clean = {"code_version": {"git_commit": "a" * 40, "git_dirty": False}}
    dirty = {"code_version": {"git_commit": "b" * 40, "git_dirty": True}}
    counts = code_provenance([clean, dirty, dirty, {}])
    assert counts == {"clean": 1, "dirty": 2, "not_recorded": 1}
    assert (
        recipe.provenance_cell(counts)
        == "1 of 4 clean commit, 2 of 4 dirty tree, 1 of 4 not recorded"
    )
    assert recipe.provenance_cell(code_provenance([clean, clean])) == "clean commit"
