"""Evaluation: metrics on hand-built episodes, the paper's numbers, determinism, the CLI."""

from __future__ import annotations

import json
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import pe_mjx
from pe_mjx import evaluate as ev
from pe_mjx import trajectory
from pe_mjx.names import CAPTURE, OBSTACLE, TEAMMATE, WALL


def test_paper_row_per_evader_cost():
    """Table II, E_BiRNN vs P_MLP: pursuit cost 7.05 at success 0.565 with 4 evaders -> 3.119."""
    trials = 100
    # m' and n' per trial whose means are 7.05 and 0.565 * 4 = 2.26.
    m = np.array([7.0] * 95 + [8.0] * 5)
    n = np.array([2.0] * 74 + [3.0] * 26)
    assert m.mean() == pytest.approx(7.05) and n.mean() == pytest.approx(2.26)
    ratio, low, high = ev.ratio_ci(m, n)
    assert ratio == pytest.approx(7.05 / 2.26)
    assert round(ratio, 3) == 3.119
    assert low <= ratio <= high
    summary = ev.summarize(
        {
            "success_rate": n / 4,
            "travel_distance": np.full(trials, 19.805),
            "pursuit_cost": m,
            "evaders_incapacitated": n,
            "length": np.full(trials, 1000.0),
        }
    )
    assert summary["success_rate"] == pytest.approx(0.565)
    assert summary["pursuit_cost"] == pytest.approx(7.05)
    assert round(summary["per_evader_cost"], 3) == 3.119
    assert summary["travel_distance_ci95"] == pytest.approx(0.0)


def test_mean_ci_matches_student_t():
    x = np.array([1.0, 2.0, 3.0, 4.0])
    mean, half = ev.mean_ci(x)
    assert mean == 2.5
    # t_{0.975, 3} = 3.182446; sd = 1.290994; n = 4.
    assert half == pytest.approx(3.182446 * 1.290994 / 2, rel=1e-5)


def test_ratio_ci_with_no_captures_is_infinite_not_nan():
    ratio, low, high = ev.ratio_ci(np.array([1.0, 2.0, 0.0]), np.zeros(3))
    assert ratio == np.inf and high == np.inf and not np.isnan(low)


def test_trial_metrics_on_a_hand_built_episode():
    env = pe_mjx.make("4-1-2", backend="kinematic")
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 2))
    w = state.world
    # Trial 0: evader captured, pursuer 0 captured it, pursuer 1 hit the wall; distances known.
    # Trial 1: nothing incapacitated except pursuer 3 on an obstacle and pursuer 2 by a teammate.
    active = np.ones((2, 5), bool)
    cause = np.zeros((2, 5), np.int32)
    active[0, [0, 1, 4]] = False
    cause[0, [0, 4]] = CAPTURE
    cause[0, 1] = WALL
    active[1, [2, 3]] = False
    cause[1, 2], cause[1, 3] = TEAMMATE, OBSTACLE
    distance = np.array([[1.0, 2.0, 3.0, 4.0, 9.0], [0.5, 0.5, 0.5, 0.5, 7.0]])
    world = w.replace(
        active=jnp.asarray(active),
        cause=jnp.asarray(cause),
        distance=jnp.asarray(distance),
        step=jnp.asarray([120, 1000], jnp.int32),
    )
    out = ev.trial_metrics(env, state.replace(world=world))
    np.testing.assert_allclose(out["success_rate"], [1.0, 0.0])
    np.testing.assert_allclose(out["travel_distance"], [2.5, 0.5])
    np.testing.assert_allclose(out["pursuit_cost"], [2.0, 2.0])
    np.testing.assert_allclose(out["length"], [120, 1000])
    np.testing.assert_allclose(out["pursuers_capture"], [1, 0])
    np.testing.assert_allclose(out["pursuers_wall"], [1, 0])
    np.testing.assert_allclose(out["pursuers_teammate"], [0, 1])
    np.testing.assert_allclose(out["pursuers_obstacle"], [0, 1])
    np.testing.assert_allclose(out["evaders_capture"], [1, 0])
    summary = ev.summarize(out)
    assert summary["per_evader_cost"] == pytest.approx(2.0 / 0.5)


def test_small_matrix_is_deterministic_and_writes_every_report(tmp_path):
    kwargs = dict(
        pursuers=["scripted", "random"],
        evaders=["scripted"],
        preset="4-1-2",
        trials=6,
        seed=3,
        backend="kinematic",
        log=lambda *_: None,
    )
    first = ev.evaluate(out=tmp_path / "a", record=2, **kwargs)
    second = ev.evaluate(out=tmp_path / "b", record=0, **kwargs)
    for r1, r2 in zip(first["results"], second["results"], strict=True):
        for key in r1.trials:
            np.testing.assert_array_equal(r1.trials[key], r2.trials[key])
    paths = first["paths"]
    table = paths["markdown"].read_text()
    assert "| E_scripted | P_scripted |" in table and "Per-Evader Cost" in table
    data = json.loads(paths["json"].read_text())
    assert len(data["pairings"]) == 2 and len(data["pairings"][0]["trials"]["success_rate"]) == 6
    assert data["meta"]["seed"] == 3
    assert len(paths["trials"].read_text().strip().splitlines()) == 1 + 2 * 6
    for key in ("success_rate_heatmap", "per_evader_cost_heatmap"):
        assert paths[key].stat().st_size > 1000
    # Trajectories: the recorded trials replay exactly the evaluated ones.
    rec = trajectory.load(tmp_path / "a" / "trajectories" / "pairing-0.npz")
    assert rec.num_arenas == 2
    final_active = rec.active[-1]
    n_p = 4
    success = (~final_active[:, n_p:]).mean(axis=1)
    np.testing.assert_allclose(success, first["results"][0].trials["success_rate"][:2])


