"""Checkpoints: exact resume, policies rebuilt from a path alone, clear errors, atomic saves."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import pe_mjx
from pe_mjx.experiment import ExperimentConfig
from pe_mjx.policy import store
from pe_mjx.policy.resolve import load_policy, resolve_policy
from pe_mjx.ppo import checkpoint
from pe_mjx.ppo.checkpoint import CheckpointError
from pe_mjx.ppo.curves import read_rows
from pe_mjx.ppo.run import resume_config, train
from tests.tiny_config import tiny

CONFIG = tiny()


def _max_diff(a, b) -> float:
    diffs = jax.tree.map(lambda x, y: float(jnp.max(jnp.abs(x - y))), a, b)
    return max(jax.tree.leaves(diffs))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """One run straight through (4 iterations) and one stopped after 2 and resumed."""
    root = tmp_path_factory.mktemp("runs")
    _, straight = train(CONFIG, root / "straight", progress=False)
    train(CONFIG, root / "split", progress=False, stop_after=2)
    _, resumed = train(resume_config(root / "split"), root / "split", resume=True, progress=False)
    return root, straight, resumed


def test_resume_matches_an_unstopped_run(runs):
    _, straight, resumed = runs
    assert int(resumed.iteration) == int(straight.iteration) == 4
    for team in ("pursuer", "evader"):
        assert _max_diff(straight.teams[team].params, resumed.teams[team].params) == 0.0
        assert _max_diff(straight.teams[team].opt_state, resumed.teams[team].opt_state) == 0.0
    assert _max_diff(straight.env_state.world.pos, resumed.env_state.world.pos) == 0.0


def test_run_directory_has_config_logs_and_checkpoints(runs):
    root, _, _ = runs
    run = root / "straight"
    assert (run / "config.json").is_file()
    assert any((run / "tb").iterdir())
    meta = store.read_meta(run)
    assert meta["iteration"] == 4 and meta["env_steps"] == 4 * 64
    assert set(meta["network_configs"]) == {"pursuer", "evader"}


def test_load_policy_plays_in_the_env(runs):
    root, straight, _ = runs
    env = pe_mjx.make("4-1-2", backend="kinematic")
    policies = {t: load_policy(root / "straight", team=t) for t in ("pursuer", "evader")}
    state = jax.jit(env.reset)(jax.random.key(0))

    @jax.jit
    def play(state, rng):
        keys = jax.random.split(rng, 2)
        actions = {t: policies[t](state.obs[t], k) for t, k in zip(policies, keys, strict=True)}
        return env.step(state, actions), actions

    for i in range(5):
        new, actions = play(state, jax.random.key(i))
        for team in ("pursuer", "evader"):
            a = np.asarray(actions[team])
            assert a.shape == (env.config.team(team).num_agents,)
            assert np.asarray(state.obs[team]["action_mask"])[np.arange(len(a)), a].all()
        state = new
    # The restored parameters are those of the run.
    restored = store.restore_policy_params(root / "straight", "pursuer").variables
    assert _max_diff(restored["params"], straight.teams["pursuer"].params) == 0.0
    # Same policy object runs unchanged at another scale (MIX is count-independent).
    big = pe_mjx.make("8-2-4", backend="kinematic")
    obs = jax.jit(big.reset)(jax.random.key(1)).obs["pursuer"]
    assert policies["pursuer"](obs, jax.random.key(0)).shape == (8,)


def test_interrupted_save_leaves_the_previous_checkpoint_loadable(runs, tmp_path):
    """A save killed midway leaves only orbax's temporary directory, which loading ignores."""
    root, _, _ = runs
    run = tmp_path / "interrupted"
    shutil.copytree(root / "straight", run)
    partial = run / "checkpoints" / "6.orbax-checkpoint-tmp-1234"
    (partial / "policy_evader").mkdir(parents=True)
    (partial / "policy_evader" / "garbage").write_bytes(b"\x00" * 10)
    assert store.read_meta(run)["iteration"] == 4
    load_policy(run, team="evader")


