"""Checkpoints (orbax, no pickle): the full train state for `--resume`, the policies, and configs.

A run directory holds `checkpoints/<iteration>/` with three orbax items:
  * `train`: the whole `TrainState` (parameters, optimiser and normaliser state, the env batch,
    RNG keys as raw key data, counters), so a resumed run continues bit-for-bit;
  * `policy_<team>`: per learned team, its parameters and observation statistics (what
    `load_policy` reads, without rebuilding any env);
  * `meta`: JSON with the whole experiment config, the env and network configs it resolved to,
    counters and the format version. Format 1 (before the experiment config) is still read for
    playing its policies; only format 2 runs can be resumed.
Orbax writes each step into a temporary directory and renames it when complete, so a kill during
a save leaves the previous step loadable; `CheckpointManager` keeps the last `MAX_TO_KEEP`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from pe_mjx.agents import init_normalizer, learned_policy
from pe_mjx.config import TEAMS, EnvConfig
from pe_mjx.env import AGENT_FEATURES, OBSTACLE_FEATURES, OWN_FEATURES
from pe_mjx.networks import NetworkConfig, make_network
from pe_mjx.ppo.train import Trainer, TrainState
from pe_mjx.shipped import resolve_run

FORMAT_VERSION = 2
READABLE_FORMATS = (1, 2)
MAX_TO_KEEP = 3
CHECKPOINT_DIR = "checkpoints"


class CheckpointError(ValueError):
    """A missing, unreadable or mismatched checkpoint."""


def _short(err: Exception, limit: int = 300) -> str:
    text = f"{type(err).__name__}: {err}"
    return text if len(text) <= limit else text[:limit] + " ..."


def _is_key(x: Any) -> bool:
    return hasattr(x, "dtype") and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def keys_to_data(tree: Any) -> Any:
    """Typed PRNG keys -> raw uint32 key data (orbax stores plain arrays)."""
    return jax.tree.map(lambda x: jax.random.key_data(x) if _is_key(x) else x, tree)


def data_to_keys(template: Any, tree: Any) -> Any:
    """Inverse of `keys_to_data`, guided by a template that has the typed keys."""
    return jax.tree.map(
        lambda t, x: jax.random.wrap_key_data(x) if _is_key(t) else x, template, tree
    )


def _flat(tree: Any) -> dict[str, Any]:
    """Leaves by position ("l00000", ...), without zero-size ones (orbax refuses to save those;
    a 1-evader scene has an empty teammate axis)."""
    return {f"l{i:05d}": x for i, x in enumerate(jax.tree.leaves(tree)) if np.size(x)}


def _unflat(template: Any, flat: dict[str, Any]) -> Any:
    leaves, treedef = jax.tree.flatten(template)
    values = [
        flat[f"l{i:05d}"] if np.size(t) else np.zeros(t.shape, t.dtype)
        for i, t in enumerate(leaves)
    ]
    return jax.tree.unflatten(treedef, values)


def _manager(run_dir: Path, create: bool) -> ocp.CheckpointManager:
    options = ocp.CheckpointManagerOptions(max_to_keep=MAX_TO_KEEP, create=create)
    return ocp.CheckpointManager(
        (run_dir / CHECKPOINT_DIR).absolute(),
        options=options,
        item_names=("train", "meta", *(f"policy_{t}" for t in TEAMS)),
    )


def save(run_dir: str | Path, trainer: Trainer, train_state: TrainState) -> int:
    """Writes a checkpoint of `train_state` (blocking); returns its iteration."""
    run_dir = Path(run_dir)
    step = int(train_state.iteration)
    policies = {
        f"policy_{team}": ocp.args.StandardSave({"params": ts.params, "normalizer": ts.normalizer})
        for team, ts in train_state.teams.items()
    }
    meta = {
        "format_version": FORMAT_VERSION,
        "iteration": step,
        "env_steps": int(train_state.env_steps),
        "experiment": trainer.config.to_dict(),
        "env_config": trainer.env_config.to_dict(),
        "network_configs": {t: c.to_dict() for t, c in trainer.network_configs.items()},
        "num_actions": {t: trainer.env_config.team(t).num_actions for t in TEAMS},
    }
    with _manager(run_dir, create=True) as mngr:
        mngr.save(
            step,
            args=ocp.args.Composite(
                train=ocp.args.StandardSave(_flat(keys_to_data(train_state))),
                **policies,
                meta=ocp.args.JsonSave(meta),
            ),
            force=True,
        )
        mngr.wait_until_finished()
    return step


def _latest_step(run_dir: Path) -> int:
    if not run_dir.exists():
        raise CheckpointError(f"no run at {run_dir}: the directory does not exist")
    if not (run_dir / CHECKPOINT_DIR).is_dir():
        raise CheckpointError(f"{run_dir} holds no checkpoints (no {CHECKPOINT_DIR}/ directory)")
    with _manager(run_dir, create=False) as mngr:
        step = mngr.latest_step()
    if step is None:
        raise CheckpointError(f"{run_dir} holds no complete checkpoint")
    return step


def read_meta(run_dir: str | Path, step: int | None = None) -> dict[str, Any]:
    """The JSON metadata of the latest (or given) checkpoint, validated. `run_dir` may also be
    a shipped policy's name (`pe_mjx.shipped`)."""
    run_dir = resolve_run(run_dir)
    step = _latest_step(run_dir) if step is None else step
    try:
        with _manager(run_dir, create=False) as mngr:
            meta = mngr.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore())).meta
    except Exception as err:  # orbax raises many types for a damaged step
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} is unreadable: {_short(err)}"
        ) from None
    required = ("format_version", "env_config", "network_configs", "num_actions")
    if not isinstance(meta, dict) or any(k not in meta for k in required):
        raise CheckpointError(f"checkpoint {step} in {run_dir} has malformed metadata")
    if meta["format_version"] not in READABLE_FORMATS:
        raise CheckpointError(
            f"checkpoint format {meta['format_version']!r} in {run_dir} is not supported "
            f"(this pe-mjx reads formats {READABLE_FORMATS})"
        )
    if meta["format_version"] >= 2 and "experiment" not in meta:
        raise CheckpointError(f"checkpoint {step} in {run_dir} has malformed metadata")
    meta["step"] = step
    return meta