def test_adding_a_policy_keeps_the_pairings_already_played(tmp_path):
    # An evaluation extended with a policy plays only its pairings, after replaying one kept
    # pairing identically; the result equals playing the whole matrix anew.
    kwargs = dict(preset="4-1-2", trials=6, seed=3, backend="kinematic", record=2)
    out = tmp_path / "table"
    ev.evaluate(["scripted", "random"], ["scripted"], out=out, log=lambda *_: None, **kwargs)
    first_recording = (out / "trajectories" / "pairing-1.npz").read_bytes()
    said = []
    both = ["scripted", "random"]
    extended = ev.evaluate(both, both, out=out, log=said.append, keep=out, **kwargs)
    fresh = ev.evaluate(both, both, out=tmp_path / "fresh", log=lambda *_: None, **kwargs)
    # (scripted, scripted) was replayed as the check, (random, scripted) kept, the rest played.
    assert [r.kept for r in extended["results"]] == [False, True, False, False]
    assert any("replays" in line and "kept" in line for line in said)
    for r1, r2 in zip(extended["results"], fresh["results"], strict=True):
        assert r1.summary == r2.summary
        for key in r2.trials:
            np.testing.assert_array_equal(r1.trials[key], r2.trials[key])
    data = json.loads((out / "results.json").read_text())
    assert data["meta"]["kept"] == [1] and data["meta"]["record"] == 2
    assert [p["kept"] for p in data["pairings"]] == [False, True, False, False]
    assert (out / "trials.csv").read_text() == (tmp_path / "fresh" / "trials.csv").read_text()
    # The kept pairing's recording is the earlier one (same index here).
    assert (out / "trajectories" / "pairing-1.npz").read_bytes() == first_recording
    assert len(list((out / "trajectories").glob("*.npz"))) == 4

    # A distance that differs by float32 rounding alone (summed in another order) is the same
    # game; a length one step off is not, and then nothing is kept.
    travel = data["pairings"][0]["trials"]["travel_distance"]
    travel[0] = float(np.nextafter(np.float32(travel[0]), np.float32(np.inf)))
    (out / "results.json").write_text(json.dumps(data))
    again = ev.evaluate(both, both, out=out, log=lambda *_: None, keep=out, **kwargs)
    assert [r.kept for r in again["results"]] == [False, True, True, True]
    data = json.loads((out / "results.json").read_text())
    # One written before a reward field existed (at its default, the same game) is kept too.
    del data["meta"]["env_config"]["reward"]["pursuit_nearest"]
    (out / "results.json").write_text(json.dumps(data))
    again = ev.evaluate(both, both, out=out, log=lambda *_: None, keep=out, **kwargs)
    assert [r.kept for r in again["results"]] == [False, True, True, True]
    data = json.loads((out / "results.json").read_text())
    data["pairings"][0]["trials"]["length"][0] += 1
    (out / "results.json").write_text(json.dumps(data))
    said.clear()
    again = ev.evaluate(both, both, out=out, log=said.append, keep=out, **kwargs)
    assert not any(r.kept for r in again["results"])
    assert any("every pairing is played" in line for line in said)
    # Nor does one of another scene, seed or trial count.
    said.clear()
    other = {**kwargs, "seed": 4}
    again = ev.evaluate(both, ["scripted"], out=out, log=said.append, keep=out, **other)
    assert not any(r.kept for r in again["results"])
    assert any("another scene, trial count, seed or backend" in line for line in said)


