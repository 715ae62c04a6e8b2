"""IPPO co-evolution: both teams' policies trained together from the same jitted rollouts.

One parameter set per team (parameter sharing, paper III); agents are folded into the batch. One
training iteration, jitted whole, reads top to bottom:

  1. rollout: `unroll_length` steps of `num_envs` arenas (auto-reset draws fresh arenas),
     learned teams sample from their masked categorical policy, fixed teams run their policy;
  2. per-team running observation normalisation (Brax `running_statistics`, one statistic per
     entity type and feature, so it does not depend on entity counts);
  3. per-team GAE (Brax `compute_gae` on [T, B, A] arrays): an agent's trajectory terminates when
     it is incapacitated or the episode terminates; transitions of agents already incapacitated
     are masked out of every loss. Time-limit truncation follows Brax: the truncated step is
     dropped and the step before it bootstraps from the value of its next observation;
  4. `update_epochs` passes of clipped PPO over shuffled minibatches, per learned team
     (Brax `gradient_update_fn`, optax Adam with global-norm clipping and a linear schedule).

With `ExperimentConfig.pool` a learned team (or both) plays each arena against a member of an
opponent pool instead (`pe_mjx.ppo.pool`); off by default, when nothing of it is built or traced.

Data parallelism: the env batch axis is sharded over every device of a `jax.sharding.Mesh`
(all local devices, or all processes' devices after `jax.distributed.initialize`); parameters
are replicated and XLA inserts the gradient all-reduce, so the same code runs on 1 or N devices.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from brax.training import gradients
from brax.training.acme import running_statistics
from flax import struct

from pe_mjx.env import AutoResetWrapper, PursuitEvasionEnv, State
from pe_mjx.episodes import play_episodes
from pe_mjx.experiment import ExperimentConfig
from pe_mjx.names import BUILTIN_POLICIES as FIXED_POLICIES
from pe_mjx.names import TEAMS, other_team
from pe_mjx.networks import log_prob, make_network, sample_actions
from pe_mjx.policy.core import Policy
from pe_mjx.policy.inference import (
    in_length_unit,
    init_normalizer,
    learned_policy,
    length_scale,
    normalize_obs,
    update_normalizer,
)
from pe_mjx.policy.scripted import make_policy
from pe_mjx.ppo.losses import TeamBatch, ppo_loss, team_targets
from pe_mjx.ppo.pool import POOL_STREAM, PoolState, make_pools, opponent_mask, settle


@struct.dataclass
class TeamState:
    """A learned team's parameters, optimiser state and observation statistics."""

    params: Any
    opt_state: Any
    normalizer: dict[str, running_statistics.RunningStatisticsState]


VALUE_HEAD = ("value_hidden_", "value_out")
"""Name prefixes of the value head's parameters in `networks.ActorCritic`."""


def _critic_first(loss_fn: Callable[..., Any], live: jax.Array) -> Callable[..., Any]:
    """`loss_fn` with the gradient of every parameter outside the value head multiplied by `live`
    (0.0 while the critic warms up, then 1.0); its value is unchanged. For Brax's
    `gradient_update_fn`, which then takes zero gradients for the actor and the encoder."""

    def scaled(path: tuple, x: jax.Array) -> jax.Array:
        if any(str(getattr(k, "key", k)).startswith(VALUE_HEAD) for k in path):
            return x
        return live * x + (1.0 - live) * jax.lax.stop_gradient(x)

    def wrapped(params: Any, *args: Any, **kwargs: Any) -> Any:
        return loss_fn(jax.tree_util.tree_map_with_path(scaled, params), *args, **kwargs)

    return wrapped


@struct.dataclass
class TrainState:
    teams: dict[str, TeamState]
    # Each pool's state keyed by the team that faces it; None (no leaves) without a pool: the
    # state is as it always was.
    pool: dict[str, PoolState] | None
    env_state: State  # batched [num_envs]
    rng: jax.Array
    iteration: jax.Array  # int32 []
    env_steps: jax.Array  # int32 [] (float64 is off by default; 2^31 env steps is plenty)


