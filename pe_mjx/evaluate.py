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
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import math
import os
import shutil
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from pe_mjx import trajectory
from pe_mjx.config import EnvConfig, get_preset
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.episodes import play_episodes
from pe_mjx.names import CAUSE_NAMES
from pe_mjx.outcomes import outcome_counts
from pe_mjx.policy.core import Policy
from pe_mjx.policy.resolve import resolve_policy

TRIAL_FIELDS = (
    "success_rate",
    "travel_distance",
    "pursuit_cost",
    "evaders_incapacitated",
    "length",
)
DISTANCE_KEYS = ("travel_distance",)
"""The per-trial fields that are float32 sums of distances (the others are counts and rates)."""

MLP_PADDED_NOTE = (
    "\\* MLP policy run at entity counts other than its training counts: its "
    "input is zero-padded or truncated (SPEC 3.1); it cannot generalise."
)
"""The footnote of a table with a starred (padded) MLP policy in it."""


def trial_metrics(env: PursuitEvasionEnv, final) -> dict[str, np.ndarray]:
    """Per-trial numbers from a batched final state [B] (numpy arrays of shape [B])."""
    w = jax.device_get(final.world)
    counts = outcome_counts(np.asarray(w.cause), np.asarray(w.distance), env.num_pursuers)
    out = {k: np.asarray(counts[k], dtype=float) for k in TRIAL_FIELDS if k != "length"}
    out["length"] = np.asarray(w.step).astype(float)
    for name in CAUSE_NAMES.values():
        for who in ("pursuers", "evaders"):
            out[f"{who}_{name}"] = np.asarray(counts[f"{who}_{name}"], dtype=float)
    return out


def mean_ci(x: np.ndarray) -> tuple[float, float]:
    """Mean and the half-width of its 95% Student-t confidence interval."""
    from scipy import stats  # lazy: scipy takes a second to import, only reports need it

    x = np.asarray(x, dtype=float)
    n = len(x)
    if n < 2:
        return float(x.mean()), float("nan")
    half = stats.t.ppf(0.975, n - 1) * x.std(ddof=1) / math.sqrt(n)
    return float(x.mean()), float(half)


def ratio_ci(num: np.ndarray, den: np.ndarray, seed: int = 0) -> tuple[float, float, float]:
    """mean(num) / mean(den) and a 95% percentile-bootstrap interval (low, high): scipy's
    `stats.bootstrap` over the trials, resampled in pairs, 2000 resamples. Resamples with no
    evader down give an infinite ratio, and so may the interval's ends (never NaN)."""
    from scipy import stats

    num, den = np.asarray(num, float), np.asarray(den, float)

    def mean_ratio(n: np.ndarray, d: np.ndarray, axis: int = -1) -> np.ndarray:
        n_mean, d_mean = n.mean(axis=axis), d.mean(axis=axis)
        return np.where(d_mean > 0, n_mean / np.maximum(d_mean, 1e-12), np.inf)

    ratio = mean_ratio(num, den)

    # Infinite resamples make scipy's standard error (unused here) inf - inf: no warning for it.
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        interval = stats.bootstrap(
            (num, den),
            mean_ratio,
            paired=True,
            vectorized=True,
            method="percentile",
            n_resamples=2000,
            rng=np.random.default_rng(seed),
        ).confidence_interval
    return float(ratio), float(interval.low), float(interval.high)


def summarize(trials: dict[str, np.ndarray]) -> dict[str, Any]:
    """The four metrics with intervals, plus length and causes, for one pairing."""
    summary: dict[str, Any] = {}
    for key in ("success_rate", "travel_distance", "pursuit_cost", "length"):
        mean, half = mean_ci(trials[key])
        summary[key] = mean
        summary[f"{key}_ci95"] = half
    ratio, low, high = ratio_ci(trials["pursuit_cost"], trials["evaders_incapacitated"])
    summary["per_evader_cost"] = ratio
    summary["per_evader_cost_ci95"] = [low, high]
    for key, values in trials.items():
        if key.startswith(("pursuers_", "evaders_")):
            summary[key] = float(np.mean(values))
    return summary


