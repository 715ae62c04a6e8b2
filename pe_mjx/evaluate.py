"""The paper's evaluation (IV-B to IV-E): cross-confrontation matrices, its four metrics, reports.

A *policy spec* is "scripted", "random", a run directory of `pe-mjx train` or a shipped policy
(resolved by `pe_mjx.policy.resolve.resolve_policy`). Every pursuer spec plays every evader spec for
`trials` episodes, all trials of a pairing as one vmapped batch; trial i of every pairing starts
from the same arena (reset key i), so pairings are compared on equal ground. Metrics per trial
(SPEC 4), with m pursuers and n evaders, m' and n' incapacitated:

  success rate      n' / n
  travel distance   mean distance travelled by the m pursuers (metres)
  pursuit cost      m'
  per-evader cost   mean(m') / mean(n') over the trials (the paper's tables; its text says n'/m')

plus the episode length and the causes of incapacitation per team. Means carry 95% confidence
intervals (Student t for means; scipy's percentile bootstrap, 2000 paired resamples, for the ratio).

One role per module: `pe_mjx.eval_config` states what is played (`EvalConfig`),
`pe_mjx.eval_metrics` the numbers, `pe_mjx.eval_games` the jitted episodes and recordings,
`pe_mjx.eval_reports` the files; this module plays the matrix (keeping an earlier evaluation's
pairings where it may) and writes it atomically. Its names are re-exported here, the API they
have always been imported from.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from pe_mjx import interrupts, outputs, sizes
from pe_mjx.config import EnvConfig, get_preset
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.eval_config import POLICY_KINDS, EvalConfig
from pe_mjx.eval_games import Games, progress_bar, record_pairing
from pe_mjx.eval_metrics import (
    DISTANCE_KEYS,
    TRIAL_FIELDS,
    PairingResult,
    mean_ci,
    ratio_ci,
    summarize,
    trial_metrics,
)
from pe_mjx.eval_reports import (
    MLP_PADDED_NOTE,
    PAPER_COLUMNS,
    markdown_table,
    plot_heatmaps,
    write_reports,
)
from pe_mjx.names import BUILTIN_POLICIES
from pe_mjx.policy.core import Policy
from pe_mjx.policy.resolve import resolve_policy

Log = Callable[[str], Any]


def check_policy_specs(config: EvalConfig) -> None:
    """Each policy spec is built in or a readable run that learned its team, checked before any
    compile: `ValueError` naming the flag (--pursuers or --evaders) and the spec."""
    from pe_mjx.policy.shipped import resolve_run, retired_note
    from pe_mjx.policy.store import CheckpointError, read_meta

    for flag, specs, team in (
        ("--pursuers", config.pursuers, "pursuer"),
        ("--evaders", config.evaders, "evader"),
    ):
        for spec in specs:
            if spec in BUILTIN_POLICIES:
                continue
            if not spec or not resolve_run(spec).is_dir():
                kinds = POLICY_KINDS.replace("a run", "a run directory")
                raise ValueError(f"{flag}: {retired_note(spec) or f'{spec!r} is not {kinds}'}")
            try:
                meta = read_meta(spec)
            except CheckpointError as err:
                raise ValueError(f"{flag}: {err}") from None
            if team not in meta["network_configs"]:
                raise ValueError(f"{flag}: run {spec} did not learn a {team} policy")


MAX_RESULTS_BYTES = 512 << 20
"""The largest results.json that `Earlier.read` opens (100 trials of 100 pairings take ~10 MB)."""


@dataclasses.dataclass(frozen=True)
class Earlier:
    """The pairings of an earlier evaluation that a new one may keep instead of playing them
    again: those whose two policies have the same fingerprints, in an evaluation of the same
    scene, trials, seed and backend. The first such pairing is played again all the same, and
    only if every trial comes out the same game (every count and length equal, the distances up
    to float32 rounding: `_same_trials`) are the others kept (a change of code since is caught
    there, and then every pairing is played)."""

    directory: Path
    pairings: dict[tuple[str, str], dict[str, Any]]
    """Each earlier pairing's record in results.json, by (pursuer, evader) fingerprint."""
    record: int | None
    """Trials recorded per pairing there (None: unknown, its trajectories are not kept)."""

    @classmethod
    def read(cls, directory: Path, config: EvalConfig) -> tuple[Earlier | None, str]:
        """The keepable pairings of `directory`/results.json (None if none) and why."""
        path = Path(directory) / "results.json"
        if not path.is_file():
            return None, f"{path} does not exist"
        if path.stat().st_size > MAX_RESULTS_BYTES:
            return None, f"{path} is larger than {MAX_RESULTS_BYTES:,} bytes"
        try:
            data = json.loads(path.read_text())
            meta, pairings = data["meta"], list(data["pairings"])
            # Both sides rebuilt as configs: a field added since (at its default) is the same game.
            earlier_scene = EnvConfig.from_dict(meta["env_config"]).to_dict()
            same = (earlier_scene, meta["trials"], meta["seed"], meta["backend"])
            if same != (config.env.to_dict(), config.trials, config.seed, config.backend):
                return None, f"{path} is of another scene, trial count, seed or backend"
            by_policies = {}
            for pairing in pairings:
                prints = tuple(pairing[team].get("fingerprint") for team in ("pursuer", "evader"))
                if None not in prints and set(pairing["trials"]) and pairing["summary"]:
                    by_policies[prints] = pairing
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            return None, f"{path} is not an evaluation's results ({type(e).__name__}: {e})"
        if not by_policies:
            return None, f"{path} has no pairing with its policies' fingerprints"
        record = meta.get("record")
        return cls(Path(directory), by_policies, record if isinstance(record, int) else None), ""

    def trajectory(self, pairing: dict[str, Any], record: int) -> Path | None:
        """The earlier recording of `pairing` if it holds the same `record` trials."""
        path = self.directory / "trajectories" / f"pairing-{pairing['pairing']}.npz"
        return path if self.record == record and path.is_file() else None


