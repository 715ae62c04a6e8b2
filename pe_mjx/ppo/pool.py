"""Opponent pools: a learned team trains against the co-evolving opponent, its past snapshots
and fixed policies, each arena's opponent drawn per episode (`ExperimentConfig.pool`); with
`pool.team = "both"` each team faces such a pool of the other's.

Members are numbered per arena: 0 the opponent's current policy, 1..keep its snapshot slots,
keep+1.. the fixed policies in `PoolConfig.fixed` order. A `PoolState` per pool team lives in the
`TrainState` (`pool`, keyed by the team that faces it; so the checkpoint holds it and a resume
continues it exactly):

  * `params` / `normalizer`: the opponent's parameters and observation statistics at each
    snapshot, stacked [keep, ...], a ring buffer. The first snapshot is the opponent's initial
    policy (iteration 0), then one after every `snapshot_every`-th iteration; `count` says how
    many were taken, the last `min(count, keep)` are kept and drawn.
  * `member`: int32 [num_envs], the member each arena plays this episode. It is drawn at init
    and redrawn in every arena whose episode ended (in the same step as the env's auto-reset),
    from `rng`, a stream of its own: the pool draws no key from the rollout's or the update's
    streams, so with `p_current = 1` every other number is that of a run without a pool.

Acting (inside the jitted rollout, nothing recompiles per draw): the current policy's logits are
computed for every arena as without a pool; when `p_snapshots > 0` each arena's snapshot is
gathered from the stack ([num_envs, ...] parameters) and the network is vmapped over arenas with
them, so the cost is one more forward pass of the opponent whatever `keep` is (computing every
member and selecting would cost `keep` passes); the logits of the arena's member are then sampled
with the key the current policy uses. Fixed policies run on every arena and are selected (no
network). Measured (docs/benchmarks.md, MIX at 20-5-8 with 4 snapshots and the scripted policy):
an iteration takes 1.3x as long as without a pool, the rollout about 3x (the snapshot pass with
per-arena parameters, and the fixed policy on every arena; not split further).

Learning: the pool team learns from every arena. The co-evolving opponent learns only from the
transitions its current policy produced: in arenas where a snapshot or a fixed policy played,
its transitions are invalid (masked out of its losses, GAE and observation statistics), since
PPO's ratio and advantages are only meaningful for data of the policy being updated.

Both teams (`team = "both"`): two pools, each with the stream above folded with its team's
index, drawn independently; then, in an arena where both drew a non-current member, a coin from
the evader pool's stream keeps one of them and gives the other side its current opponent
(`settle`), so no arena is lost to both learners. Metrics are named per team
(`pool/<team>_vs_<kind>/...`); with one team they stay `pool/vs_<kind>/...`.

Fixed members may be learned (a shipped policy or a run directory, `PoolConfig.fixed`): the
caller resolves them for the opponent team (`pe_mjx.ppo.run.resolve_pool_members`) and the
Trainer hands them in; each then plays with its own parameters and observation statistics, on
every arena like a builtin one (one more forward pass per learned member and step).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from pe_mjx.experiment import PoolConfig
from pe_mjx.names import other_team
from pe_mjx.networks import sample_actions
from pe_mjx.policy.core import Policy
from pe_mjx.policy.inference import normalize_obs

POOL_STREAM = 0x9001
"""Folded into the run's key to start the pool's own random stream."""


@struct.dataclass
class PoolState:
    params: Any  # the opponent's parameters, stacked [keep, ...]
    normalizer: Any  # its observation statistics, stacked [keep, ...]
    count: jax.Array  # int32 []: snapshots taken so far
    member: jax.Array  # int32 [num_envs]: each arena's member this episode
    rng: jax.Array


class Pool:
    """The pool of `config` for the learned team `team`, whose opponent's network is `network`
    (`apply(params, obs) -> (logits, value)`) and fixed members `fixed`."""

    def __init__(self, config: PoolConfig, team: str, network: Any, fixed: dict[str, Policy]):
        self.config = config
        self.team = team
        self.opponent = other_team(team)
        self.network = network
        self.fixed = [fixed[spec] for spec in config.fixed]
        self.keep = config.keep
        self.kinds = ("current", "snapshot", *config.member_names)
        """Member kinds, as the metrics name them (`pool/vs_<kind>/...`)."""
        self.prefix = f"pool/{team}_vs_" if config.team == "both" else "pool/vs_"

    def kind_of(self, member: jax.Array) -> jax.Array:
        """Index into `kinds` of each member [...]."""
        return jnp.where(member == 0, 0, jnp.where(member <= self.keep, 1, member - self.keep + 1))

    # ------------------------------------------------------------------ state

    def init(self, rng: jax.Array, params: Any, normalizer: Any, num_envs: int) -> PoolState:
        """The pool at iteration 0: every slot holds the opponent's initial policy (counted as one
        snapshot), each arena's member drawn."""
        rng, key = jax.random.split(rng)
        filled = self._filled_with(params, normalizer)
        return PoolState(**filled, member=self.draw(key, filled["count"], num_envs), rng=rng)

    def refill(self, state: PoolState, params: Any, normalizer: Any) -> PoolState:
        """`state` with the opponent's initial policy replaced by `params` and `normalizer`
        (a warm start, `TeamTraining.init`), counted as the one snapshot taken."""
        return state.replace(**self._filled_with(params, normalizer))

    def _filled_with(self, params: Any, normalizer: Any) -> dict[str, Any]:
        """Every slot holding `params` and `normalizer`, counted as one snapshot."""
        stack = _stack(self.keep)
        return {
            "params": jax.tree.map(stack, params),
            "normalizer": jax.tree.map(stack, normalizer),
            "count": jnp.ones((), jnp.int32),
        }

    def draw(self, rng: jax.Array, count: jax.Array, n: int) -> jax.Array:
        """int32 [n] members: current with `p_current`, a kept snapshot (uniform over the
        `min(count, keep)` kept) with `p_snapshots`, a fixed policy (uniform) with `p_fixed`."""
        cfg = self.config
        kind_key, slot_key, fixed_key = jax.random.split(rng, 3)
        u = jax.random.uniform(kind_key, (n,))
        # Slots 0..count-1 fill first; once the ring is full every slot holds a kept snapshot.
        slot = jax.random.randint(slot_key, (n,), 0, jnp.minimum(count, self.keep))
        # Kinds with probability 0 are never drawn, whatever rounding left in the sum (`act`
        # skips the snapshots' forward pass when `p_snapshots` is 0).
        member = jnp.zeros((n,), jnp.int32)
        if cfg.p_snapshots > 0:
            member = jnp.where(u >= cfg.p_current, 1 + slot, member)
        if self.fixed:
            fixed = 1 + self.keep + jax.random.randint(fixed_key, (n,), 0, len(self.fixed))
            member = jnp.where(u >= cfg.p_current + cfg.p_snapshots, fixed, member)
        return member.astype(jnp.int32)

    def redraw(self, state: PoolState, done: jax.Array) -> PoolState:
        """New members for the arenas whose episode ended (`done` bool [num_envs])."""
        rng, key = jax.random.split(state.rng)
        fresh = self.draw(key, state.count, done.shape[0])
        return state.replace(member=jnp.where(done, fresh, state.member), rng=rng)

    def snapshot(
        self, state: PoolState, params: Any, normalizer: Any, iteration: jax.Array
    ) -> PoolState:
        """After iteration `iteration` (counted from 1): the opponent's `params` and `normalizer`
        replace the oldest snapshot when `iteration % snapshot_every == 0`."""
        due = iteration % self.config.snapshot_every == 0
        slot = state.count % self.keep

        def put(stack: jax.Array, x: jax.Array) -> jax.Array:
            return jnp.where(due, stack.at[slot].set(x), stack)

        return state.replace(
            params=jax.tree.map(put, state.params, params),
            normalizer=jax.tree.map(put, state.normalizer, normalizer),
            count=state.count + due.astype(jnp.int32),
        )

    def latest(self, state: PoolState) -> dict[str, Any]:
        """The variables (`params`, `normalizer`) of the newest snapshot."""
        slot = (state.count - 1) % self.keep
        return {
            "params": jax.tree.map(lambda x: x[slot], state.params),
            "normalizer": jax.tree.map(lambda x: x[slot], state.normalizer),
        }

    # ------------------------------------------------------------------ rollout

    def act(
        self,
        state: PoolState,
        obs: dict[str, jax.Array],
        raw_obs: dict[str, jax.Array],
        current_logits: jax.Array,
        rng: jax.Array,
    ) -> jax.Array:
        """int32 [B, A] actions of each arena's member.

        Args:
          obs: the opponent's observations [B, A, ...] in its network's length unit.
          raw_obs: the same as the env gives them (for fixed policies).
          current_logits: [B, A, n_act], the current policy's masked logits.
          rng: the key the current policy samples with.
        """
        member = state.member
        logits = current_logits
        if self.config.p_snapshots > 0:
            slot = jnp.clip(member - 1, 0, self.keep - 1)
            params = jax.tree.map(lambda x: x[slot], state.params)
            normalizer = jax.tree.map(lambda x: x[slot], state.normalizer)

            def one(p: Any, n: Any, o: dict[str, jax.Array]) -> jax.Array:
                return self.network.apply(p, normalize_obs(o, n))[0]

            snapshot_logits = jax.vmap(one)(params, normalizer, obs)
            is_snapshot = (member >= 1) & (member <= self.keep)
            logits = jnp.where(is_snapshot[:, None, None], snapshot_logits, logits)
        action = sample_actions(logits, rng)
        batch = member.shape[0]
        for i, policy in enumerate(self.fixed):
            keys = jax.random.split(jax.random.fold_in(rng, i + 1), batch)
            fixed_action = jax.vmap(policy)(raw_obs, keys).astype(jnp.int32)
            action = jnp.where((member == 1 + self.keep + i)[:, None], fixed_action, action)
        return action

    # ------------------------------------------------------------------ metrics

    def metrics(self, data: dict[str, Any]) -> dict[str, jax.Array]:
        """Per member kind, from a rollout's [T, B] arrays (`pool_member`, the member that
        played each step; `done`; the env's `episode/success_rate`; the pool team's summed
        reward per step, `team_reward`):

          * `pool/vs_<kind>/episodes`: its share of the episodes that ended this iteration;
          * `pool/vs_<kind>/success_rate`: their mean success rate (NaN when none ended);
          * `pool/vs_<kind>/<team>_reward`: the pool team's reward per step against it.

        NaN where there is nothing to average (the loggers skip it)."""
        team = self.team
        kind = self.kind_of(data["pool_member"][team])
        done = data["done"].astype(jnp.float32)
        success = data["metrics"]["episode/success_rate"]
        team_reward = data["team_reward"][team]
        finished = jnp.sum(done)
        out = {}
        for k, name in enumerate(self.kinds):
            played = (kind == k).astype(jnp.float32)
            ended = jnp.sum(done * played)
            out[f"{self.prefix}{name}/episodes"] = jnp.where(
                finished > 0, ended / jnp.maximum(finished, 1.0), jnp.nan
            )
            out[f"{self.prefix}{name}/success_rate"] = jnp.where(
                ended > 0, jnp.sum(success * done * played) / jnp.maximum(ended, 1.0), jnp.nan
            )
            out[f"{self.prefix}{name}/{team}_reward"] = jnp.where(
                jnp.sum(played) > 0,
                jnp.sum(team_reward * played) / jnp.maximum(jnp.sum(played), 1.0),
                jnp.nan,
            )
        return out

    def eval_opponents(self, snapshot: Policy) -> list[tuple[str, str, Policy]]:
        """(team, name, opponent) pairs the in-training evaluation adds: the newest `snapshot`
        and each fixed member but scripted (which every learned team already meets)."""
        pairs = [(self.team, "snapshot", snapshot)]
        for name, policy in zip(self.config.member_names, self.fixed, strict=True):
            if name != "scripted":
                pairs.append((self.team, name, policy))
        return pairs