@dataclasses.dataclass
class PairingResult:
    index: int
    pursuer: Policy
    evader: Policy
    trials: dict[str, np.ndarray]
    summary: dict[str, Any]
    seconds: float
    """Seconds it took to play (for a kept pairing, when it was played)."""
    kept: bool = False
    """Kept from an earlier evaluation rather than played (see `Earlier`)."""


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
    def read(
        cls, directory: Path, env_config: EnvConfig, trials: int, seed: int, backend: str
    ) -> tuple[Earlier | None, str]:
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
            if same != (env_config.to_dict(), trials, seed, backend):
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
    pursuers: list[str],
    evaders: list[str],
    env_config: EnvConfig,
    trials: int = 100,
    seed: int = 0,
    backend: str = "mjx",
    record: int = 0,
    out: Path | None = None,
    log: Any = print,
    skip_same_method: bool = False,
    progress: bool = False,
    earlier: Earlier | None = None,
) -> list[PairingResult]:
    """Runs every pursuer spec against every evader spec; optionally records `record` trials.

    Trajectories are written to `out/trajectories/pairing-<i>.npz` when `record` > 0. With
    `skip_same_method`, pairings of two policies with the same encoder are left out, as in the
    paper's tables (a co-evolution's own opponent is never its test opponent). With
    `progress`, a progress bar over each pairing's trials on a terminal's stderr. With
    `earlier`, its pairings of the same policies are kept instead of played (see `Earlier`).
    """
    env = PursuitEvasionEnv(env_config, backend=backend)
    p_specs = [resolve_policy(s, "pursuer", env_config) for s in pursuers]
    e_specs = [resolve_policy(s, "evader", env_config) for s in evaders]
    keys = jax.random.split(jax.random.key(seed), trials)
    pairs = [
        (p, e)
        for e in e_specs
        for p in p_specs
        if not (skip_same_method and p.method and p.method == e.method)
    ]
    games = _Games(env, log)
    results = []
    checked: dict[str, np.dtype] | None = None  # an earlier pairing replayed identically
    with _progress(progress) as bar:
        for index, (p_spec, e_spec) in enumerate(pairs):
            old = None
            if earlier is not None:
                old = earlier.pairings.get((p_spec.fingerprint, e_spec.fingerprint))
            if old is not None and checked is not None:
                kept = {k: np.asarray(v, dtype=checked[k]) for k, v in old["trials"].items()}
                result = PairingResult(
                    index, p_spec, e_spec, kept, summarize(kept), old["seconds"], kept=True
                )
                results.append(result)
                log(f"[{index}] {e_spec.label} vs {p_spec.label}: kept from {earlier.directory}")
                if record and out is not None:
                    _keep_or_record(games, earlier, old, keys[:record], result, out, seed)
                continue
            tic = time.perf_counter()
            title = f"[{index + 1}/{len(pairs)}] {e_spec.label} vs {p_spec.label}"
            final = games.play(p_spec, e_spec, keys, bar, title)
            per_trial = trial_metrics(env, final)
            seconds = time.perf_counter() - tic
            result = PairingResult(index, p_spec, e_spec, per_trial, summarize(per_trial), seconds)
            results.append(result)
            log(
                f"[{index}] {e_spec.label} vs {p_spec.label}: success "
                f"{result.summary['success_rate']:.3f}, pursuit cost "
                f"{result.summary['pursuit_cost']:.2f} ({seconds:.1f} s)"
            )
            if old is not None:
                if _same_trials(old["trials"], per_trial):
                    checked = {k: v.dtype for k, v in per_trial.items()}
                    log(
                        f"[{index}] replays {earlier.directory} (the same game): its other "
                        "pairings of the same policies are kept"
                    )
                else:
                    earlier = None
                    log(
                        f"[{index}] differs from {old['pairing']} of the earlier evaluation "
                        "(the code or a policy changed since): every pairing is played"
                    )
            if record and out is not None:
                _record(games, p_spec, e_spec, keys[:record], result, out, seed)
    return results


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
    games: _Games, earlier: Earlier, old: dict, keys, result: PairingResult, out: Path, seed: int
) -> None:
    """The earlier recording of a kept pairing, renumbered; recorded anew if there is none."""
    path = earlier.trajectory(old, len(keys))
    if path is None:
        _record(games, result.pursuer, result.evader, keys, result, out, seed)
        return
    (out / "trajectories").mkdir(parents=True, exist_ok=True)
    shutil.copyfile(path, out / "trajectories" / f"pairing-{result.index}.npz")