def cross_confrontation(
    config: EvalConfig,
    out: Path | None = None,
    log: Log = print,
    progress: bool = False,
    earlier: Earlier | None = None,
) -> list[PairingResult]:
    """Runs every pursuer spec against every evader spec; optionally records `config.record`
    trials.

    Trajectories are written to `out/trajectories/pairing-<i>.npz` when `config.record` > 0.
    With `config.skip_same_method`, pairings of two policies with the same encoder are left out,
    as in the paper's tables. With `progress`, a progress bar over each pairing's trials on a
    terminal's stderr. With `earlier`, its pairings of the same policies are kept instead of
    played (see `Earlier`).
    """
    env = PursuitEvasionEnv(config.env, backend=config.backend)
    p_specs = distinct_labels([resolve_policy(s, "pursuer", config.env) for s in config.pursuers])
    e_specs = distinct_labels([resolve_policy(s, "evader", config.env) for s in config.evaders])
    keys = jax.random.split(jax.random.key(config.seed), config.trials)
    pairs = [
        (p, e)
        for e in e_specs
        for p in p_specs
        if not (config.skip_same_method and p.method and p.method == e.method)
    ]
    matrix = _Matrix(Games(env, log), config, keys, out, log, earlier)
    with progress_bar(progress) as bar:
        for index, (p_spec, e_spec) in enumerate(pairs):
            interrupts.check()  # a safe point between pairings (Ctrl-C)
            matrix.pairing(index, p_spec, e_spec, f"[{index + 1}/{len(pairs)}]", bar)
    return matrix.results


def distinct_labels(policies: list[Policy]) -> list[Policy]:
    """One side's policies with the labels that two or more of them share (two MIX runs trained
    at the same counts are both "P_MIX(20,5,8)") followed by their source's name,
    "P_MIX(20,5,8) [mix-20-5-8-3m]", so that the reports and heatmaps keep them apart; a label
    that one policy holds stays the paper's."""
    labels = [p.label for p in policies]
    return [
        dataclasses.replace(p, label=f"{p.label} [{Path(p.source).name}]")
        if labels.count(p.label) > 1
        else p
        for p in policies
    ]


