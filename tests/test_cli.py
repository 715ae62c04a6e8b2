"""`pe-mjx` command line, run as a subprocess through the installed console script (SPEC 6)."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import tyro

CLI = Path(sys.executable).parent / "pe-mjx"


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    cmd = [str(CLI)] if CLI.exists() else [sys.executable, "-m", "pe_mjx.cli"]
    return subprocess.run(
        [*cmd, *args], cwd=cwd, capture_output=True, text=True, timeout=300, check=False
    )


def test_scene_writes_loadable_arena(tmp_path, get_compiled):
    (tmp_path / "tmp").mkdir()
    result = run_cli(
        "scene", "--preset", "4-1-2", "--seed", "3", "-o", "tmp/arena.xml", cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    out = tmp_path / "tmp" / "arena.xml"
    assert "wrote" in result.stdout
    model = mujoco.MjModel.from_xml_path(str(out))
    assert model.nq == 3 * 5 and model.nkey == 1
    c = get_compiled("4-1-2", "kinematic")  # shared with the contract and export tests
    state = c.batch_reset(jnp.stack([jax.random.key(3), jax.random.key(4)]))
    expected = np.concatenate(
        [np.asarray(state.world.pos[0]), np.asarray(state.world.yaw[0])[:, None]], axis=1
    ).reshape(-1)
    np.testing.assert_array_equal(model.qpos0, expected.astype(np.float64))
    assert sorted(p.name for p in out.parent.iterdir()) == ["arena.xml"]  # no temp file left

    # existing output without --force: refused, file untouched; with --force: rewritten
    out.write_text("precious")
    refused = run_cli("scene", "--preset", "2-1-1", "-o", str(out), cwd=tmp_path)
    assert refused.returncode != 0
    assert "exists" in refused.stderr and "--force" in refused.stderr
    assert out.read_text() == "precious"
    forced = run_cli("scene", "--preset", "2-1-1", "-o", str(out), "--force", cwd=tmp_path)
    assert forced.returncode == 0, forced.stderr
    assert mujoco.MjModel.from_xml_path(str(out)).nq == 3 * 3


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("scene", "--preset", "nope"), "invalid choice 'nope'"),
        (("scene", "--no-such-flag"), "--no-such-flag"),
        (("scene", "--seed", "abc"), "abc"),
        (("scene", "-o", "missing_dir/arena.xml"), "does not exist"),
        (("frobnicate",), "frobnicate"),
    ],
)
def test_bad_arguments_exit_nonzero(tmp_path, args, needle):
    result = run_cli(*args, cwd=tmp_path)
    assert result.returncode != 0
    assert needle in result.stderr + result.stdout
    assert "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (
            ["reproduce", "--skip-train", "--suffix", "-s1-3m"],
            "--suffix needs a value (-s1-3m reads as a flag; give it as --suffix=-s1-3m)",
        ),
        (["scene", "--preset"], "--preset needs a value"),
        (
            ["evaluate", "--trials", "--seed", "1"],
            "--trials needs a value (--seed reads as a flag; ",
        ),
    ],
)
def test_a_flag_without_its_value_says_how_to_give_one(argv, said, capsys):
    """argparse reads a word that starts with "-" as the next flag, so `--suffix -s1-3m` leaves
    --suffix without a value: the one line names the flag and the `--flag=value` form."""
    from pe_mjx import cli

    with pytest.raises(SystemExit) as exit_:
        cli.main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2
    assert err.startswith(f"pe-mjx: error: {said}") and err.count("\n") == 1, err


def test_output_is_a_directory(tmp_path):
    (tmp_path / "d").mkdir()
    result = run_cli("scene", "--preset", "2-1-1", "-o", "d", "--force", cwd=tmp_path)
    assert result.returncode != 0
    assert "directory" in result.stderr
    assert "Traceback" not in result.stderr
    assert (tmp_path / "d").is_dir()


def test_train_interrupted_keeps_its_checkpoint_even_with_sigint_ignored(tmp_path):
    """Ctrl-C stops `pe-mjx train` with a short message and exit 130, its last checkpoint intact,
    also when the shell started it with SIGINT ignored (a background job)."""
    import shlex
    import signal
    import time

    from pe_mjx.policy.store import read_meta

    out = tmp_path / "run"
    flags = "--preset 2-1-1 --backend kinematic --evader.policy scripted --env-steps 1000000"
    flags += " --ppo.num-envs 2 --ppo.unroll-length 4 --ppo.num-minibatches 1"
    flags += " --ppo.update-epochs 1 --pursuer.network.width 8 --pursuer.network.num-heads 2"
    flags += " --pursuer.network.hidden 16 --eval-every 0 --checkpoint-every 20"
    train = f"{shlex.quote(str(CLI))} train {flags} --out {shlex.quote(str(out))}"
    command = f"trap '' INT; exec {train}"
    log = tmp_path / "stderr.txt"
    with open(log, "w") as err:  # a file, not a pipe nobody drains
        proc = subprocess.Popen(
            ["sh", "-c", command], stdout=subprocess.DEVNULL, stderr=err, cwd=tmp_path
        )
    try:
        deadline = time.monotonic() + 600
        while not any((out / "checkpoints").glob("[0-9]*/commit_success.txt")):
            assert proc.poll() is None, log.read_text()[-2000:]
            assert time.monotonic() < deadline, "no checkpoint within 600 s"
            time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        try:
            code = proc.wait(timeout=120)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGUSR1)  # the CLI's faulthandler: every thread's stack
            time.sleep(3)
            code = None
        assert code == 130, log.read_text()[-8000:]
        assert "pe-mjx: interrupted" in log.read_text()
        assert read_meta(out)["iteration"] >= 20
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _help_texts(parser: argparse.ArgumentParser):
    """(flags, help text) of every argument of `parser` and its subparsers."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _help_texts(sub)
        elif action.dest != "help":
            yield "/".join(action.option_strings) or action.dest, str(action.help or "")