class _Games:
    """Jitted episode batches, one compile per (pursuer shape, evader shape, batch, record): the
    policies' learned state is an argument, so pairings of same-shaped policies share a program
    (compiling took about 15 s of each pairing when every pairing closed over its parameters)."""

    def __init__(self, env: PursuitEvasionEnv, log: Any = None):
        self.env = env
        self.log = log
        """Told "compiling..." before each new compile when no progress bar shows it."""
        self.compiled: dict[tuple, Callable[..., Any]] = {}
        self.shapes_run: set[tuple] = set()

    def _fn(self, p_spec: Policy, e_spec: Policy, record: bool) -> Callable[..., Any]:
        key = (p_spec.shape_key, e_spec.shape_key, record)
        if key not in self.compiled:
            p_apply, e_apply, env = p_spec.apply, e_spec.apply, self.env

            def run(p_vars, e_vars, keys):
                pols = {
                    "pursuer": lambda obs, rng: p_apply(p_vars, obs, rng),
                    "evader": lambda obs, rng: e_apply(e_vars, obs, rng),
                }
                return play_episodes(env, pols, keys, record=record)

            self.compiled[key] = jax.jit(run)
        return self.compiled[key]

    def play(self, p_spec, e_spec, keys, bar=None, title: str = ""):
        """The batched final state of one episode per key, in chunks so that the progress bar
        moves over the trials (chunks of equal size, the last padded: one compile). Only on
        CPU, where a wider batch gains little; an accelerator plays all trials in one batch."""
        fn = self._fn(p_spec, e_spec, False)
        n = len(keys)
        steps = PROGRESS_STEPS if jax.default_backend() == "cpu" else 1
        chunk = -(-n // min(n, steps))
        task = None
        if bar is not None:
            task = bar.add_task(title, total=n)
        finals = []
        for start in range(0, n, chunk):
            part = keys[start : start + chunk]
            if len(part) < chunk:
                part = jnp.concatenate([part, keys[: chunk - len(part)]])
            shape = (p_spec.shape_key, e_spec.shape_key, chunk)
            if shape not in self.shapes_run:
                if bar is not None:
                    bar.update(task, description=f"{title}: compiling...")
                elif self.log is not None:
                    self.log(f"{title}: compiling...")
            self.shapes_run.add(shape)
            final = fn(p_spec.variables, e_spec.variables, part)
            finals.append(final)
            if bar is not None:
                bar.update(task, advance=min(chunk, n - start), description=title)
        if bar is not None:
            bar.remove_task(task)
        return jax.tree.map(lambda *x: jnp.concatenate(x)[:n], *finals)

    def record(self, p_spec, e_spec, keys):
        shape = (p_spec.shape_key, e_spec.shape_key, len(keys), "record")
        if shape not in self.shapes_run and self.log is not None:
            self.log(f"{e_spec.label} vs {p_spec.label}: compiling the recording...")
        self.shapes_run.add(shape)
        fn = self._fn(p_spec, e_spec, True)
        return fn(p_spec.variables, e_spec.variables, keys)


PROGRESS_STEPS = 10
"""On CPU the trials of a pairing run in at most this many equal chunks (one progress step
each); arena i depends on its key alone, so the results are those of one batch."""


@contextlib.contextmanager
def _progress(enabled: bool):
    """A rich progress bar on stderr (stdout keeps only the results), or None."""
    if not enabled:
        yield None
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    console = Console(stderr=True)
    if not console.is_terminal:
        yield None
        return
    columns = [
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("trials"),
        TimeElapsedColumn(),
    ]
    with Progress(*columns, console=console, transient=True) as bar:
        yield bar


def _record(
    games: _Games, p_spec, e_spec, keys, result: PairingResult, out: Path, seed: int
) -> None:
    env = games.env
    final, traj = games.record(p_spec, e_spec, keys)
    # Cut the frames after the longest of the recorded episodes ended.
    length = int(np.max(np.asarray(final.world.step))) + 1
    traj = jax.tree.map(lambda x: np.asarray(x)[:length], traj)
    meta = {
        "pursuer": result.pursuer.label,
        "evader": result.evader.label,
        "pursuer_source": result.pursuer.source,
        "evader_source": result.evader.source,
        "seed": seed,
        "trials": list(range(len(keys))),
    }
    rec = trajectory.from_episodes(env.config, traj, final, meta)
    path = out / "trajectories" / f"pairing-{result.index}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    trajectory.save(path, rec, overwrite=True)


# ---------------------------------------------------------------------------- reports

PAPER_COLUMNS = ("Success Rate", "Travel distance", "Pursuit Cost", "Per-Evader Cost")


def markdown_table(results: list[PairingResult], title: str) -> str:
    """The layout of the paper's Tables II-VI, grouped by evader policy, with 95% intervals."""
    lines = [
        f"### {title}",
        "",
        "| Evader's Policy | Pursuer's Policy | Average Success Rate | Average Travel distance "
        "| Average Pursuit Cost | Average Per-Evader Cost |",
        "|---|---|---|---|---|---|",
    ]
    last = None
    for r in results:
        s = r.summary
        evader = r.evader.label if r.evader.label != last else ""
        last = r.evader.label
        low, high = s["per_evader_cost_ci95"]
        lines.append(
            f"| {evader} | {r.pursuer.label} "
            f"| {s['success_rate']:.3f} ± {s['success_rate_ci95']:.3f} "
            f"| {s['travel_distance']:.3f} ± {s['travel_distance_ci95']:.3f} "
            f"| {s['pursuit_cost']:.2f} ± {s['pursuit_cost_ci95']:.2f} "
            f"| {s['per_evader_cost']:.3f} [{low:.3f}, {high:.3f}] |"
        )
    notes = sorted({r.pursuer.note for r in results} | {r.evader.note for r in results} - {""})
    if "mlp-padded" in notes:
        lines += ["", MLP_PADDED_NOTE]
    return "\n".join(lines) + "\n"


def write_reports(
    results: list[PairingResult], out: Path, env_config: EnvConfig, meta: dict[str, Any]
) -> dict[str, Path]:
    """Writes results.md, results.csv (one row per pairing), trials.csv (one row per trial),
    results.json (everything) and the heatmaps; returns their paths."""
    out.mkdir(parents=True, exist_ok=True)
    title = (
        f"Results of {env_config.pursuer.num_agents} pursuers, {env_config.evader.num_agents} "
        f"evaders and {env_config.arena.num_obstacles} obstacles"
    )
    paths = {"markdown": out / "results.md"}
    paths["markdown"].write_text(markdown_table(results, title))
    paths["csv"] = out / "results.csv"
    summary_keys = sorted(results[0].summary) if results else []
    with paths["csv"].open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["pairing", "evader", "pursuer", *summary_keys])
        for r in results:
            row = [r.summary[k] for k in summary_keys]
            row = [json.dumps(v) if isinstance(v, list) else v for v in row]
            writer.writerow([r.index, r.evader.label, r.pursuer.label, *row])
    paths["trials"] = out / "trials.csv"
    trial_keys = sorted(results[0].trials) if results else []
    with paths["trials"].open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["pairing", "evader", "pursuer", "trial", *trial_keys])
        for r in results:
            for i in range(len(r.trials[trial_keys[0]])):
                values = [float(r.trials[k][i]) for k in trial_keys]
                writer.writerow([r.index, r.evader.label, r.pursuer.label, i, *values])
    paths["json"] = out / "results.json"
    payload = {
        "meta": meta,
        "env_config": env_config.to_dict(),
        "pairings": [
            {
                "pairing": r.index,
                "pursuer": {
                    "label": r.pursuer.label,
                    "source": r.pursuer.source,
                    "note": r.pursuer.note,
                    "fingerprint": r.pursuer.fingerprint,
                },
                "evader": {
                    "label": r.evader.label,
                    "source": r.evader.source,
                    "note": r.evader.note,
                    "fingerprint": r.evader.fingerprint,
                },
                "summary": r.summary,
                "seconds": r.seconds,
                "kept": r.kept,
                "trials": {k: v.tolist() for k, v in r.trials.items()},
            }
            for r in results
        ],
    }
    paths["json"].write_text(json.dumps(payload, indent=1))
    paths.update(plot_heatmaps(results, out, env_config.name, meta.get("trials")))
    return paths