def _stack(keep: int) -> Callable[[jax.Array], jax.Array]:
    """An array -> `keep` copies of it stacked [keep, ...]."""
    return lambda x: jnp.broadcast_to(x, (keep, *jnp.shape(x)))


def opponent_mask(valid: jax.Array, member: jax.Array) -> jax.Array:
    """The co-evolving opponent's `valid` [B, A] with the arenas where another member played
    (`member` [B] not 0) masked out."""
    return valid & (member == 0)[:, None]


def settle(states: dict[str, PoolState]) -> dict[str, PoolState]:
    """With both teams on pools: in each arena where both drew a non-current member, a coin
    (from the evader pool's stream, which then moves on) keeps the pursuers' draw or the
    evaders', and the other side plays its current opponent. One pool: `states` as they are."""
    if len(states) < 2:
        return states
    pursuer, evader = states["pursuer"], states["evader"]
    rng, key = jax.random.split(evader.rng)
    both = (pursuer.member != 0) & (evader.member != 0)
    keep_pursuer = jax.random.bernoulli(key, 0.5, both.shape)
    return {
        "pursuer": pursuer.replace(member=jnp.where(both & ~keep_pursuer, 0, pursuer.member)),
        "evader": evader.replace(member=jnp.where(both & keep_pursuer, 0, evader.member), rng=rng),
    }


def make_pools(
    config: PoolConfig, networks: dict[str, Any], make_fixed: Callable[[str, str], Policy]
) -> dict[str, Pool]:
    """The pools of `config` keyed by the team that faces each (none when it is off): the
    opponent's network from `networks`, fixed members from `make_fixed(spec, opponent)`."""
    pools = {}
    for team in config.teams:
        opponent = other_team(team)
        fixed = {spec: make_fixed(spec, opponent) for spec in config.fixed}
        pools[team] = Pool(config, team, networks[opponent], fixed)
    return pools
