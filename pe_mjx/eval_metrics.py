"""An evaluation's numbers: the per-trial metrics of a batch of episodes (SPEC 4), their means
with 95% intervals, and one pairing's result."""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any

import jax
import numpy as np

from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.names import CAUSE_NAMES
from pe_mjx.outcomes import outcome_counts
from pe_mjx.policy.core import Policy

TRIAL_FIELDS = (
    "success_rate",
    "travel_distance",
    "pursuit_cost",
    "evaders_incapacitated",
    "length",
)
DISTANCE_KEYS = ("travel_distance",)
"""The per-trial fields that are float32 sums of distances (the others are counts and rates)."""


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


BOOTSTRAP_BATCH_ELEMENTS = 4_000_000
"""Resampled trials per vectorised call of the bootstrap (its memory: ~3 arrays of this many
float64)."""


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
            # In batches: one batch of all 2000 resamples of 100,000 trials took 5.5 GB; these
            # take ~100 MB at most, with the same numbers (the same draws, made in turn).
            batch=max(1, BOOTSTRAP_BATCH_ELEMENTS // max(len(num), 1)),
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
