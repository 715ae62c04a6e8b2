"""The policies shipped inside the package (pe_mjx/assets/policies) and run-name resolution.

A shipped policy is a packed policy (`pe_mjx.policy.packed`: the run's config and one
`policy.msgpack`; older ones, a run directory with metadata and policy items only) that installs
with the package, so `load_policy("mix-20-5-8")`, `pe-mjx evaluate --pursuers
mix-20-5-8` and `pe-mjx view --pursuers mix-20-5-8` work from a wheel as from a checkout (where
assets/policies/<name> links to the same files).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from pe_mjx.policy.packed import PACKED_FILE


def policies_dir() -> Path:
    """The directory of the shipped policies (inside the installed package)."""
    return Path(str(resources.files("pe_mjx").joinpath("assets", "policies")))


def shipped_names() -> tuple[str, ...]:
    """The names of the shipped policies ("mix-20-5-8", ...)."""
    root = policies_dir()
    if not root.is_dir():
        return ()
    return tuple(
        sorted(
            p.name
            for p in root.iterdir()
            if (p / "checkpoints").is_dir() or (p / PACKED_FILE).is_file()
        )
    )


RETIRED = {
    "mlp-20-5-8": ("mlp-20-5-8-s0", 510),
    "mean-20-5-8": ("mean-20-5-8-s0", 510),
    "birnn-20-5-8": ("birnn-20-5-8-s0", 170),
}
"""Policies that shipped once and were removed on 2026-12-06 (the 1M snapshots of Table III's
MLP, MEAN and BIRNN co-evolutions, superseded by their `-3m` and `-10m` successors; see
assets/policies/README.md): name -> (the run under train/runs whose config made it, the
iteration it was taken at)."""


def retired_note(spec: str | Path) -> str | None:
    """For the name of a retired policy (`RETIRED`), one sentence on what to play instead and
    how to train it again; None for anything else."""
    name = str(spec)
    if name not in RETIRED:
        return None
    run, iteration = RETIRED[name]
    return (
        f"{name} no longer ships (retired on 2026-12-06): play {name}-3m or {name}-10m, or "
        f"train it again from a checkout with `pe-mjx train --config "
        f"train/runs/{run}/config.json --stop-after {iteration} --out runs/{name}`"
    )


def resolve_run(spec: str | Path) -> Path:
    """A run directory from a path or a shipped policy's name.

    An existing path wins (a local run directory named like a shipped policy is that run);
    otherwise a bare name of a shipped policy is its packaged directory; anything else is
    returned as a path, for the caller to report as missing.
    """
    path = Path(spec).expanduser()
    if path.exists():
        return path
    text = str(spec)
    if "/" not in text and text in shipped_names():
        return policies_dir() / text
    return path


__all__ = ["RETIRED", "policies_dir", "resolve_run", "retired_note", "shipped_names"]
