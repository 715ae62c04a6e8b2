"""The paper's evaluation (IV-B to IV-E): cross-confrontation matrices, its four metrics, reports.

A *policy spec* is "scripted", "random" or a run directory of `pe-mjx train`. Every pursuer spec
plays every evader spec for `trials` episodes, all trials of a pairing as one vmapped batch; trial
i of every pairing starts from the same arena (reset key i), so pairings are compared on equal
ground. Metrics per trial (SPEC 4), with m pursuers and n evaders, m' and n' incapacitated:

  success rate      n' / n
  travel distance   mean distance travelled by the m pursuers (metres)
  pursuit cost      m'
  per-evader cost   mean(m') / mean(n') over the trials (the paper's tables; its text says n'/m')

plus the episode length and the causes of incapacitation per team. Means carry 95% confidence
intervals (Student t for means; percentile bootstrap, 2000 resamples, for the ratio).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from pe_mjx.config import EnvConfig, get_preset
from pe_mjx.env import CAUSE_NAMES, PursuitEvasionEnv
from pe_mjx.episodes import play_episodes
from pe_mjx.policies import Policy, make_policy

BUILTIN = ("scripted", "random")
TRIAL_FIELDS = ("success_rate", "travel_distance", "pursuit_cost", "evaders_incapacitated")
TRIAL_FIELDS += ("length",)


@dataclasses.dataclass(frozen=True)
class PolicySpec:
    """A policy for one team, resolved: its label, where it came from, and the callable."""

    team: str
    source: str
    label: str
    policy: Policy
    note: str = ""
    method: str = ""
    """The encoder of a learned policy ("mix", ...); the spec itself for built-in ones."""


def _team_letter(team: str) -> str:
    return "P" if team == "pursuer" else "E"


def resolve_policy(spec: str, team: str, env_config: EnvConfig) -> PolicySpec:
    """Turns a spec string into a policy for `team` in scenes of `env_config`.

    Raises ValueError (a CheckpointError for runs) with a clear message when it does not fit.
    """
    if spec in BUILTIN:
        policy = make_policy(spec, env_config, team)
        return PolicySpec(team, spec, f"{_team_letter(team)}_{spec}", policy, method=spec)
    from pe_mjx.ppo.checkpoint import load_policy, read_meta

    meta = read_meta(spec)
    if team not in meta["network_configs"]:
        raise ValueError(f"run {spec} did not learn a {team} policy")
    net = meta["network_configs"][team]
    trained = EnvConfig.from_dict(meta["env_config"])
    counts = (trained.pursuer.num_agents, trained.evader.num_agents, trained.arena.num_obstacles)
    label = f"{_team_letter(team)}_{net['encoder'].upper()}({counts[0]},{counts[1]},{counts[2]})"
    note = ""
    here = (env_config.pursuer.num_agents, env_config.evader.num_agents)
    here += (env_config.arena.num_obstacles,)
    if net["encoder"] == "mlp" and here != counts:
        # SPEC 3.1: an MLP cannot generalise; its input is padded/truncated to its training counts.
        note = "mlp-padded"
        label += "*"
    policy = load_policy(spec, team=team, env_config=env_config)
    return PolicySpec(team, str(spec), label, policy, note, method=net["encoder"])


def trial_metrics(env: PursuitEvasionEnv, final) -> dict[str, np.ndarray]:
    """Per-trial numbers from a batched final state [B] (numpy arrays of shape [B])."""
    w = jax.device_get(final.world)
    p = env.num_pursuers
    inactive = ~np.asarray(w.active)
    cause = np.asarray(w.cause)
    out = {
        "success_rate": inactive[:, p:].mean(axis=1),
        "travel_distance": np.asarray(w.distance)[:, :p].mean(axis=1),
        "pursuit_cost": inactive[:, :p].sum(axis=1).astype(float),
        "evaders_incapacitated": inactive[:, p:].sum(axis=1).astype(float),
        "length": np.asarray(w.step).astype(float),
    }
    for code, name in CAUSE_NAMES.items():
        out[f"pursuers_{name}"] = (cause[:, :p] == code).sum(axis=1).astype(float)
        out[f"evaders_{name}"] = (cause[:, p:] == code).sum(axis=1).astype(float)
    return out


def mean_ci(x: np.ndarray) -> tuple[float, float]:
    """Mean and the half-width of its 95% Student-t confidence interval."""
    from scipy import stats

    x = np.asarray(x, dtype=float)
    n = len(x)
    if n < 2:
        return float(x.mean()), float("nan")
    half = stats.t.ppf(0.975, n - 1) * x.std(ddof=1) / math.sqrt(n)
    return float(x.mean()), float(half)


def ratio_ci(num: np.ndarray, den: np.ndarray, seed: int = 0) -> tuple[float, float, float]:
    """mean(num) / mean(den) and a 95% percentile-bootstrap interval (low, high)."""
    num, den = np.asarray(num, float), np.asarray(den, float)
    ratio = num.mean() / den.mean() if den.mean() > 0 else float("inf")
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(num), size=(2000, len(num)))
    n_mean, d_mean = num[idx].mean(axis=1), den[idx].mean(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        boot = np.sort(np.where(d_mean > 0, n_mean / np.maximum(d_mean, 1e-12), np.inf))
    # Order statistics rather than np.percentile, which interpolates inf - inf into NaN.
    low, high = boot[int(0.025 * len(boot))], boot[int(np.ceil(0.975 * len(boot))) - 1]
    return float(ratio), float(low), float(high)


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
    pursuer: PolicySpec
    evader: PolicySpec
    trials: dict[str, np.ndarray]
    summary: dict[str, Any]
    seconds: float


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
) -> list[PairingResult]:
    """Runs every pursuer spec against every evader spec; optionally records `record` trials.

    Trajectories are written to `out/trajectories/pairing-<i>.npz` when `record` > 0. With
    `skip_same_method`, pairings of two policies with the same encoder are left out, as in the
    paper's tables (a co-evolution's own opponent is never its test opponent).
    """
    env = PursuitEvasionEnv(env_config, backend=backend)
    p_specs = [resolve_policy(s, "pursuer", env_config) for s in pursuers]
    e_specs = [resolve_policy(s, "evader", env_config) for s in evaders]
    keys = jax.random.split(jax.random.key(seed), trials)
    results = []
    index = 0
    for e_spec in e_specs:
        for p_spec in p_specs:
            if skip_same_method and p_spec.method and p_spec.method == e_spec.method:
                continue
            pols = {"pursuer": p_spec.policy, "evader": e_spec.policy}
            tic = time.perf_counter()
            final = jax.jit(lambda k, pols=pols: play_episodes(env, pols, k))(keys)
            per_trial = trial_metrics(env, final)
            seconds = time.perf_counter() - tic
            result = PairingResult(index, p_spec, e_spec, per_trial, summarize(per_trial), seconds)
            results.append(result)
            log(
                f"[{index}] {e_spec.label} vs {p_spec.label}: success "
                f"{result.summary['success_rate']:.3f}, pursuit cost "
                f"{result.summary['pursuit_cost']:.2f} ({seconds:.1f} s)"
            )
            if record and out is not None:
                _record(env, pols, keys[:record], result, out, seed)
            index += 1
    return results


def _record(env, pols, keys, result: PairingResult, out: Path, seed: int) -> None:
    from pe_mjx import trajectory

    final, traj = jax.jit(lambda k: play_episodes(env, pols, k, record=True))(keys)
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
        lines += [
            "",
            "\\* MLP policy run at entity counts other than its training counts: its "
            "input is zero-padded or truncated (SPEC 3.1); it cannot generalise.",
        ]
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
                },
                "evader": {
                    "label": r.evader.label,
                    "source": r.evader.source,
                    "note": r.evader.note,
                },
                "summary": r.summary,
                "seconds": r.seconds,
                "trials": {k: v.tolist() for k, v in r.trials.items()},
            }
            for r in results
        ],
    }
    paths["json"].write_text(json.dumps(payload, indent=1))
    paths.update(plot_heatmaps(results, out))
    return paths


def plot_heatmaps(results: list[PairingResult], out: Path) -> dict[str, Path]:
    """Success rate and per-evader cost as heatmaps over pursuer x evader policies."""
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
            ax.text(
                j,
                i,
                "inf" if np.isinf(v) else f"{v:.2f}",
                ha="center",
                va="center",
                color="white" if key == "success_rate" else "black",
                fontsize=9,
            )
        fig.colorbar(im, ax=ax, label=name)
        ax.set_title(name)
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
) -> dict[str, Any]:
    """Runs a matrix and writes every report to `out`; returns the paths and the results."""
    env_config = get_preset(preset) if isinstance(preset, str) else preset
    out = Path(out)
    tic = time.perf_counter()
    results = cross_confrontation(
        pursuers, evaders, env_config, trials, seed, backend, record, out, log, skip_same_method
    )
    meta = {
        "preset": env_config.name,
        "trials": trials,
        "seed": seed,
        "backend": backend,
        "pursuers": pursuers,
        "evaders": evaders,
        "seconds": time.perf_counter() - tic,
        "jax_version": jax.__version__,
        "devices": [str(d) for d in jax.devices()],
    }
    paths = write_reports(results, out, env_config, meta)
    return {"paths": paths, "results": results, "meta": meta}


__all__ = [
    "PolicySpec",
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
