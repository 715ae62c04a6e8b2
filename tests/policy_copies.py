"""Policy copies in the orbax layout that training writes (`checkpoints/<step>/meta` and
`policy_<team>` items), made from a shipped (packed) policy: the tests of damaged orbax
checkpoints damage these."""

from __future__ import annotations

import shutil
from pathlib import Path

import orbax.checkpoint as ocp

from pe_mjx.policy import store
from pe_mjx.policy.shipped import resolve_run


def orbax_copy(name: str, dest: Path) -> Path:
    """Writes shipped policy `name` to `dest` as an orbax policy-only run directory."""
    meta = store.read_meta(name)
    policies = {t: store.restore_policy_params(name, t).variables for t in meta["network_configs"]}
    dest.mkdir(parents=True)
    shutil.copy2(resolve_run(name) / "config.json", dest / "config.json")
    saved = {k: v for k, v in meta.items() if k != "step"}
    items = {f"policy_{t}": ocp.args.StandardSave(p) for t, p in policies.items()}
    with store.manager(dest, create=True) as mngr:
        mngr.save(meta["step"], args=ocp.args.Composite(meta=ocp.args.JsonSave(saved), **items))
        mngr.wait_until_finished()
    return dest