def test_main_in_process_leaves_the_signal_handlers_as_they_were(tmp_path, capsys):
    """`cli.main` installs its Ctrl-C handler (and its watchdogs) only while a command runs: a
    caller's own handlers (pytest's, a notebook's) are back afterwards."""
    import signal

    from pe_mjx import cli

    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    cli.main(["scene", "--preset", "2-1-1", "-o", str(tmp_path / "a.xml")])
    assert {s: signal.getsignal(s) for s in before} == before


def test_every_flag_of_every_subcommand_has_help_text(capsys):
    """tyro shows a field without a docstring as "(default: ...)" alone: no flag may do so."""
    from pe_mjx import cli

    commands = {
        "scene": cli.SceneArgs,
        "demo": cli.DemoArgs,
        "train": cli.TrainArgs,
        "view": cli.ViewArgs,
        "evaluate": cli.EvaluateArgs,
        "export": cli.ExportArgs,
        "plot": cli.PlotArgs,
        "reproduce": cli.ReproduceArgs,
        "ship": cli.ShipArgs,
        "rate": cli.RateArgs,
    }
    undocumented, counted = [], 0
    for name, cls in commands.items():
        with pytest.raises(SystemExit) as exit_:  # the real --help works too
            cli.main([name, "--help"])
        assert exit_.value.code == 0 and "usage: pe-mjx" in capsys.readouterr().out
        with warnings.catch_warnings():  # get_parser is deprecated, still tyro's argparse view
            warnings.simplefilter("ignore", DeprecationWarning)
            parser = tyro.extras.get_parser(cls)
        for flag, text in _help_texts(parser):
            counted += 1
            described = re.sub(r"\((default|required|fixed to)\b[^)]*\)", "", text).strip()
            if not described:
                undocumented.append(f"pe-mjx {name} {flag}")
    assert counted > 100  # every subcommand's flags were seen (train alone has > 60)
    assert not undocumented, f"flags without help text: {undocumented}"


def test_training_summary_names_the_scene_so_that_its_commands_run(tmp_path, capsys):
    """The commands printed after a run: a preset's scene by --preset, a scene of its own (here
    3 evaders at 24-6-12) by the run's config.json, and a frozen team by its policy."""
    from types import SimpleNamespace

    from pe_mjx.commands.train_summary import training_summary
    from pe_mjx.experiment import default_config

    state = SimpleNamespace(env_steps=64, iteration=1, teams={"evader": None})
    own = default_config("24-6-12").override(
        {"env.name": "24-3-12", "env.evader.num_agents": 3, "pursuer.policy": "mix-20-5-8"}
    )
    training_summary(tmp_path, state, own)
    said = capsys.readouterr().out
    assert f"--config {tmp_path}/config.json" in said and "--preset" not in said, said
    assert "--pursuers mix-20-5-8 scripted --evaders" in said, said
    training_summary(tmp_path, state, default_config("24-6-12"))
    said = capsys.readouterr().out
    assert "--preset 24-6-12 " in said and "pe-mjx view --preset 24-6-12" in said, said


@pytest.mark.parametrize("trails", [True, False])
def test_view_export_honours_the_options_of_the_live_view(tmp_path, monkeypatch, capsys, trails):
    """`view --export` plays the policies as the live view would (--deterministic: greedy) with
    its trail length and --trails, resolving each policy once; it checked --trail-length and
    then recorded 30-step trails of sampling policies whatever was asked."""
    from pe_mjx import cli
    from pe_mjx.viewer import live, replay

    played, recorded, resolved = {}, [], []
    real_run, real_resolve = live.LiveRun, live.resolve_policy

    def run(config, policies, *args):
        played.update(policies)
        return real_run(config, policies, *args)

    def resolve(spec, team, *args):
        resolved.append((spec, team))
        return real_resolve(spec, team, *args)

    def record(config, arenas, frames, stem, dt):
        recorded.extend(frames)
        return Path(f"{stem}.viser"), Path(f"{stem}.html")

    monkeypatch.setattr(live, "LiveRun", run)
    monkeypatch.setattr(live, "resolve_policy", resolve)
    monkeypatch.setattr(replay, "export_recording", record)
    argv = ["view", "--preset", "2-1-1", "--backend", "kinematic", "--pursuers", "mix-20-5-8"]
    argv += ["--deterministic", "--trail-length", "3", "--steps", "5", "--arenas", "2"]
    argv += ["--export", str(tmp_path / "rec"), "--trails" if trails else "--no-trails"]
    cli.main(argv)
    assert "wrote" in capsys.readouterr().out
    assert played["pursuer"].deterministic and played["pursuer"].learned
    assert resolved == [("mix-20-5-8", "pursuer"), ("scripted", "evader")]  # once each
    assert 2 <= len(recorded) <= 6
    for _, trail in recorded:
        if trails:
            assert trail.shape[:2] == (3, 2)  # [trail length, arenas, agents, 2]
        else:
            assert trail is None