class _Matrix:
    """The pairings of one cross-confrontation as they are played or kept, in order."""

    def __init__(
        self,
        games: Games,
        config: EvalConfig,
        keys: jax.Array,
        out: Path | None,
        log: Log,
        earlier: Earlier | None,
    ):
        self.games, self.config, self.keys, self.out, self.log = games, config, keys, out, log
        self.earlier = earlier
        self.results: list[PairingResult] = []
        self.checked: dict[str, np.dtype] | None = None  # an earlier pairing replayed identically

    def pairing(self, index: int, p_spec: Policy, e_spec: Policy, count: str, bar: Any) -> None:
        old = None
        if self.earlier is not None:
            old = self.earlier.pairings.get((p_spec.fingerprint, e_spec.fingerprint))
        if old is not None and self.checked is not None:
            self._keep(index, p_spec, e_spec, old)
        else:
            self._play(index, p_spec, e_spec, old, f"{count} {e_spec.label} vs {p_spec.label}", bar)

    def _keep(self, index: int, p_spec: Policy, e_spec: Policy, old: dict[str, Any]) -> None:
        kept = {k: np.asarray(v, dtype=self.checked[k]) for k, v in old["trials"].items()}
        result = PairingResult(
            index, p_spec, e_spec, kept, summarize(kept), old["seconds"], kept=True
        )
        self.results.append(result)
        self.log(f"[{index}] {e_spec.label} vs {p_spec.label}: kept from {self.earlier.directory}")
        if self.config.record and self.out is not None:
            keys = self.keys[: self.config.record]
            _keep_or_record(self.games, self.earlier, old, keys, result, self.out, self.config.seed)

    def _play(
        self, index: int, p_spec: Policy, e_spec: Policy, old: dict | None, title: str, bar: Any
    ) -> None:
        tic = time.perf_counter()
        final = self.games.play(p_spec, e_spec, self.keys, bar, title)
        per_trial = trial_metrics(self.games.env, final)
        seconds = time.perf_counter() - tic
        result = PairingResult(index, p_spec, e_spec, per_trial, summarize(per_trial), seconds)
        self.results.append(result)
        self.log(
            f"[{index}] {e_spec.label} vs {p_spec.label}: success "
            f"{result.summary['success_rate']:.3f}, pursuit cost "
            f"{result.summary['pursuit_cost']:.2f} ({seconds:.1f} s)"
        )
        if old is not None:
            self._compare(index, old, per_trial)
        if self.config.record and self.out is not None:
            keys = self.keys[: self.config.record]
            record_pairing(self.games, p_spec, e_spec, keys, result, self.out, self.config.seed)

    def _compare(self, index: int, old: dict[str, Any], per_trial: dict[str, np.ndarray]) -> None:
        """After the first replayed pairing: keep the others if it is the same game."""
        if _same_trials(old["trials"], per_trial):
            self.checked = {k: v.dtype for k, v in per_trial.items()}
            self.log(
                f"[{index}] replays {self.earlier.directory} (the same game): its other "
                "pairings of the same policies are kept"
            )
        else:
            self.earlier = None
            self.log(
                f"[{index}] differs from {old['pairing']} of the earlier evaluation "
                "(the code or a policy changed since): every pairing is played"
            )


SAME_DISTANCE_RTOL = 1e-6
"""How far a replayed trial's distances may be from the earlier ones (relative) and still be the
same game: a few float32 roundings (the distances are float32 sums over an episode's steps; a
change in how they are summed moved Table IV's by at most 5e-8 relative, a change in any move
of the game moves them by far more)."""


def _same_trials(old: dict[str, list], new: dict[str, np.ndarray]) -> bool:
    """Whether an earlier pairing's trials (as results.json holds them) are the new ones: every
    count, length and rate equal, every distance equal up to float32 rounding."""
    if set(old) != set(new):
        return False
    for key, value in new.items():
        earlier = np.asarray(old[key], dtype=float)
        if earlier.shape != value.shape:
            return False
        if key in DISTANCE_KEYS:
            same = np.allclose(earlier, value, rtol=SAME_DISTANCE_RTOL, atol=0, equal_nan=True)
        else:
            same = np.array_equal(earlier, value, equal_nan=True)
        if not same:
            return False
    return True


