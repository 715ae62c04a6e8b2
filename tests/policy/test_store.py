"""pe_mjx/policy/store.py: reading a run's policies back, with one clear error for a missing,
mismatched or damaged policy (here a shipped one; tests/ppo/test_checkpoint.py covers the
trainer's own checkpoints, a truncated one among them)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import pe_mjx
from pe_mjx.policy.resolve import load_policy
from pe_mjx.policy.shipped import RETIRED, resolve_run, shipped_names
from pe_mjx.policy.store import CheckpointError
from tests.policy_copies import orbax_copy

SHIPPED = resolve_run("mix-20-5-8")
ROOT = Path(__file__).resolve().parents[2]


def test_missing_and_mismatched_checkpoints_give_clear_errors(tmp_path):
    with pytest.raises(CheckpointError, match="does not exist"):
        load_policy(tmp_path / "nowhere", team="pursuer")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CheckpointError, match="no checkpoints"):
        load_policy(tmp_path / "empty", team="pursuer")
    with pytest.raises(CheckpointError, match="unknown team"):
        load_policy(SHIPPED, team="referee")
    other = pe_mjx.get_preset("4-1-2")
    other = other.replace(
        pursuer=other.pursuer.__class__(**{**other.pursuer.__dict__, "num_speeds": 4})
    )
    with pytest.raises(CheckpointError, match="actions"):
        load_policy(SHIPPED, team="pursuer", env_config=other)


def test_a_truncated_array_is_named_in_one_line(tmp_path):
    """Orbax words a failed array read as the store's whole TensorStore spec; the error line
    names the array and what is wrong with its bytes instead."""
    run = orbax_copy("mix-20-5-8", tmp_path / "run")
    step = next(p for p in (run / "checkpoints").iterdir() if p.name.isdigit())
    data = [p for p in (step / "policy_evader").rglob("d/*") if p.is_file()]
    assert data
    for path in data:
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 3])
    with pytest.raises(CheckpointError) as raised:
        load_policy(run, team="evader")
    message = str(raised.value)
    assert "\n" not in message and "TensorStore(" not in message
    assert re.search(r'Error reading "\w[\w.]*/[\w.]+"', message), message  # an array's chunk


@pytest.mark.parametrize("name", sorted(RETIRED))
def test_a_retired_policy_is_one_line_on_what_to_play_instead(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no local run of that name
    assert name not in shipped_names()
    run, iteration = RETIRED[name]
    with pytest.raises(CheckpointError) as raised:
        load_policy(name, team="pursuer")
    message = str(raised.value)
    assert message.startswith(f"{name} no longer ships") and "\n" not in message
    assert f"play {name}-3m or {name}-10m" in message
    assert f"--config train/runs/{run}/config.json --stop-after {iteration} " in message
    assert (ROOT / "train" / "runs" / run / "config.json").is_file()
    for shipped in (f"{name}-3m", f"{name}-10m"):
        assert shipped in shipped_names()
