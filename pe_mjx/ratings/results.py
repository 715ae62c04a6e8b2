"""Reading `pe-mjx evaluate` results.json files into the pairings of one scene (`read_results`),
each validated, with a one-line ValueError naming the file and what is wrong.

Combining files. Every file must be of the same scene (env config) and backend. A pairing that
two files with the same seed and trial count both hold is the same games (or, under other code,
games from the same arenas): it counts once, from the file given first. Other seeds or trial
counts are other arenas, and pool.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pe_mjx import outputs
from pe_mjx.config import EnvConfig
from pe_mjx.eval_config import MAX_TRIALS
from pe_mjx.names import BACKENDS
from pe_mjx.ratings.model import TEAMS, Pairing
from pe_mjx.sizes import shorten

_SHIPPED = re.compile(r"(?:^|/)assets/policies/([^/]+)/?$")


@dataclasses.dataclass(frozen=True)
class Matches:
    """The pairings of one scene read from results.json files, each counted once."""

    scene: str
    backend: str
    pairings: tuple[Pairing, ...]
    labels: dict[tuple[str, str], str]
    """(team, policy name) -> its label in the results (e.g. "P_MIX(20,5,8)")."""
    sources: tuple[dict[str, Any], ...]
    """Per file: its path, seed, trials, pairings and those counted from an earlier file."""


def policy_name(source: str) -> str:
    """A policy's name from the source results.json records: a shipped policy's name however it
    was given ("mix-20-5-8-3m" or "assets/policies/mix-20-5-8-3m"), else the source itself."""
    found = _SHIPPED.search(source)
    return found.group(1) if found else source


@dataclasses.dataclass(frozen=True)
class _File:
    path: Path
    env: dict[str, Any]
    backend: str
    seed: int
    trials: int
    evaders: int
    pairings: list[tuple[dict[str, tuple[str, str, str]], np.ndarray]]
    """Per pairing: team -> (policy name, label, fingerprint or ""), and its captures [T]."""


def _need(ok: bool, where: str, what: str) -> None:
    if not ok:
        raise ValueError(f"{where} {what}")


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _numbers(values: Any, length: int, where: str) -> np.ndarray:
    """`values` as float [length], each a finite JSON number (a ValueError naming `where`)."""
    _need(
        isinstance(values, list) and len(values) == length,
        where,
        f"must be a list of {length} numbers (meta.trials), got {shorten(values, 60)}",
    )
    for v in values:
        number = isinstance(v, int | float) and not isinstance(v, bool)
        _need(number and math.isfinite(v), where, f"holds {shorten(v, 40)}, not a finite number")
    return np.asarray(values, dtype=float)


def _read_pairing(raw: Any, where: str, trials: int, evaders: int):
    """One pairing of a results.json: team -> (name, label, fingerprint), captures [T]."""
    _need(isinstance(raw, dict), where, "is not an object")
    teams = {}
    for team in TEAMS:
        side = raw.get(team)
        ok = isinstance(side, dict) and isinstance(side.get("source"), str) and side["source"]
        _need(bool(ok), where, f"has no {team}.source naming its {team} policy")
        label, print_ = side.get("label", ""), side.get("fingerprint") or ""
        _need(isinstance(label, str), where, f"has a {team}.label that is not a string")
        _need(isinstance(print_, str), where, f"has a {team}.fingerprint that is not a string")
        teams[team] = (policy_name(side["source"]), label, print_)
    outcomes = raw.get("trials")
    _need(
        isinstance(outcomes, dict) and "evaders_incapacitated" in outcomes,
        where,
        "has no per-trial outcomes (trials.evaders_incapacitated)",
    )
    name = f"{where} trials.evaders_incapacitated"
    captured = _numbers(outcomes["evaders_incapacitated"], trials, name)
    bad = (captured != np.round(captured)) | (captured < 0) | (captured > evaders)
    _need(not bad.any(), name, f"holds {shorten(captured[bad][:1].tolist())}, not 0..{evaders}")
    if "success_rate" in outcomes:
        rates = _numbers(outcomes["success_rate"], trials, f"{where} trials.success_rate")
        off = np.flatnonzero(np.abs(rates - captured / evaders) > 1e-6)
        _need(
            len(off) == 0,
            where,
            f"trial {off[0] if len(off) else 0}: success_rate is not evaders_incapacitated / "
            f"{evaders}",
        )
    return teams, captured.astype(np.int64)


def _read_file(path: Path) -> _File:
    """One results.json, validated (a one-line ValueError naming it and what is wrong)."""
    from pe_mjx.evaluate import MAX_RESULTS_BYTES  # the cap every reader of results.json uses

    text = outputs.read_text(path, MAX_RESULTS_BYTES)
    try:
        data = json.loads(text)
    except ValueError as err:
        raise ValueError(f"{path}: not JSON ({err})") from None
    where = f"{path}:"
    _need(isinstance(data, dict), where, "is not the results.json of `pe-mjx evaluate`")
    meta, env, pairings = data.get("meta"), data.get("env_config"), data.get("pairings")
    _need(isinstance(meta, dict), where, "has no meta object (not an evaluation's results)")
    _need(isinstance(env, dict), where, "has no env_config object (not an evaluation's results)")
    _need(isinstance(pairings, list) and bool(pairings), where, "has no pairings")
    try:
        scene = EnvConfig.from_dict(env)
    except ValueError as err:
        raise ValueError(f"{path}: env_config: {err}") from None
    _need(
        scene.evader.min_agents in (None, scene.evader.num_agents),
        where,
        "plays a varying number of evaders (evader.min_agents), and results.json does not say "
        "how many a trial had: not rated",
    )
    trials, seed, backend = meta.get("trials"), meta.get("seed"), meta.get("backend")
    ok = _is_int(trials) and 1 <= trials <= MAX_TRIALS
    _need(ok, where, f"meta.trials must be an integer in 1..{MAX_TRIALS}, got {shorten(trials)}")
    _need(_is_int(seed), where, f"meta.seed must be an integer, got {shorten(seed)}")
    _need(backend in BACKENDS, where, f"meta.backend must be one of {BACKENDS}")
    n = scene.evader.num_agents
    read = [_read_pairing(p, f"{path}: pairing {i}", trials, n) for i, p in enumerate(pairings)]
    for team, key in (("pursuer", "pursuers"), ("evader", "evaders")):
        listed = meta.get(key)
        names = (
            {policy_name(s) for s in listed if isinstance(s, str)}
            if isinstance(listed, list)
            else set()
        )
        for name in sorted(names - {teams[team][0] for teams, _ in read}):
            raise ValueError(
                f"{path}: {team} policy {name} (meta.{key}) plays no pairing: a policy with no "
                "matches has no rating"
            )
    return _File(path, scene.to_dict(), backend, seed, trials, n, read)


def _first_difference(a: Any, b: Any, prefix: str = "env_config") -> str:
    """The path of the first field in which two config trees differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            if a.get(key) != b.get(key):
                return _first_difference(a.get(key), b.get(key), f"{prefix}.{key}")
    return f"{prefix} is {shorten(a, 40)}, not {shorten(b, 40)}"


