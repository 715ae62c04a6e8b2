"""Ship one checkpoint of a `pe-mjx train` run as a packaged policy (pe_mjx/assets/policies).

    python tools/ship_policy.py RUN NAME [--step N]

Copies the run's config.json and, of the chosen checkpoint (default: the latest), its metadata
and policy items only: no optimiser or arena state, so the shipped policy plays
(`pe-mjx view/evaluate --pursuers NAME`) but cannot be resumed. assets/policies/NAME links to the
packaged copy, as for the other shipped policies. Refuses to replace an existing policy unless
--replace is given. The model card is written by hand in assets/policies/README.md.

    python tools/ship_policy.py RUN NAME --dest train/seeds

writes the same policy-only copy to DEST/NAME instead, outside the package (no link): for
policies the repository keeps so that its evaluations can be rerun, without installing them.

    python tools/ship_policy.py RUN NAME --nearest-k 4

ships the same parameters with *local attention*: both teams' networks keep only the k nearest
entities of each type (`NetworkConfig.nearest_k`, pe_mjx/networks.py) before encoding. The
encoders' parameters do not depend on how many entities they see, so this changes which tokens
the network reads, not what it learned: no training. The copy's metadata and config.json record
the new `nearest_k` and `derived_from` (the run, its step and its former network configs).

    python tools/ship_policy.py RUN NAME --length-unit 5

ships the same parameters reading the distances to other entities in units of 5 metres in any
arena (`NetworkConfig.length_unit`) instead of in arena radii: a policy trained in an arena of
radius 5 m plays exactly as before there, and sees a neighbourhood of the same density the same
way in a larger arena. Both options may be given together; both are recorded the same way.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import shutil
from pathlib import Path

import tyro

from pe_mjx.experiment import NetworkConfig
from pe_mjx.policy import store
from pe_mjx.policy.shipped import policies_dir

ROOT = Path(__file__).resolve().parent.parent
KEEP = ("_CHECKPOINT_METADATA", "commit_success.txt", "meta", "policy_pursuer", "policy_evader")


@dataclasses.dataclass(frozen=True)
class Args:
    run: tyro.conf.Positional[Path]
    """The run directory."""
    name: tyro.conf.Positional[str]
    """The shipped policy's name (e.g. mlp-20-5-8)."""
    step: int | None = None
    """Checkpoint step (iteration) to ship; default the latest."""
    replace: bool = False
    """Replace a shipped policy of that name."""
    dest: Path | None = None
    """Write to DEST/NAME rather than into the package (pe_mjx/assets/policies)."""
    nearest_k: int | None = None
    """Ship with local attention: both teams' networks read only the k nearest entities of each
    type (the parameters are the run's, unchanged)."""
    length_unit: float | None = None
    """Ship reading neighbour distances in units of this many metres, in any arena (the
    parameters are the run's, unchanged)."""


def ship(args: Args) -> Path:
    changes = {"nearest_k": args.nearest_k, "length_unit": args.length_unit}
    changes = {k: v for k, v in changes.items() if v is not None}
    _check_changes(changes)  # before anything is copied
    meta = store.read_meta(args.run, args.step)  # validates the run and the step
    step = meta["step"]
    dest = (args.dest or policies_dir()) / args.name
    if "/" in args.name or args.name.startswith("."):
        raise SystemExit(f"ship_policy: error: bad name {args.name!r}")
    if dest.exists():
        if not args.replace:
            raise SystemExit(f"ship_policy: error: {dest} exists (--replace to replace it)")
        shutil.rmtree(dest)
    src = args.run / store.CHECKPOINT_DIR / str(step)
    out = dest / store.CHECKPOINT_DIR / str(step)
    out.mkdir(parents=True)
    for item in KEEP:
        if (src / item).is_dir():
            shutil.copytree(src / item, out / item)
        elif (src / item).exists():
            shutil.copy2(src / item, out / item)
    shutil.copy2(args.run / "config.json", dest / "config.json")
    if changes:
        with_network(dest, changes, f"{args.run} step {step}")
    link = ROOT / "assets" / "policies" / args.name
    if args.dest is None and not link.is_symlink():
        link.symlink_to(Path("../../pe_mjx/assets/policies") / args.name)
    store.read_meta(dest)  # the shipped copy reads back
    print(f"shipped {args.run} step {step} ({meta['env_steps']:,} env steps) as {dest}")
    return dest


def _check_changes(changes: dict) -> None:
    """`NetworkConfig`'s own checks of the changed fields, as one line naming the flag."""
    try:
        NetworkConfig(**changes)
    except ValueError as err:
        field, _, problem = str(err).removeprefix("invalid config: ").partition(" ")
        raise SystemExit(f"ship_policy: error: --{field.replace('_', '-')} {problem}") from None


def _set_network(tree: dict, changes: dict) -> dict:
    """Sets `changes` in every network config of a run's config or metadata tree."""
    for net in tree.get("network_configs", {}).values():
        net.update(changes)
    experiment = tree.get("experiment", {})
    for team in ("pursuer", "evader"):
        if "network" in experiment.get(team, {}):
            experiment[team]["network"].update(changes)
    return tree


def with_network(run_copy: Path, changes: dict, source: str) -> None:
    """Rewrites a policy-only copy (`ship`'s output) with `changes` (`nearest_k`, `length_unit`)
    in both teams' network configs; records where it came from. Parameters are untouched."""
    _check_changes(changes)
    step = store.latest_step(run_copy)
    meta_file = run_copy / store.CHECKPOINT_DIR / str(step) / "meta" / "metadata"
    meta = json.loads(meta_file.read_text())
    before = copy.deepcopy(meta["network_configs"])
    meta_file.write_text(json.dumps(_set_network(meta, changes)))
    config_file = run_copy / "config.json"
    config = _set_network(json.loads(config_file.read_text()), changes)
    config["derived_from"] = {"run": source, "network_configs": before, **changes}
    config_file.write_text(json.dumps(config, indent=2, sort_keys=True) + "\n")
    store.read_meta(run_copy)  # still valid


if __name__ == "__main__":
    ship(tyro.cli(Args))