def dummy_obs(env_config: EnvConfig, team: str) -> dict[str, jax.Array]:
    """Zero observations of one arena with the shapes of `env._observe` (for network init)."""
    a = env_config.team(team).num_agents
    other = env_config.team("evader" if team == "pursuer" else "pursuer").num_agents
    k = env_config.arena.num_obstacles
    n_act = env_config.team(team).num_actions
    return {
        "own": jnp.zeros((a, OWN_FEATURES)),
        "teammates": jnp.zeros((a, a - 1, AGENT_FEATURES)),
        "opponents": jnp.zeros((a, other, AGENT_FEATURES)),
        "obstacles": jnp.zeros((a, k, OBSTACLE_FEATURES)),
        "teammate_mask": jnp.ones((a, a - 1), bool),
        "opponent_mask": jnp.ones((a, other), bool),
        "obstacle_mask": jnp.ones((a, k), bool),
        "action_mask": jnp.ones((a, n_act), bool),
    }


def restore_policy_params(
    run_dir: str | Path, team: str
) -> tuple[Any, Any, NetworkConfig, dict[str, Any]]:
    """(network, {"params", "normalizer"}, network config, meta) of one team of a run (a run
    directory or a shipped policy's name)."""
    run_dir = resolve_run(run_dir)
    meta = read_meta(run_dir)
    if team not in TEAMS:
        raise CheckpointError(f"unknown team {team!r}; expected one of {TEAMS}")
    if team not in meta["network_configs"]:
        learned = ", ".join(meta["network_configs"]) or "none"
        raise CheckpointError(
            f"run {run_dir} did not learn a {team} policy (learned teams: {learned})"
        )
    try:
        env_config = EnvConfig.from_dict(meta["env_config"])
        net_config = NetworkConfig.from_dict(meta["network_configs"][team])
    except (TypeError, ValueError) as err:
        raise CheckpointError(f"checkpoint in {run_dir} has an invalid config: {err}") from None
    network = make_network(net_config, int(meta["num_actions"][team]))
    obs = dummy_obs(env_config, team)
    abstract = {
        "params": jax.eval_shape(network.init, jax.random.key(0), obs),
        "normalizer": jax.eval_shape(init_normalizer, obs),
    }
    try:
        with _manager(run_dir, create=False) as mngr:
            restored = mngr.restore(
                meta["step"],
                args=ocp.args.Composite(**{f"policy_{team}": ocp.args.StandardRestore(abstract)}),
            )[f"policy_{team}"]
    except Exception as err:
        raise CheckpointError(
            f"the {team} policy in {run_dir} (step {meta['step']}) cannot be restored: "
            f"{_short(err)}"
        ) from None
    return network, restored, net_config, meta


