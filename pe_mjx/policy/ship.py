"""Ship one checkpoint of a `pe-mjx train` run as a policy-only copy (`pe-mjx ship RUN NAME`).

The copy is a packed policy (`pe_mjx.policy.packed`): the run's config.json and one
`policy.msgpack` with the chosen checkpoint's (default: the latest) metadata and its teams'
parameters and observation statistics: no optimiser or arena state, so the shipped policy plays
(`pe-mjx view/evaluate --pursuers NAME`) but cannot be resumed. The source may be a training run
or another packed policy. By default it goes into the
package (pe_mjx/assets/policies/NAME, linked from assets/policies/NAME in a checkout, as the
other shipped policies are); `dest` writes DEST/NAME instead, outside the package (no link). The
model card is written by hand in assets/policies/README.md.

`nearest_k` ships the same parameters with *local attention* (both teams' networks keep only the
k nearest entities of each type, `NetworkConfig.nearest_k`) and `length_unit` reading neighbour
distances in units of that many metres in any arena (`NetworkConfig.length_unit`) instead of in
arena radii. The encoders' parameters do not depend on either, so this changes what the network
reads, not what it learned: no training. The copy records both and `derived_from` (the run, its
step and its former network configs). Such a copy of a packed policy, shipped beside it (into the
same directory), shares its parameters file rather than holding the parameters again
(`pe_mjx.policy.packed`, version 2): a few kB instead of a few hundred, and it plays only while
that policy stays as it was (it fails with one line naming both otherwise).

Every failure is a `ValueError` naming the flag or the path, before anything is written.
"""

from __future__ import annotations

import copy
import json
import os
import re
import shutil
from pathlib import Path
from typing import Any

from pe_mjx import outputs
from pe_mjx.experiment import NetworkConfig
from pe_mjx.names import BUILTIN_POLICIES, POLICY_NAME
from pe_mjx.policy import packed, store
from pe_mjx.policy.shipped import policies_dir, resolve_run

CHECKOUT_LINKS = Path(__file__).resolve().parents[2] / "assets" / "policies"
"""Where a checkout links the packaged policies from (absent in an installed package)."""


def ship_policy(
    run: Path,
    name: str,
    step: int | None = None,
    replace: bool = False,
    dest: Path | None = None,
    nearest_k: int | None = None,
    length_unit: float | None = None,
) -> tuple[Path, dict[str, Any]]:
    """Writes the policy-only copy of `run` as `name`; returns its path and the checkpoint's
    metadata (with its step and env steps)."""
    changes = {"nearest_k": nearest_k, "length_unit": length_unit}
    changes = {k: v for k, v in changes.items() if v is not None}
    check_changes(changes)  # before anything is copied
    check_name(name)
    meta = store.read_meta(run, step)  # validates the run and the step
    step = meta["step"]
    target = (dest or policies_dir()) / name
    if target.exists() and not replace:
        raise ValueError(f"{target} exists (--replace to replace it)")
    policies = {
        team: store.restore_policy_params(run, team, step=step).variables
        for team in meta["network_configs"]
    }
    source = resolve_run(run)
    config = _read_config(source / "config.json")
    packed_meta = {k: v for k, v in meta.items()}
    # A derived copy beside its packed source shares the parameters' file (its owner is the
    # source or the source's own owner, always in the source's directory).
    beside = source.resolve().parent == target.parent.resolve()
    shared = packed.owner(source) if changes and beside and packed.is_packed(source) else None
    if shared is not None and shared.name == name:  # replacing its own owner: a whole copy
        shared = None
    if changes:
        before = copy.deepcopy(meta["network_configs"])
        _set_network(packed_meta, changes)
        _set_network(config, changes)
        config["derived_from"] = {
            "run": f"{run}{_STEP}{step}",
            "network_configs": before,
            **changes,
        }
    # Built in a temporary beside the target, then one rename: a failure or Ctrl-C midway
    # leaves the target as it was (`pe_mjx.outputs`).
    target.parent.mkdir(parents=True, exist_ok=True)
    stage = outputs.temp_path(target, keep_suffix=False)
    stage.mkdir()
    try:
        if shared is None:
            packed.write(stage, packed_meta, policies)
        else:
            packed.write(stage, packed_meta, parameters_of=shared)
        (stage / "config.json").write_text(json.dumps(config, indent=2, sort_keys=True) + "\n")
        if target.exists():  # --replace
            shutil.rmtree(target)
        os.replace(stage, target)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    link = CHECKOUT_LINKS / name
    if dest is None and CHECKOUT_LINKS.is_dir() and not link.is_symlink():
        link.symlink_to(Path("../../pe_mjx/assets/policies") / name)
    store.read_meta(target)  # the shipped copy reads back
    return target, meta


_STEP = " step "
"""Between the source and its step in `derived_from.run` ("train/runs/x step 1465")."""


def derived_source(config: dict[str, Any]) -> str | None:
    """The run or policy a shipped copy's `config.json` (as a dict) was derived from with
    --nearest-k or --length-unit, as it was named when shipped; None for any other config."""
    derived = config.get("derived_from")
    return derived["run"].rsplit(_STEP, 1)[0] if isinstance(derived, dict) else None


def check_name(name: str) -> None:
    """A name that `--pursuers NAME` can give back: letters, digits, `.`, `_` and `-` (a newline
    or a lone space made a directory that nothing could name), not a builtin policy's (a
    shipped "scripted" was never played: the builtin wins)."""
    if not re.fullmatch(POLICY_NAME, name):
        raise ValueError(
            f"NAME: bad name {name!r} (a plain name such as mix-20-5-8: letters, digits, '.', "
            "'_' and '-', at most 100)"
        )
    if name in BUILTIN_POLICIES:
        raise ValueError(f"NAME: {name!r} is a builtin policy's name; choose another")


MAX_CONFIG_BYTES = 1 << 20


def _read_config(path: Path) -> dict[str, Any]:
    """A run's config.json, read with a byte cap (ValueError naming it when unreadable)."""
    try:
        # Through the capped reader: a FIFO here waited for a writer forever.
        config = json.loads(outputs.read_bytes(path, MAX_CONFIG_BYTES))
        if not isinstance(config, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError, RecursionError) as err:
        raise ValueError(f"{path}: cannot be read as a run's config ({err})") from None
    return config


def check_changes(changes: dict[str, Any]) -> None:
    """`NetworkConfig`'s own checks of the changed fields, as one line naming the flag."""
    try:
        NetworkConfig(**changes)
    except ValueError as err:
        field, _, problem = str(err).removeprefix("invalid config: ").partition(" ")
        raise ValueError(f"--{field.replace('_', '-')} {problem}") from None


def _set_network(tree: dict, changes: dict) -> dict:
    """Sets `changes` in every network config of a run's config or metadata tree."""
    for net in tree.get("network_configs", {}).values():
        net.update(changes)
    experiment = tree.get("experiment", {})
    for team in ("pursuer", "evader"):
        if "network" in experiment.get(team, {}):
            experiment[team]["network"].update(changes)
    return tree