def _cli(*args, timeout=900):
    return subprocess.run(
        [sys.executable, "-m", "pe_mjx.cli", "evaluate", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_cli_end_to_end_and_bad_inputs(tmp_path):
    """Also a scene of the user's: a config file over the preset, then a flag over the file."""
    out = tmp_path / "cli"
    scene = tmp_path / "scene.yaml"
    scene.write_text("name: 2-1-1\narena: {radius: 3.0}\npursuer: {num_agents: 4}\n")
    ok = _cli(
        "--pursuers",
        "scripted",
        "--evaders",
        "random",
        "--config",
        str(scene),
        "--env.pursuer.num-agents",
        "3",
        "--trials",
        "4",
        "--backend",
        "kinematic",
        "--record",
        "1",
        "--no-progress",
        "--out",
        str(out),
    )
    assert ok.returncode == 0, ok.stderr[-2000:]
    assert "| E_random | P_scripted |" in ok.stdout
    assert "Results of 3 pursuers, 1 evaders and 1 obstacles" in ok.stdout
    meta = json.loads((out / "results.json").read_text())["meta"]
    assert meta["preset"] == "3-1-1-custom"  # no preset has these rules
    assert meta["env_config"]["arena"]["radius"] == 3.0
    assert meta["env_config"]["pursuer"]["num_agents"] == 3
    # Without the progress bar each compile is still announced, on stderr.
    assert "E_random vs P_scripted: compiling..." in ok.stderr
    assert "compiling the recording..." in ok.stderr and "compiling" not in ok.stdout
    assert (out / "results.md").is_file() and (out / "trajectories" / "pairing-0.npz").is_file()
    again = _cli("--pursuers", "scripted", "--preset", "2-1-1", "--out", str(out))
    assert again.returncode != 0 and "already holds results" in again.stderr
    for args, message in (
        (("--preset", "9-9-9"), "--preset: unknown preset '9-9-9'"),
        (("--pursuers", str(tmp_path / "missing-run")), "is not scripted, random, a shipped"),
        (("--trials", "0"), "trials"),
    ):
        bad = _cli(*args, "--out", str(tmp_path / "bad"), timeout=300)
        assert bad.returncode != 0, args
        assert message in bad.stderr, (args, bad.stderr[-1000:])
        assert "Traceback" not in bad.stderr


def test_pe_mjx_evaluate_keep_adds_a_policy_and_plays_only_its_pairings(tmp_path, capsys):
    """`--keep DIR`: an evaluation that adds a policy keeps DIR's pairings of the same policies
    (after replaying one), into another --out or into DIR itself; a --keep without results is
    one line naming it, and the earlier results are left as they were."""
    from pe_mjx.cli import main

    out = tmp_path / "table"
    argv = ["evaluate", "--preset", "2-1-1", "--trials", "3", "--backend", "kinematic"]
    argv += ["--record", "0", "--no-progress", "--pursuers", "scripted", "random"]
    main([*argv, "--evaders", "scripted", "--out", str(out)])
    before = (out / "results.json").read_text()
    with pytest.raises(SystemExit):
        main([*argv, "--evaders", "scripted", "--out", str(out), "--keep", str(tmp_path)])
    assert f"--keep: {tmp_path} holds no results.json" in capsys.readouterr().err
    assert (out / "results.json").read_text() == before
    for target in (tmp_path / "other", out):
        main([*argv, "--evaders", "scripted", "random", "--out", str(target), "--keep", str(out)])
        data = json.loads((target / "results.json").read_text())
        # (scripted, scripted) replayed as the check, (random, scripted) kept, the rest played.
        assert [p["kept"] for p in data["pairings"]] == [False, True, False, False]
        assert data["meta"]["kept_from"] == str(out)
    capsys.readouterr()


def test_the_api_and_the_cli_evaluate_a_shipped_policy_bit_for_bit(tmp_path, capsys):
    """One `EvalConfig` through both front ends, `evaluate(...)` and `pe-mjx evaluate`: the same
    results.json (but for wall times), trials.csv and trajectories, byte for byte."""
    from pe_mjx.cli import main

    kwargs = dict(trials=3, seed=5, backend="kinematic", record=1)
    ev.evaluate(
        ["mix-20-5-8"], ["scripted"], "2-1-1", tmp_path / "api", log=lambda *_: None, **kwargs
    )
    argv = ["evaluate", "--pursuers", "mix-20-5-8", "--evaders", "scripted", "--preset", "2-1-1"]
    argv += ["--trials", "3", "--seed", "5", "--backend", "kinematic", "--record", "1"]
    main([*argv, "--no-progress", "--out", str(tmp_path / "cli")])
    capsys.readouterr()

    def results(name):
        data = json.loads((tmp_path / name / "results.json").read_text())
        for key in ("seconds", "code_version", "devices"):
            data["meta"].pop(key)
        for pairing in data["pairings"]:
            pairing.pop("seconds")
        return data

    assert results("api") == results("cli")
    for name in ("trials.csv", "results.csv", "results.md", "trajectories/pairing-0.npz"):
        assert (tmp_path / "api" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes()


def test_two_runs_of_one_method_get_labels_that_tell_them_apart():
    env = pe_mjx.get_preset("20-5-8")
    specs = ("mix-20-5-8", "mix-20-5-8-3m", "mean-20-5-8-3m", "scripted")
    policies = ev.distinct_labels([ev.resolve_policy(s, "pursuer", env) for s in specs])
    assert [p.label for p in policies] == [
        "P_MIX(20,5,8) [mix-20-5-8]",
        "P_MIX(20,5,8) [mix-20-5-8-3m]",
        "P_MEAN(20,5,8)",  # a label only one policy holds stays the paper's
        "P_scripted",
    ]
    assert [p.source for p in policies] == list(specs)