def load_policy(
    run_dir: str | Path,
    team: str,
    deterministic: bool = False,
    env_config: EnvConfig | None = None,
):
    """Rebuilds a team's policy from a run directory alone.

    Args:
      run_dir: a `pe-mjx train --out` directory, or the name of a shipped policy
        ("mix-20-5-8"; `pe_mjx.shipped.shipped_names()`).
      team: "pursuer" or "evader".
      deterministic: greedy actions instead of sampling.
      env_config: if given, checked for compatibility (the team's action count).

    Returns:
      A jittable `policy(obs, rng) -> int32 [...]`, obs being that team's observation dict with
      any leading dims ([A, ...] for one arena).
    """
    network, state, _, meta = restore_policy_params(run_dir, team)
    if env_config is not None:
        want = env_config.team(team).num_actions
        have = int(meta["num_actions"][team])
        if want != have:
            raise CheckpointError(
                f"the {team} policy in {run_dir} has {have} actions but this scene's {team}s "
                f"have {want}"
            )
    return learned_policy(network, state["params"], state["normalizer"], deterministic)


def read_experiment(run_dir: str | Path) -> dict[str, Any]:
    """The experiment config tree (a dict) saved with the latest checkpoint of a resumable run."""
    meta = read_meta(run_dir)
    if meta["format_version"] < 2:
        raise CheckpointError(
            f"{run_dir} was made by an older pe-mjx (checkpoint format {meta['format_version']}): "
            f"its policies can be played and evaluated, the run cannot be resumed"
        )
    return meta["experiment"]


def restore_train_state(run_dir: str | Path, trainer: Trainer) -> TrainState:
    """The full train state of the latest checkpoint, placed with the trainer's shardings.

    `trainer` is built from the run's saved experiment config.
    """
    run_dir = Path(run_dir)
    step = _latest_step(run_dir)
    if not (run_dir / CHECKPOINT_DIR / str(step) / "train").is_dir():
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} holds policies only (no train state): it can be "
            f"played and evaluated, not resumed"
        )
    template = trainer.abstract_state()
    abstract = jax.eval_shape(keys_to_data, template)
    try:
        with _manager(run_dir, create=False) as mngr:
            restored = mngr.restore(
                step, args=ocp.args.Composite(train=ocp.args.StandardRestore(_flat(abstract)))
            ).train
    except Exception as err:
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} cannot be restored: {_short(err)}"
        ) from None
    restored = _unflat(abstract, jax.tree.map(np.asarray, restored))
    restored = data_to_keys(template, restored)
    state = jax.tree.map(jnp.asarray, restored)
    env_state = jax.device_put(state.env_state, trainer.batch_sharding)
    teams = jax.device_put(state.teams, trainer.replicated)
    return state.replace(env_state=env_state, teams=teams)