class Trainer:
    """Builds the jitted training iteration and evaluation for one `ExperimentConfig`.

    `opponents` holds a ready policy for each team that does not learn (built by the caller from
    the config's policy spec, e.g. with `pe_mjx.ppo.run.resolve_opponents`); "scripted" and
    "random" are built here when not given. `pool_members` the same for the pools' fixed members
    (`config.pool.fixed`), keyed by (the team that plays it, its spec), e.g. from
    `pe_mjx.ppo.run.resolve_pool_members`.
    """

    def __init__(
        self,
        config: ExperimentConfig,
        opponents: dict[str, Policy] | None = None,
        mesh: jax.sharding.Mesh | None = None,
        pool_members: dict[tuple[str, str], Policy] | None = None,
    ):
        self.config = config
        self.env_config = config.env
        self.env = AutoResetWrapper(PursuitEvasionEnv(self.env_config, backend=config.backend))
        self.eval_env = PursuitEvasionEnv(self.env_config, backend=config.backend)
        self.learned = config.learned
        self.network_configs = {t: config.network(t) for t in self.learned}
        self.networks = {
            t: make_network(self.network_configs[t], self.env_config.team(t).num_actions)
            for t in self.learned
        }
        self.fixed: dict[str, Policy] = dict(opponents or {})
        for team in TEAMS:
            spec = config.team(team).policy
            if team in self.learned or team in self.fixed:
                continue
            if spec not in FIXED_POLICIES:
                raise ValueError(
                    f"the {team} policy {spec!r} must be handed in as an opponent "
                    f"(Trainer builds only {FIXED_POLICIES})"
                )
            self.fixed[team] = make_policy(spec, self.env_config, team)
        self.scripted = {t: make_policy("scripted", self.env_config, t) for t in TEAMS}
        members = dict(pool_members or {})

        def pool_member(spec: str, team: str) -> Policy:
            if (team, spec) in members:
                return members[team, spec]
            if spec not in FIXED_POLICIES:
                raise ValueError(
                    f"the {team} pool member {spec!r} must be handed in as a pool member "
                    f"(Trainer builds only {FIXED_POLICIES})"
                )
            return make_policy(spec, self.env_config, team)

        self.pools = make_pools(config.pool, self.networks, pool_member)
        """The opponent pools keyed by the team that faces each (`pe_mjx.ppo.pool`): the pool
        that stands in for team T's policy is `pools[other_team(T)]`."""
        self.mesh = mesh or jax.sharding.Mesh(np.array(jax.devices()), ("data",))
        n_dev = self.mesh.devices.size
        if config.ppo.num_envs % n_dev:
            raise ValueError(
                f"invalid config: ppo.num_envs={config.ppo.num_envs} must be a multiple of the "
                f"{n_dev} devices"
            )
        if config.eval_envs % n_dev:
            raise ValueError(f"invalid config: eval_envs must be a multiple of {n_dev} devices")
        self.batch_sharding = jax.sharding.NamedSharding(
            self.mesh, jax.sharding.PartitionSpec("data")
        )
        self.replicated = jax.sharding.NamedSharding(self.mesh, jax.sharding.PartitionSpec())
        self.optimizers = {
            t: optax.chain(
                optax.clip_by_global_norm(config.ppo.max_grad_norm),
                optax.adam(self.schedule(t)),
            )
            for t in self.learned
        }

    def schedule(self, team: str) -> optax.Schedule | float:
        """The team's learning rate per gradient step (its own `learning_rate` if set, else
        `ppo.learning_rate`; decayed linearly to 0 over the budget unless constant). A constant
        rate stays a float: optax's Adam then keeps no step count, and checkpoints keep their
        structure."""
        ppo = self.config.ppo
        lr = self.config.team(team).learning_rate or ppo.learning_rate
        if ppo.lr_schedule == "constant":
            return lr
        updates_per_iter = ppo.update_epochs * ppo.num_minibatches
        return optax.linear_schedule(
            lr, 0.0, transition_steps=self.config.num_iterations * updates_per_iter
        )

    # ------------------------------------------------------------------ init

    def _shard_batch(self, tree: Any) -> Any:
        return jax.lax.with_sharding_constraint(tree, self.batch_sharding)

    def init(self, seed: int | None = None) -> TrainState:
        seed = self.config.seed if seed is None else seed
        # The key is made inside the jitted function: in a group of processes every input of a
        # computation over all devices must be global, and a constant is.
        return jax.jit(lambda: self._init(jax.random.key(seed)))()

    def state_shardings(self, state: TrainState) -> Any:
        """Where each leaf of a train state lives: the env batch split over the mesh, the rest
        replicated. Empty arrays (a lone evader's teammates) are replicated too, as XLA places
        them in a compiled program: its inputs must come in the shardings it was compiled for."""
        return state.replace(
            env_state=jax.tree.map(
                lambda x: self.batch_sharding if np.size(x) else self.replicated, state.env_state
            ),
            teams=jax.tree.map(lambda _: self.replicated, state.teams),
            pool=None
            if state.pool is None
            else {
                team: jax.tree.map(lambda _: self.replicated, pool).replace(
                    member=self.batch_sharding
                )
                for team, pool in state.pool.items()
            },
            rng=self.replicated,
            iteration=self.replicated,
            env_steps=self.replicated,
        )

    def abstract_state(self) -> TrainState:
        """Shapes and dtypes of a `TrainState` (for restoring a checkpoint), computing nothing."""
        return jax.eval_shape(self._init, jax.random.key(0))

    def _init(self, rng: jax.Array) -> TrainState:
        pool_rng = jax.random.fold_in(rng, POOL_STREAM)  # its own stream: the others as before
        rng, env_rng, *net_rngs = jax.random.split(rng, 2 + len(TEAMS))
        env_keys = jax.random.split(env_rng, self.config.ppo.num_envs)
        env_state = self._shard_batch(jax.vmap(self.env.reset)(env_keys))
        teams = {}
        for team, net_rng in zip(TEAMS, net_rngs, strict=True):
            if team not in self.learned:
                continue
            obs = jax.tree.map(lambda x: x[0], env_state.obs[team])
            params = self.networks[team].init(net_rng, obs)
            teams[team] = TeamState(
                params=params,
                opt_state=self.optimizers[team].init(params),
                normalizer=init_normalizer(obs),
            )
        pool = None
        if self.pools:
            pool = {}
            for i, (team, team_pool) in enumerate(self.pools.items()):
                # One pool: its stream as ever; both: each folded with its index.
                key = pool_rng if len(self.pools) == 1 else jax.random.fold_in(pool_rng, i)
                opponent = teams[team_pool.opponent]
                pool[team] = team_pool.init(
                    key, opponent.params, opponent.normalizer, self.config.ppo.num_envs
                )
            pool = settle(pool)
        state = TrainState(
            teams=teams,
            pool=pool,
            env_state=env_state,
            rng=rng,
            iteration=jnp.zeros((), jnp.int32),
            env_steps=jnp.zeros((), jnp.int32),
        )
        return jax.lax.with_sharding_constraint(state, self.state_shardings(state))

    # ------------------------------------------------------------------ rollout

    def _act(
        self,
        teams: dict[str, TeamState],
        obs: dict[str, dict[str, jax.Array]],
        rng: jax.Array,
        pool: dict[str, PoolState] | None = None,
        raw_obs: dict[str, dict[str, jax.Array]] | None = None,
    ) -> tuple[dict[str, jax.Array], dict[str, dict[str, jax.Array]]]:
        """Actions for both teams on batched obs [B, A, ...] (a learned team's already in its
        network's length unit: `_inputs`; `raw_obs` as the env gives them); extras for learned
        teams. With a `pool`, a pool team's opponent plays each arena's member."""
        actions, extras = {}, {}
        keys = dict(zip(TEAMS, jax.random.split(rng, len(TEAMS)), strict=True))
        for team in TEAMS:
            team_obs = obs[team]
            if team in self.learned:
                ts = teams[team]
                logits, value = self.networks[team].apply(
                    ts.params, normalize_obs(team_obs, ts.normalizer)
                )
                facing = other_team(team)  # the team whose pool stands in for this one
                if pool is not None and facing in self.pools:
                    action = self.pools[facing].act(
                        pool[facing], team_obs, raw_obs[team], logits, keys[team]
                    )
                else:
                    action = sample_actions(logits, keys[team])
                extras[team] = {"log_prob": log_prob(logits, action), "value": value}
            else:
                batch = team_obs["own"].shape[0]
                action = jax.vmap(self.fixed[team])(team_obs, jax.random.split(keys[team], batch))
            actions[team] = action.astype(jnp.int32)
        return actions, extras

    def _inputs(self, team: str, obs: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """A learned team's observations in its network's length unit (statistics and updates
        see them so; `NetworkConfig.length_unit`)."""
        scale = length_scale(self.network_configs[team], self.env_config)
        return obs if scale is None else in_length_unit(obs, scale)

    def _rollout(
        self, ts: TrainState, rng: jax.Array
    ) -> tuple[tuple[State, dict[str, PoolState] | None], dict[str, Any]]:
        def step(carry: tuple[State, dict[str, PoolState] | None], key: jax.Array):
            env_state, pool = carry
            obs = dict(env_state.obs)
            for team in self.learned:  # once per step: acting and the stored data share it
                obs[team] = self._inputs(team, obs[team])
            actions, extras = self._act(ts.teams, obs, key, pool, env_state.obs)
            next_state = self.env.step_batch(env_state, actions)
            next_state = self._shard_batch(next_state)
            data = {}
            for team in self.learned:
                scale = self.config.team(team).reward_scale
                valid = next_state.info["valid"][team]
                facing = other_team(team)
                if pool is not None and facing in self.pools:  # its own policy's data only
                    valid = opponent_mask(valid, pool[facing].member)
                active_after = next_state.info["active"][team]
                data[team] = {
                    "obs": obs[team],
                    "action": actions[team],
                    "log_prob": extras[team]["log_prob"],
                    "value": extras[team]["value"],
                    "reward": next_state.reward[team] * scale,
                    "valid": valid,
                    "termination": (
                        next_state.info["terminated"][:, None] | ~active_after | ~valid
                    ).astype(jnp.float32),
                    "truncation": (next_state.info["truncation"][:, None] * valid),
                }
            data["metrics"] = next_state.metrics
            data["team_reward"] = {t: jnp.sum(next_state.reward[t], axis=-1) for t in TEAMS}
            data["done"] = next_state.done
            if pool is not None:
                # The members that played this step, per pool team.
                data["pool_member"] = {team: p.member for team, p in pool.items()}
                ended = next_state.done > 0
                pool = settle({t: self.pools[t].redraw(p, ended) for t, p in pool.items()})
            return (next_state, pool), data

        keys = jax.random.split(rng, self.config.ppo.unroll_length)
        return jax.lax.scan(step, (ts.env_state, ts.pool), keys)

    # ------------------------------------------------------------------ update

    def _team_batch(self, team: str, ts: TeamState, data: dict, bootstrap: jax.Array) -> TeamBatch:
        cfg = self.config.ppo
        advantages, returns, mask = team_targets(data, bootstrap, cfg.gamma, cfg.gae_lambda)
        obs = normalize_obs(data["obs"], ts.normalizer)
        batch = TeamBatch(
            obs=obs,
            actions=data["action"],
            log_prob=data["log_prob"],
            advantages=advantages,
            returns=returns,
            mask=mask,
        )

        def fold(x):  # [T, B, A, ...] -> [T * B * A, ...]
            return x.reshape((x.shape[0] * x.shape[1] * x.shape[2], *x.shape[3:]))

        return jax.tree.map(fold, batch)

    def _update_team(
        self, team: str, ts: TeamState, batch: TeamBatch, rng: jax.Array, iteration: jax.Array
    ) -> tuple[TeamState, dict[str, jax.Array]]:
        cfg = self.config.ppo
        network = self.networks[team]
        loss_fn = functools.partial(
            ppo_loss,
            apply_fn=network.apply,
            clip_epsilon=cfg.clip_epsilon,
            value_coef=cfg.value_coef,
            entropy_coef=cfg.entropy_coef,
        )
        warmup = self.config.team(team).critic_warmup
        if warmup:  # a run without one keeps exactly Brax's update
            loss_fn = _critic_first(loss_fn, live=(iteration >= warmup).astype(jnp.float32))
        update = gradients.gradient_update_fn(loss_fn, self.optimizers[team], None, has_aux=True)
        n = batch.actions.shape[0]
        mb = n // cfg.num_minibatches

        def minibatch_step(carry, mb_batch):
            params, opt_state = carry
            (_, metrics), params, opt_state = update(params, mb_batch, optimizer_state=opt_state)
            return (params, opt_state), metrics

        def epoch(carry, key):
            perm = jax.random.permutation(key, n)[: mb * cfg.num_minibatches]
            shuffled = jax.tree.map(
                lambda x: x[perm].reshape((cfg.num_minibatches, mb, *x.shape[1:])), batch
            )
            return jax.lax.scan(minibatch_step, carry, shuffled)

        keys = jax.random.split(rng, cfg.update_epochs)
        (params, opt_state), metrics = jax.lax.scan(epoch, (ts.params, ts.opt_state), keys)
        metrics = jax.tree.map(jnp.mean, metrics)
        return ts.replace(params=params, opt_state=opt_state), metrics

    def iteration(self, ts: TrainState) -> tuple[TrainState, dict[str, jax.Array]]:
        """One training iteration (rollout, normalisation, GAE, PPO); jit it."""
        rng, rollout_rng, update_rng = jax.random.split(ts.rng, 3)
        (env_state, pool), data = self._rollout(ts, rollout_rng)
        metrics: dict[str, jax.Array] = {}
        teams = dict(ts.teams)
        update_keys = dict(zip(TEAMS, jax.random.split(update_rng, len(TEAMS)), strict=True))
        for team in self.learned:
            team_ts = teams[team]
            team_data = data[team]
            normalizer = update_normalizer(team_ts.normalizer, team_data["obs"], team_data["valid"])
            team_ts = team_ts.replace(normalizer=normalizer)
            _, bootstrap = self.networks[team].apply(
                team_ts.params, normalize_obs(self._inputs(team, env_state.obs[team]), normalizer)
            )
            batch = self._team_batch(team, team_ts, team_data, bootstrap)
            team_ts, losses = self._update_team(
                team, team_ts, batch, update_keys[team], ts.iteration
            )
            teams[team] = team_ts
            for k, v in losses.items():
                metrics[f"loss/{team}/{k}"] = v
        # Env metrics: per-step ones (reward terms, invalid actions) averaged per step and arena;
        # episode stats over finished ones.
        done = data["done"]
        finished = jnp.maximum(jnp.sum(done), 1.0)
        for k, v in data["metrics"].items():
            if not k.startswith("episode/"):
                metrics[k] = jnp.mean(v)
            else:
                # NaN when no arena finished this iteration: the logger skips it.
                metrics[k] = jnp.where(jnp.sum(done) > 0, jnp.sum(v * done) / finished, jnp.nan)
        metrics["episode/finished"] = jnp.sum(done)
        for team, reward in data["team_reward"].items():
            # The team's reward (summed over its agents, unscaled) per step and arena.
            metrics[f"reward/{team}/total"] = jnp.mean(reward)
        if pool is not None:
            snapshots = {}
            for team, team_pool in self.pools.items():
                metrics.update(team_pool.metrics(data))
                opponent = teams[team_pool.opponent]
                snapshots[team] = team_pool.snapshot(
                    pool[team], opponent.params, opponent.normalizer, ts.iteration + 1
                )
            pool = snapshots
        steps = self.config.steps_per_iteration
        new_ts = TrainState(
            teams=teams,
            pool=pool,
            env_state=env_state,
            rng=rng,
            iteration=ts.iteration + 1,
            env_steps=ts.env_steps + steps,
        )
        return new_ts, metrics

    # ------------------------------------------------------------------ evaluation

    def policies(self, ts: TrainState) -> dict[str, Policy]:
        """Current policy per team: learned ones from `ts`, fixed ones as configured."""
        out = dict(self.fixed)
        for team in self.learned:
            team_ts = ts.teams[team]
            variables = {"params": team_ts.params, "normalizer": team_ts.normalizer}
            out[team] = learned_policy(
                team,
                self.networks[team],
                self.network_configs[team],
                variables,
                env_config=self.env_config,
            )
        return out

    def evaluate(self, ts: TrainState, rng: jax.Array) -> dict[str, jax.Array]:
        """Each learned team against the scripted opponent, `eval_envs` full episodes each.

        Keys `eval/<team>_vs_scripted/<metric>`: the env's `episode/*` metrics averaged over the
        episodes, and `<team>_return`, the team's episodic return (unscaled rewards summed over
        the episode, averaged over its agents and the episodes).

        With a pool, also each pool team against its newest snapshot (`<team>_vs_snapshot`) and
        against each fixed member other than scripted (`<team>_vs_random`), after the above
        (which therefore draw the keys they drew without a pool)."""
        metrics = {}
        current = self.policies(ts)
        pairs = [(team, "scripted", self.scripted[other_team(team)]) for team in self.learned]
        for team, team_pool in self.pools.items():
            opponent = team_pool.opponent
            snapshot = learned_policy(
                opponent,
                self.networks[opponent],
                self.network_configs[opponent],
                team_pool.latest(ts.pool[team]),
                env_config=self.env_config,
            )
            pairs += team_pool.eval_opponents(snapshot)
        for team, name, opponent_policy in pairs:
            other = other_team(team)
            pair = {team: current[team], other: opponent_policy}
            rng, key = jax.random.split(rng)
            keys = self._shard_batch(jax.random.split(key, self.config.eval_envs))
            final, returns = play_episodes(self.eval_env, pair, keys, returns=True)
            for k, v in final.metrics.items():
                if k.startswith("episode/"):
                    metrics[f"eval/{team}_vs_{name}/{k[len('episode/') :]}"] = jnp.mean(v)
            metrics[f"eval/{team}_vs_{name}/{team}_return"] = jnp.mean(returns[team])
        return metrics