def test_kill_during_save_keeps_previous_checkpoint(tmp_path):
    """Kill a real training process while it saves; the run stays loadable."""
    script = (
        "import sys\n"
        "from pe_mjx.experiment import ExperimentConfig\n"
        "from pe_mjx.ppo.run import train\n"
        "from pe_mjx.ppo import checkpoint\n"
        "orig = checkpoint.save\n"
        "count = [0]\n"
        "def save(run_dir, trainer, state):\n"
        "    count[0] += 1\n"
        "    if count[0] == 2:\n"
        "        import os, threading\n"
        "        threading.Timer(0.05, lambda: os._exit(9)).start()\n"
        "    return orig(run_dir, trainer, state)\n"
        "import pe_mjx.ppo.run as run_mod\n"
        "run_mod.checkpoint.save = save\n"
        f"cfg = ExperimentConfig.from_dict({CONFIG.to_dict()!r})\n"
        "train(cfg, sys.argv[1], progress=False)\n"
    )
    out = tmp_path / "killed"
    result = subprocess.run(
        [sys.executable, "-c", script, str(out)], capture_output=True, timeout=900
    )
    assert result.returncode != 0
    meta = store.read_meta(out)
    assert meta["iteration"] in (2, 4)
    load_policy(out, team="pursuer")


