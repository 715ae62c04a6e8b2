"""`rollout`, `play_scripted_match` and the `pe-mjx demo` command (run for real in a subprocess)."""

from __future__ import annotations

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pe_mjx.config import get_preset
from pe_mjx.match import play_scripted_match, rollout
from pe_mjx.names import CAUSE_NAMES
from pe_mjx.policy.scripted import make_policy

PRESET = "4-1-2"


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pe_mjx.cli", *args],
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_play_scripted_match_summary():
    result = play_scripted_match(PRESET, seed=0, backend="kinematic", steps=300)
    config = get_preset(PRESET)
    for value in result.values():
        assert type(value) in (int, float, bool)
    assert 1 <= result["steps"] <= 300
    assert result["evaders_total"] == config.evader.num_agents
    assert result["pursuers_total"] == config.pursuer.num_agents
    assert 0 <= result["evaders_captured"] <= result["evaders_total"]
    assert result["evaders_captured"] == result["evaders_capture"]
    for who, total in (("pursuers", "pursuers_total"), ("evaders", "evaders_total")):
        causes = sum(result[f"{who}_{name}"] for name in CAUSE_NAMES.values())
        assert causes + result[f"{who}_active"] == result[total]
    assert result["terminated"] != result["truncated"]
    if result["terminated"]:
        assert result["evaders_active"] == 0 or result["pursuers_active"] == 0
    assert result["mean_pursuer_distance"] > 0
    # Same seed, same result (the compiled match is cached, so this costs one run).
    assert play_scripted_match(PRESET, seed=0, backend="kinematic", steps=300) == result


def test_play_scripted_match_stops_at_the_step_budget():
    result = play_scripted_match(PRESET, seed=1, backend="kinematic", steps=3)
    assert result["steps"] == 3
    assert result["truncated"] and not result["terminated"]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"steps": 0}, "steps"),
        ({"backend": "bullet"}, "backend"),
        ({"preset": "3-3-3"}, "preset"),
    ],
)
def test_play_scripted_match_rejects_bad_input(kwargs, match):
    args = {"preset": PRESET, "seed": 0, "backend": "kinematic", "steps": 10, **kwargs}
    with pytest.raises(ValueError, match=match):
        play_scripted_match(**args)


def test_rollout_stops_at_done_and_freezes_finished_arenas(get_compiled):
    """A pursuer placed touching the evader captures it in step 1: that arena stops there."""
    c = get_compiled("2-1-1", "kinematic")
    env, config = c.env, c.config
    policies = {t: make_policy("scripted", config, t) for t in ("pursuer", "evader")}
    with pytest.raises(ValueError, match="evader"):
        rollout(env, {"pursuer": policies["pursuer"]}, jax.random.key(0), 5)
    start = c.place(
        pursuer=[[0.0, 0.0, 0.0], [-1.0, 1.0, 0.0]],
        evader=[[0.15, 0.0, 0.0]],
        obstacles=[[0.0, -1.2, 0.3]],
    )
    # Batched with a fresh arena: the captured one stops at step 1 while the other plays on.
    fresh = c.reset(3)
    both = jax.tree.map(lambda a, b: jnp.stack([a, b]), start, fresh)
    keys = jax.random.split(jax.random.key(0), 2)
    finals = jax.jit(jax.vmap(lambda key, s: rollout(env, policies, key, 50, state=s)))(keys, both)
    assert float(finals.done[0]) == 1.0
    assert int(finals.metrics["episode/captures"][0]) == 1
    steps = np.asarray(finals.world.step)
    assert steps[0] == 1
    assert 1 <= steps[1] <= 50
    assert steps[1] == 50 or float(finals.done[1]) == 1.0


def test_demo_cli_prints_the_match():
    proc = run_cli("demo", "--preset", PRESET, "--seed", "0", "--steps", "300")
    assert proc.returncode == 0, proc.stderr
    lines = dict(
        (key.strip(), value.strip())
        for key, _, value in (line.partition(":") for line in proc.stdout.splitlines())
        if _
    )
    assert int(lines["steps"]) <= 300
    assert int(lines["evaders_total"]) == 1
    assert lines["terminated"] in ("True", "False")
    # Matches the in-process result for the same seed.
    result = play_scripted_match(PRESET, seed=0, backend="kinematic", steps=300)
    assert int(lines["evaders_captured"]) == result["evaders_captured"]
    assert int(lines["steps"]) == result["steps"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--preset", "9-9-9"], "invalid choice"),
        (["--backend", "bullet"], "backend"),
        (["--steps", "0"], "steps"),
    ],
)
def test_demo_cli_rejects_bad_input(args, message):
    proc = run_cli("demo", *args)
    assert proc.returncode != 0
    assert message in proc.stderr
    assert "Traceback" not in proc.stderr