def _keep_or_record(
    games: Games, earlier: Earlier, old: dict, keys, result: PairingResult, out: Path, seed: int
) -> None:
    """The earlier recording of a kept pairing, renumbered; recorded anew if there is none."""
    path = earlier.trajectory(old, len(keys))
    if path is None:
        record_pairing(games, result.pursuer, result.evader, keys, result, out, seed)
        return
    (out / "trajectories").mkdir(parents=True, exist_ok=True)
    shutil.copyfile(path, out / "trajectories" / f"pairing-{result.index}.npz")


def evaluate(
    pursuers: list[str],
    evaders: list[str],
    preset: str | EnvConfig,
    out: str | Path,
    trials: int = 100,
    seed: int = 0,
    backend: str = "mjx",
    record: int = 3,
    log: Log = print,
    skip_same_method: bool = False,
    progress: bool = False,
    keep: str | Path | None = None,
) -> dict[str, Any]:
    """`run_evaluation` of the `EvalConfig` these keywords state (the API of old, kept: tests,
    docs and scripts call it so); `preset` is a preset's name or a whole scene."""
    config = EvalConfig(
        env=get_preset(preset) if isinstance(preset, str) else preset,
        pursuers=tuple(pursuers),
        evaders=tuple(evaders),
        trials=trials,
        seed=seed,
        backend=backend,
        record=record,
        skip_same_method=skip_same_method,
    )
    return run_evaluation(config, out, log=log, progress=progress, keep=keep)


def run_evaluation(
    config: EvalConfig,
    out: str | Path,
    log: Log = print,
    progress: bool = False,
    keep: str | Path | None = None,
) -> dict[str, Any]:
    """Runs the matrix `config` states and writes every report to `out`; returns the paths, the
    results and the meta data (as results.json holds them).

    Everything is written into a temporary directory beside `out` first, which becomes `out` by
    one rename when complete (`pe_mjx.outputs.writing_dir`): `out` appears whole or not at all,
    also under `kill -9`, and a failed or interrupted evaluation leaves the earlier `out` as it
    was. `keep`: an earlier evaluation's directory (`out`
    itself, to add policies to a matrix) whose pairings of the same policies are kept rather
    than played again, after one of them has replayed identically (`Earlier`)."""
    out = Path(out)
    sizes.check_evaluation(config.env, config.trials, config.record)  # before any allocation
    out.parent.mkdir(parents=True, exist_ok=True)
    with outputs.writing_dir(out, flag="--out") as stage:
        report = _evaluate_into(config, stage, log, progress, keep)
    report["paths"] = {k: out / p.relative_to(stage) for k, p in report["paths"].items()}
    return report


def _evaluate_into(
    config: EvalConfig, out: Path, log: Log, progress: bool, keep: str | Path | None
) -> dict[str, Any]:
    from pe_mjx.ppo.run import code_version

    tic = time.perf_counter()
    earlier = None
    if keep is not None:
        earlier, why = Earlier.read(Path(keep), config)
        if earlier is None:
            log(f"keeping nothing: {why}; every pairing is played")
    results = cross_confrontation(config, out, log, progress, earlier)
    env_config = config.env
    meta = {
        "preset": env_config.name,
        "env_config": env_config.to_dict(),  # the whole scene, also when it is no preset
        "trials": config.trials,
        "seed": config.seed,
        "backend": config.backend,
        "pursuers": list(config.pursuers),
        "evaders": list(config.evaders),
        "seconds": time.perf_counter() - tic,
        "record": config.record,
        "kept": [r.index for r in results if r.kept],
        "kept_from": str(keep) if any(r.kept for r in results) else None,
        "code_version": code_version(),
        "jax_version": jax.__version__,
        "devices": [str(d) for d in jax.devices()],
    }
    paths = write_reports(results, out, env_config, meta)
    return {"paths": paths, "results": results, "meta": meta}


__all__ = [
    "DISTANCE_KEYS",
    "MLP_PADDED_NOTE",
    "PAPER_COLUMNS",
    "TRIAL_FIELDS",
    "Earlier",
    "EvalConfig",
    "PairingResult",
    "Policy",
    "check_policy_specs",
    "cross_confrontation",
    "distinct_labels",
    "evaluate",
    "markdown_table",
    "mean_ci",
    "plot_heatmaps",
    "ratio_ci",
    "resolve_policy",
    "run_evaluation",
    "summarize",
    "trial_metrics",
    "write_reports",
]