def test_cli_train_runs_logs_checkpoints_and_resumes(tmp_path):
    out = tmp_path / "cli-run"
    exe = [sys.executable, "-m", "pe_mjx.cli", "train"]
    flags = [
        "--preset",
        "4-1-2",
        "--backend",
        "kinematic",
        "--evader.policy",
        "scripted",
        "--pursuer.network.encoder",
        "mean",
        "--ppo.num-envs",
        "8",
        "--ppo.unroll-length",
        "8",
        "--env-steps",
        "256",
        "--eval-every",
        "2",
        "--eval-envs",
        "4",
        "--checkpoint-every",
        "1",
        "--pursuer.network.width",
        "16",
        "--pursuer.network.hidden",
        "32",
        "--no-progress",
        "--out",
        str(out),
    ]
    first = subprocess.run(
        [*exe, *flags, "--stop-after", "2"], capture_output=True, text=True, timeout=900
    )
    assert first.returncode == 0, first.stderr[-3000:]
    assert store.read_meta(out)["iteration"] == 2
    saved = json.loads((out / "config.json").read_text())
    assert saved["experiment"]["pursuer"]["network"]["encoder"] == "mean"
    assert saved["code_version"]["pe_mjx"]
    # A resume that would change the game is refused, and nothing is written.
    refused = subprocess.run(
        [*exe, "--resume", str(out), "--env.reward.capture", "50"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert refused.returncode == 2
    assert "cannot change env.reward.capture" in refused.stderr
    assert "Traceback" not in refused.stderr
    assert store.read_meta(out)["iteration"] == 2
    assert json.loads((out / "config.json").read_text()) == saved
    # The same run can be reproduced from its config file alone.
    from pe_mjx.experiment import read_config_file

    assert read_config_file(out / "config.json") == ExperimentConfig.from_dict(saved["experiment"])
    again = subprocess.run(
        [*exe, "--resume", str(out), "--no-progress"], capture_output=True, text=True, timeout=900
    )
    assert again.returncode == 0, again.stderr[-3000:]
    assert store.read_meta(out)["iteration"] == 4
    assert "env steps" in again.stdout
    # config.json keeps every start of the run with the code it ran.
    starts = json.loads((out / "config.json").read_text())["starts"]
    assert [s["iteration"] for s in starts] == [0, 2]
    assert all(s["code_version"]["pe_mjx"] for s in starts)
    # Starting a new run over an existing one is refused; nothing is overwritten.
    clash = subprocess.run([*exe, *flags], capture_output=True, text=True, timeout=900)
    assert clash.returncode != 0 and "already holds a run" in clash.stderr
    missing = subprocess.run(
        [*exe, "--resume", str(tmp_path / "nope")], capture_output=True, text=True, timeout=300
    )
    assert missing.returncode != 0 and "does not exist" in missing.stderr
    assert "Traceback" not in missing.stderr
    # Team mismatch: this run learned only the pursuer.
    with pytest.raises(ValueError, match=r"did not learn an? evader"):
        resolve_policy(str(out), "evader", pe_mjx.get_preset("4-1-2"))
    bad = subprocess.run(
        [
            sys.executable,
            "-m",
            "pe_mjx.cli",
            "evaluate",
            "--pursuers",
            "scripted",
            "--evaders",
            str(out),
            "--preset",
            "4-1-2",
            "--trials",
            "2",
            "--out",
            str(tmp_path / "ev"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert bad.returncode != 0 and "did not learn" in bad.stderr
    events = list((out / "tb").iterdir())
    assert events, "no TensorBoard event files"
    assert Path(out / "config.json").is_file()


def test_a_team_can_be_frozen_at_a_checkpoint(runs):
    """--evader <run>: the evader plays the run's policy, unchanged, while the pursuer learns."""
    from pe_mjx.ppo.train import Trainer

    root, _, _ = runs
    from pe_mjx.ppo.run import resolve_opponents

    config = CONFIG.override({"evader.policy": str(root / "straight")})
    trainer = Trainer(config, opponents=resolve_opponents(config))
    assert trainer.learned == ("pursuer",)
    state = trainer.init()
    new, metrics = jax.jit(trainer.iteration)(state)
    assert "evader" not in new.teams and "loss/pursuer/entropy" in metrics
    # The frozen policy acts like the checkpoint's evader policy.
    obs = jax.tree.map(lambda x: x[0], state.env_state.obs["evader"])
    key = jax.random.key(5)
    frozen = trainer.fixed["evader"](obs, key)
    direct = load_policy(root / "straight", team="evader")(obs, key)
    np.testing.assert_array_equal(np.asarray(frozen), np.asarray(direct))


def test_non_finite_parameters_stop_the_run_and_keep_the_last_good_checkpoint(
    tmp_path, monkeypatch
):
    """A NaN in the parameters at iteration 3 stops the run before anything non-finite is saved;
    checkpoint 2 stays the latest. The directory held only an unfinished first save (a kill
    during it), which a fresh run may reuse."""
    from pe_mjx.ppo import run as run_mod

    out = tmp_path / "diverged"
    (out / "checkpoints" / "2.orbax-checkpoint-tmp-1").mkdir(parents=True)
    calls = []

    def finite(teams):
        calls.append(1)
        return len(calls) < 3

    monkeypatch.setattr(run_mod, "_params_finite", finite)
    with pytest.raises(run_mod.TrainingError, match=r"iteration 3.*last good checkpoint \(iter"):
        train(CONFIG, out, progress=False)
    assert store.read_meta(out)["iteration"] == 2
    assert not (out / "checkpoints" / "4").exists()
    with checkpoint.lock_run(out):  # released when train() ended
        pass


def test_loaders_refuse_non_finite_parameters(runs, tmp_path):
    from pe_mjx.ppo.train import Trainer

    root, _, _ = runs
    run = tmp_path / "nan"
    shutil.copytree(root / "straight", run)
    trainer = Trainer(CONFIG)
    state = checkpoint.restore_train_state(run, trainer)
    teams = dict(state.teams)
    teams["pursuer"] = teams["pursuer"].replace(
        params=jax.tree.map(lambda x: x * jnp.nan, teams["pursuer"].params)
    )
    checkpoint.save(run, trainer, state.replace(teams=teams, iteration=state.iteration + 1))
    with pytest.raises(CheckpointError, match="non-finite"):
        load_policy(run, team="pursuer")
    load_policy(run, team="evader")
    assert store.all_finite({"a": np.ones(3), "b": np.arange(2)})
    assert not store.all_finite({"a": np.array([1.0, np.inf])})


def test_a_locked_run_directory_refuses_a_second_trainer(tmp_path):
    out = tmp_path / "busy"
    out.mkdir()
    with checkpoint.lock_run(out):
        with pytest.raises(CheckpointError, match="in use by another pe-mjx train"):
            train(CONFIG, out, progress=False)
        with pytest.raises(CheckpointError, match="in use"), checkpoint.lock_run(out):
            pass
    assert not (out / "checkpoints").exists()


def test_an_unwritable_checkpoint_directory_fails_fast(runs, tmp_path):
    """The save probes the directory before orbax starts (orbax's threads hang when a save
    fails midway): a clear CheckpointWriteError within seconds."""
    import os
    import time

    from pe_mjx.ppo.train import Trainer

    root, _, _ = runs
    run = tmp_path / "readonly"
    shutil.copytree(root / "straight", run)
    trainer = Trainer(CONFIG)
    state = checkpoint.restore_train_state(run, trainer)
    ckpt = run / "checkpoints"
    if os.geteuid() == 0:  # root ignores permissions: a file where the directory was
        shutil.rmtree(ckpt)
        ckpt.write_text("the disk went away")
    else:
        ckpt.chmod(0o500)
    try:
        tic = time.monotonic()
        with pytest.raises(checkpoint.CheckpointWriteError, match="cannot write checkpoint 5"):
            checkpoint.save(run, trainer, state.replace(iteration=state.iteration + 1))
        assert time.monotonic() - tic < 10
    finally:
        if ckpt.is_dir():
            ckpt.chmod(0o700)


def test_a_run_saved_by_a_version_with_another_arena_state_resumes_its_learners(
    runs, monkeypatch, capsys
):
    """An env metric added since the save changes the arena state's structure: the learners,
    the RNG and the counters still come back exactly, the arenas are drawn afresh, with a
    warning."""
    from pe_mjx.ppo.train import Trainer
    from pe_mjx.stages import metrics

    root, straight, _ = runs
    plain = metrics.step_metrics

    def more_metrics(*args, **kwargs):
        return {**plain(*args, **kwargs), "new_metric": jnp.zeros(())}

    monkeypatch.setattr(metrics, "step_metrics", more_metrics)
    trainer = Trainer(CONFIG)
    state = checkpoint.restore_train_state(root / "straight", trainer)
    assert "another pe-mjx version" in capsys.readouterr().err
    assert "new_metric" in state.env_state.metrics
    assert int(state.iteration) == int(straight.iteration)
    assert int(state.env_steps) == int(straight.env_steps)
    for team in ("pursuer", "evader"):
        assert _max_diff(straight.teams[team].params, state.teams[team].params) == 0.0
        assert _max_diff(straight.teams[team].opt_state, state.teams[team].opt_state) == 0.0
    new, _ = jax.jit(trainer.iteration)(state)
    assert int(new.iteration) == int(straight.iteration) + 1


def test_a_learned_team_can_start_from_a_trained_policy_in_another_scene(runs):
    """--evader.init <run>: the evader starts from the run's evader parameters and observation
    statistics, with a fresh optimiser, in a scene with other counts (a MIX network reads any);
    the pursuer, with no init, starts from fresh random parameters."""
    from pe_mjx.ppo.run import initial_variables, warm_start
    from pe_mjx.ppo.train import Trainer

    root, straight, _ = runs
    source = store.restore_policy_params(root / "straight", "evader").variables
    config = tiny("4-2-2", **{"evader.init": str(root / "straight")})
    trainer = Trainer(config)
    fresh = trainer.init()
    state = warm_start(trainer, fresh, initial_variables(trainer))
    assert _max_diff(state.teams["evader"].params, source["params"]) == 0.0
    assert _max_diff(state.teams["evader"].normalizer, source["normalizer"]) == 0.0
    assert _max_diff(state.teams["evader"].params, fresh.teams["evader"].params) > 0.0
    adam = state.teams["evader"].opt_state[1][0]  # (clip, adam) -> adam's (state, ...)
    assert int(adam.count) == 0 and _max_diff(adam.mu, jax.tree.map(jnp.zeros_like, adam.mu)) == 0
    assert _max_diff(state.teams["pursuer"].params, fresh.teams["pursuer"].params) == 0.0
    assert _max_diff(state.teams["pursuer"].params, straight.teams["pursuer"].params) > 0.0


def test_a_run_started_from_a_policy_trains_on_from_it_and_records_where_from(runs, tmp_path):
    """Through `train`: one iteration later the evader is still near its starting policy (one
    update away, far nearer than a fresh start is), and config.json records the init."""
    from pe_mjx.ppo.train import Trainer

    root, _, _ = runs
    config = CONFIG.override({"evader.init": str(root / "straight"), "seed": 3})
    _, state = train(config, tmp_path / "tuned", progress=False, stop_after=1)
    assert int(state.iteration) == 1
    saved = json.loads((tmp_path / "tuned" / "config.json").read_text())
    assert saved["experiment"]["evader"]["init"] == str(root / "straight")
    source = store.restore_policy_params(root / "straight", "evader").variables["params"]
    moved = _max_diff(state.teams["evader"].params, source)
    unstarted = Trainer(config.override({"evader.init": None})).init()
    fresh = _max_diff(unstarted.teams["evader"].params, source)
    assert 0.0 < moved < 0.1 * fresh, (moved, fresh)


def test_a_policy_that_does_not_fit_the_network_is_refused_before_the_run_starts(runs, tmp_path):
    root, _, _ = runs
    config = CONFIG.override({"evader.init": str(root / "straight"), "evader.network.width": 8})
    with pytest.raises(CheckpointError, match=r"^--evader\.init: .*does not fit .* it .*float32"):
        train(config, tmp_path / "misfit", progress=False)
    assert not (tmp_path / "misfit").exists()


def _truncate_data(item: Path) -> None:
    """Cuts every data file of an orbax item in half (a bad copy, a disk that filled up).

    Every file, not the largest: `ocdbt.process_0/d` also holds the per-process B-tree nodes,
    which a restore never reads once they are merged into the item's own manifest, and under
    load one of them can be the largest file there (CI, 2026-12-05). (Not any file of the item
    either: orbax does not read `_sharding` back, for one.)"""
    for data in (item / "ocdbt.process_0" / "d").iterdir():
        data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])


def test_a_damaged_latest_checkpoint_names_the_intact_one_and_can_fall_back(runs, tmp_path, capsys):
    """Checkpoint 4's train state damaged: one line naming checkpoint 2; with fallback=True the
    run resumes from 2, checkpoint 4 kept under damaged-checkpoints/."""
    from pe_mjx.ppo.train import Trainer

    root, _, _ = runs
    run = tmp_path / "damaged"
    shutil.copytree(root / "straight", run)
    _truncate_data(run / "checkpoints" / "4" / "train")
    trainer = Trainer(CONFIG)
    with pytest.raises(store.DamagedCheckpointError) as caught:
        checkpoint.restore_train_state(run, trainer)
    message = str(caught.value)
    assert "\n" not in message and len(message) < 1000, message
    assert message.startswith(f"checkpoint 4 in {run} cannot be restored"), message
    assert "checkpoint 2 is the latest intact one" in message and "--resume-intact" in message
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["2", "4"]  # nothing moved
    capsys.readouterr()
    state = checkpoint.restore_train_state(run, trainer, fallback=True)
    assert int(state.iteration) == 2
    warning = capsys.readouterr().err.strip().splitlines()
    assert len(warning) == 1 and warning[0].startswith("pe-mjx: warning: checkpoint 4"), warning
    assert "resuming from checkpoint 2" in warning[0]
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["2"]
    assert (run / "damaged-checkpoints" / "4" / "train").is_dir()
    assert store.read_meta(run)["iteration"] == 2
    restored = store.restore_policy_params(run, "pursuer").variables["params"]
    assert _max_diff(state.teams["pursuer"].params, restored) == 0.0
    # Every checkpoint damaged: said so, and nothing moves.
    both = tmp_path / "both-damaged"
    shutil.copytree(root / "straight", both)
    for step in ("2", "4"):
        _truncate_data(both / "checkpoints" / step / "train")
    with pytest.raises(store.DamagedCheckpointError, match=r"no earlier checkpoint of .* either"):
        checkpoint.restore_train_state(both, trainer, fallback=True)
    assert sorted(p.name for p in (both / "checkpoints").iterdir()) == ["2", "4"]


def test_a_damaged_latest_policy_or_metadata_names_the_intact_one(runs, tmp_path, capsys):
    root, _, _ = runs
    run = tmp_path / "policy-damaged"
    shutil.copytree(root / "straight", run)
    _truncate_data(run / "checkpoints" / "4" / "policy_pursuer")
    with pytest.raises(store.DamagedCheckpointError, match="checkpoint 2 is the latest intact"):
        load_policy(run, team="pursuer")
    capsys.readouterr()
    policy = load_policy(run, team="pursuer", fallback=True)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "playing checkpoint 2 instead" in err[0], err
    assert policy.variables is not None
    assert (run / "checkpoints" / "4").is_dir()  # reading a policy moves nothing
    load_policy(run, team="evader")  # its item at checkpoint 4 is intact
    # Damaged metadata: the same, for every reader of it; resume_intact sets it aside.
    meta = run / "checkpoints" / "4" / "meta" / "metadata"
    meta.write_bytes(meta.read_bytes()[:50])
    with pytest.raises(store.DamagedCheckpointError) as caught:
        store.read_meta(run)
    assert str(caught.value).startswith(f"checkpoint 4 in {run} is unreadable")
    assert "checkpoint 2 is the latest intact one" in str(caught.value)
    assert store.read_meta(run, fallback=True)["iteration"] == 2
    assert checkpoint.resume_intact(run) == 2
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["2"]
    assert (run / "damaged-checkpoints" / "4" / "meta").is_dir()
    # The only checkpoint left damaged too: its own error, and nothing moves.
    _truncate_data(run / "checkpoints" / "2" / "train")
    with pytest.raises(store.DamagedCheckpointError, match=f"^checkpoint 2 in {run} cannot be"):
        checkpoint.resume_intact(run)
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["2"]


def test_cli_resume_of_a_damaged_run_is_one_line_then_resumes_from_the_intact_one(runs, tmp_path):
    root, _, _ = runs
    run = tmp_path / "cli-damaged"
    shutil.copytree(root / "straight", run)
    _truncate_data(run / "checkpoints" / "4" / "train")
    before = sorted(str(p) for p in run.rglob("*"))
    exe = [sys.executable, "-m", "pe_mjx.cli", "train", "--resume", str(run), "--no-progress"]
    refused = subprocess.run(exe, capture_output=True, text=True, timeout=600)
    assert refused.returncode == 2, refused.stderr[-2000:]
    lines = refused.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pe-mjx: error: "), refused.stderr[-3000:]
    assert "checkpoint 2 is the latest intact one" in lines[0] and "Traceback" not in lines[0]
    assert sorted(str(p) for p in run.rglob("*")) == before  # nothing written, nothing moved
    resumed = subprocess.run([*exe, "--resume-intact"], capture_output=True, text=True, timeout=900)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert "Traceback" not in resumed.stderr
    warnings = [x for x in resumed.stderr.splitlines() if x.startswith("pe-mjx: warning:")]
    assert len(warnings) == 1 and "resuming from checkpoint 2" in warnings[0], resumed.stderr
    assert store.read_meta(run)["iteration"] == 4  # trained on from 2 to 4
    assert (run / "damaged-checkpoints" / "4").is_dir()
    starts = json.loads((run / "config.json").read_text())["starts"]
    assert [s["iteration"] for s in starts][-1] == 2


def test_truncated_checkpoint_gives_a_clear_error(runs, tmp_path):
    root, _, _ = runs
    broken = tmp_path / "broken"
    shutil.copytree(root / "straight", broken)
    step_dir = broken / "checkpoints" / "4"
    # Truncate every data file of the policy item.
    for f in (step_dir / "policy_pursuer").rglob("*"):
        if f.is_file() and f.stat().st_size > 0:
            f.write_bytes(f.read_bytes()[: f.stat().st_size // 3])
    with pytest.raises(CheckpointError, match=r"cannot be restored|unreadable"):
        load_policy(broken, team="pursuer")


def _bytes(directory: Path) -> int:
    return sum(f.stat().st_size for f in directory.rglob("*") if f.is_file())


def test_a_resumable_copy_keeps_the_learners_and_the_run_goes_on_from_it(runs, tmp_path, capsys):
    """`pe-mjx ship RUN NAME --dest D --resumable`: the run's config, curves and checkpoint 2's
    learners, RNG and counters (no arenas, no policy items); `--resume` restores those exactly,
    with one warning line, draws fresh arenas and trains on to the budget."""
    from pe_mjx.cli import main
    from pe_mjx.ppo.train import Trainer

    root, _, _ = runs
    split = root / "split"
    main(["ship", str(split), "split-copy", "--dest", str(tmp_path), "--resumable", "--step", "2"])
    copy = tmp_path / "split-copy"
    assert "continue it with `pe-mjx train --resume" in capsys.readouterr().out
    assert sorted(p.name for p in copy.iterdir()) == ["checkpoints", "config.json", "curves.csv.xz"]
    assert [p.name for p in (copy / "checkpoints").iterdir()] == ["2"]
    step = copy / "checkpoints" / "2"
    assert sorted(p.name for p in step.iterdir() if p.is_dir()) == ["meta", "train"]
    assert _bytes(step) < 0.6 * _bytes(split / "checkpoints" / "2")
    # The learners, RNG and counters exactly as checkpoint 2 of the run had them.
    trainer = Trainer(CONFIG)
    abstract = jax.eval_shape(checkpoint.keys_to_data, trainer.abstract_state())
    source = checkpoint._restore_step(split, 2, trainer, abstract)
    state = checkpoint.restore_train_state(copy, trainer)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is a resumable copy without arenas" in err[0], err
    for team in ("pursuer", "evader"):
        assert _max_diff(source.teams[team], state.teams[team]) == 0.0
    assert np.array_equal(source.rng, jax.random.key_data(state.rng))
    assert int(state.iteration) == 2 and int(state.env_steps) == 2 * 64
    # Its policies are not there to play: one line saying what it is.
    with pytest.raises(CheckpointError, match="is a resumable copy"):
        load_policy(copy, team="pursuer")
    # The run goes on from the copy to its budget; the curves' rows after iteration 2 (the run
    # had gone on to 4 before it was copied) are those of the resumed run.
    before = read_rows(copy / "curves.csv.xz")
    _, done = train(resume_config(copy), copy, resume=True, progress=False)
    assert int(done.iteration) == 4
    after = read_rows(copy / "curves.csv.xz")
    assert [r["env_steps"] for r in after] == [64, 128, 192, 256]
    assert after[1] == before[1] and after[-1]["wall_time"] > before[-1]["wall_time"]
    load_policy(copy, team="pursuer")  # its own new checkpoint plays
    # Refused in one line each: no --dest, an existing copy without --replace.
    for argv, message in (
        (["ship", str(split), "c"], "--resumable needs --dest"),
        (["ship", str(split), "split-copy", "--dest", str(tmp_path)], "exists (--replace"),
        (["ship", str(split), root.name, "--dest", str(root.parent), "--replace"], "holds the run"),
        (["ship", str(split), "x", "--dest", str(split / "checkpoints")], "lies inside it"),
    ):
        with pytest.raises(SystemExit):
            main([*argv, "--resumable"])
        assert message in capsys.readouterr().err
    assert sorted(p.name for p in (split / "checkpoints").iterdir()) == ["2", "4"]
