"""experiments/results/recipe.py: the committed recipe tables are what it writes, every deviation
names ours and the paper's value, and the training-time rule on small made-up curves."""

from __future__ import annotations

import json
import subprocess
import sys

from pe_mjx.experiment import default_config
from pe_mjx.paper import SETTINGS, hyperparameters
from tests.tool_modules import ROOT

RECIPE = ROOT / "docs" / "data" / "recipe"
FILES = ("recipe.json", "deviations.md", "hyperparameters.md", "compute.md")


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