def plot_heatmaps(
    results: list[PairingResult], out: Path, preset: str = "", trials: int | None = None
) -> dict[str, Path]:
    """Success rate and per-evader cost as heatmaps over pursuer x evader policies, titled with
    the preset and the trials per pairing; each cell's number is black or white by the
    luminance of its colour, so it reads on every cell."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p_labels = list(dict.fromkeys(r.pursuer.label for r in results))
    e_labels = list(dict.fromkeys(r.evader.label for r in results))
    paths = {}
    for key, name, cmap in (
        ("success_rate", "Success rate", "viridis"),
        ("per_evader_cost", "Per-evader cost", "magma_r"),
    ):
        grid = np.full((len(e_labels), len(p_labels)), np.nan)
        for r in results:
            grid[e_labels.index(r.evader.label), p_labels.index(r.pursuer.label)] = r.summary[key]
        fig, ax = plt.subplots(figsize=(1.6 + 1.4 * len(p_labels), 1.2 + 0.8 * len(e_labels)))
        finite = np.where(np.isfinite(grid), grid, np.nan)
        im = ax.imshow(finite, cmap=cmap, aspect="auto")
        ax.set_xticks(range(len(p_labels)), p_labels, rotation=30, ha="right")
        ax.set_yticks(range(len(e_labels)), e_labels)
        ax.set_xlabel("pursuer policy")
        ax.set_ylabel("evader policy")
        for (i, j), v in np.ndenumerate(grid):
            if np.isnan(v):
                continue
            # An inf cell is left blank (NaN in the image): white under its text.
            r, g, b, _ = im.cmap(im.norm(v)) if np.isfinite(v) else (1.0, 1.0, 1.0, 1.0)
            luminance = 0.2126 * r + 0.7152 * g + 0.0722 * b
            ax.text(
                j,
                i,
                "inf" if np.isinf(v) else f"{v:.2f}",
                ha="center",
                va="center",
                color="black" if luminance > 0.5 else "white",
                fontsize=9,
            )
        fig.colorbar(im, ax=ax, label=name)
        details = [f"preset {preset}" if preset else "", f"{trials} trials" if trials else ""]
        details = [d for d in details if d]
        ax.set_title(f"{name} ({', '.join(details)})" if details else name)
        fig.tight_layout()
        path = out / f"{key}_heatmap.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        paths[f"{key}_heatmap"] = path
    return paths


def evaluate(
    pursuers: list[str],
    evaders: list[str],
    preset: str | EnvConfig,
    out: str | Path,
    trials: int = 100,
    seed: int = 0,
    backend: str = "mjx",
    record: int = 3,
    log: Any = print,
    skip_same_method: bool = False,
    progress: bool = False,
    keep: str | Path | None = None,
) -> dict[str, Any]:
    """Runs a matrix and writes every report to `out`; returns the paths and the results.

    Everything is written into a temporary directory inside `out` first and moved into place
    when complete, so a failed or interrupted evaluation leaves no partial results (nor does it
    touch the earlier results in `out`). `keep`: an earlier evaluation's directory (`out`
    itself, to add policies to a matrix) whose pairings of the same policies are kept rather
    than played again, after one of them has replayed identically (`Earlier`)."""
    env_config = get_preset(preset) if isinstance(preset, str) else preset
    out = Path(out)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(dir=out, prefix=".partial-"))
    try:
        report = _evaluate_into(
            pursuers,
            evaders,
            env_config,
            stage,
            trials,
            seed,
            backend,
            record,
            log,
            skip_same_method,
            progress,
            keep,
        )
        _move_into(stage, out)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    stage.rmdir()
    report["paths"] = {k: out / p.relative_to(stage) for k, p in report["paths"].items()}
    return report


def _move_into(src: Path, dst: Path) -> None:
    """Moves every file under `src` to the same place under `dst` (each by an atomic rename)."""
    for entry in sorted(src.iterdir()):
        if entry.is_dir():
            (dst / entry.name).mkdir(exist_ok=True)
            _move_into(entry, dst / entry.name)
            entry.rmdir()
        else:
            os.replace(entry, dst / entry.name)


def _evaluate_into(
    pursuers: list[str],
    evaders: list[str],
    env_config: EnvConfig,
    out: Path,
    trials: int,
    seed: int,
    backend: str,
    record: int,
    log: Any,
    skip_same_method: bool,
    progress: bool = False,
    keep: str | Path | None = None,
) -> dict[str, Any]:
    from pe_mjx.ppo.run import code_version

    tic = time.perf_counter()
    earlier = None
    if keep is not None:
        earlier, why = Earlier.read(Path(keep), env_config, trials, seed, backend)
        if earlier is None:
            log(f"keeping nothing: {why}; every pairing is played")
    results = cross_confrontation(
        pursuers,
        evaders,
        env_config,
        trials,
        seed,
        backend,
        record,
        out,
        log,
        skip_same_method,
        progress,
        earlier,
    )
    meta = {
        "preset": env_config.name,
        "env_config": env_config.to_dict(),  # the whole scene, also when it is no preset
        "trials": trials,
        "seed": seed,
        "backend": backend,
        "pursuers": pursuers,
        "evaders": evaders,
        "seconds": time.perf_counter() - tic,
        "record": record,
        "kept": [r.index for r in results if r.kept],
        "kept_from": str(keep) if any(r.kept for r in results) else None,
        "code_version": code_version(),
        "jax_version": jax.__version__,
        "devices": [str(d) for d in jax.devices()],
    }
    paths = write_reports(results, out, env_config, meta)
    return {"paths": paths, "results": results, "meta": meta}


__all__ = [
    "Earlier",
    "Policy",
    "cross_confrontation",
    "evaluate",
    "markdown_table",
    "mean_ci",
    "ratio_ci",
    "resolve_policy",
    "summarize",
    "trial_metrics",
    "write_reports",
]