def read_results(paths: Sequence[str | Path]) -> Matches:
    """The pairings of one scene from results.json files of `pe-mjx evaluate` (or reproduce),
    each pairing counted once (module docstring); a one-line ValueError naming the file if one
    is not such a file, or is of another scene or backend than the first."""
    if not paths:
        raise ValueError("no results given: name one or more results.json of `pe-mjx evaluate`")
    files = [_read_file(Path(p)) for p in paths]
    first = files[0]
    pairings: list[Pairing] = []
    labels: dict[tuple[str, str], str] = {}
    prints: dict[tuple[str, str], tuple[str, Path]] = {}
    seen: dict[tuple[str, str, int, int], tuple[Path, np.ndarray]] = {}
    sources = []
    for f in files:
        if (f.env["name"], f.backend) != (first.env["name"], first.backend):
            raise ValueError(
                f"{f.path}: scene {f.env['name']} ({f.backend}) is not {first.path}'s "
                f"{first.env['name']} ({first.backend}); rate each scene apart"
            )
        if f.env != first.env:
            raise ValueError(
                f"{f.path}: {_first_difference(f.env, first.env)} as in {first.path}: another "
                "scene under the same name; rate each scene apart"
            )
        counted_before = []
        for teams, captured in f.pairings:
            for team in TEAMS:
                name, label, print_ = teams[team]
                labels.setdefault((team, name), label)
                earlier = prints.setdefault((team, name), (print_, f.path)) if print_ else None
                if earlier is not None and earlier[0] != print_:
                    raise ValueError(
                        f"{f.path}: {team} policy {name} has fingerprint {print_[:8]} here but "
                        f"{earlier[0][:8]} in {earlier[1]}: two policies under one name"
                    )
            key = (teams["pursuer"][0], teams["evader"][0], f.seed, f.trials)
            if key in seen:
                counted_before.append(
                    {
                        "pursuer": key[0],
                        "evader": key[1],
                        "counted_from": str(seen[key][0]),
                        "same_games": bool(np.array_equal(seen[key][1], captured)),
                    }
                )
                continue
            seen[key] = (f.path, captured)
            pairings.append(Pairing(key[0], key[1], captured, f.evaders, f"seed {f.seed}"))
        sources.append(
            {
                "path": str(f.path),
                "seed": f.seed,
                "trials": f.trials,
                "pairings": len(f.pairings),
                "counted_before": counted_before,
            }
        )
    return Matches(first.env["name"], first.backend, tuple(pairings), labels, tuple(sources))
