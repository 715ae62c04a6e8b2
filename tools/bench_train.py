"""Training throughput per encoder, and where the time of an iteration goes.

    python tools/bench_train.py [--quick] [--out docs/bench_train.json]

For each encoder and preset it times, jitted and warmed up, in the same run:
  * the full training iteration (rollout + normalisation + GAE + PPO update of both teams);
  * the rollout alone with the learned policies (env steps + network forward passes);
  * the rollout with both teams scripted-free: uniformly random masked actions (env steps only).
Shares: env = env-only rollout; networks (forward) = rollout - env; update = iteration - rollout.
"Update alone allows" = env steps per iteration / update time: the throughput if the env and the
rollout cost nothing, a ceiling that only a faster PPO update can raise.
Results go to a JSON file and a Markdown table (printed, and pasted into docs/benchmarks.md).

The peer trainer timed beside ours (`measure_peer`, "Peer IPPO" below) is in this file, not in a
module of its own: no tool imports another.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time
from pathlib import Path
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
import tyro

from pe_mjx import bench
from pe_mjx.bench import best_of
from pe_mjx.experiment import ExperimentConfig
from pe_mjx.names import ENCODERS
from pe_mjx.paper import paper_experiment
from pe_mjx.policy.scripted import make_policy
from pe_mjx.ppo.train import Trainer


@dataclasses.dataclass(frozen=True)
class Args:
    out: Path = Path("docs/bench_train.json")
    quick: bool = False
    """Only 20-5-8 with the chosen encoders (and the reset ablation), no MJX, no large preset."""
    backend: str = "kinematic"
    """Env backend of the measured runs (mjx is measured for MIX at 20-5-8 in addition)."""
    repeats: int = 3
    encoders: tuple[str, ...] = ENCODERS
    """Encoders to measure."""
    peer: bool = True
    """Also time the peer trainer: a standard JAX IPPO ("Peer IPPO" below, after JaxMARL's
    baseline) on JaxMARL's MPE simple_tag with 20 adversaries, 5 good agents and 8 obstacles,
    64 envs x 32 steps, 2 epochs x 4 minibatches (the `bench` extra: pip install
    'pe-mjx[bench]')."""
    reset_ablation: bool = True
    """Also time MIX with the env's reset computed on every step (`vmap(AutoResetWrapper.step)`)
    instead of only on steps where an arena finished (`step_batch`, what the trainer does)."""
    pool_ablation: bool = True
    """Also time MIX with its evaders training against an opponent pool (`POOL`: the co-evolving
    pursuers, their last 4 snapshots and the scripted pursuers), where each arena's snapshot
    pursuers run with their own gathered parameters (`pe_mjx.ppo.pool`)."""


POOL = {
    "pool.team": "evader",
    "pool.snapshot_every": 10,
    "pool.keep": 4,
    "pool.fixed": ["scripted"],
    "pool.p_current": 0.5,
    "pool.p_snapshots": 0.3,
    "pool.p_fixed": 0.2,
}
"""The pool of the ablation row: what issue 34's pool co-evolution would train against."""


def measure(config: ExperimentConfig, repeats: int, eager_reset: bool = False) -> dict:
    """One configuration's iteration, timed; and, without an opponent pool, the shares of the
    env, the rollout's forward passes and the update (the env-only rollout swaps the policies
    for random ones, which a pool's acting does not allow: None there)."""
    trainer = Trainer(config)
    if eager_reset:  # the ablation: a fresh arena drawn for every arena on every step
        trainer.env.step_batch = jax.vmap(trainer.env.step)
    state = trainer.init()
    tic = time.perf_counter()
    iteration = jax.jit(trainer.iteration)
    jax.block_until_ready(iteration(state))
    compile_s = time.perf_counter() - tic
    t_iter = best_of(lambda s: iteration(s)[1], state, repeats=repeats).wall
    rollout = jax.jit(lambda s: trainer._rollout(s, s.rng)[1])
    t_roll = best_of(rollout, state, repeats=repeats).wall
    t_env = None
    if not config.pool.on:
        # Env only: the same rollout machinery with random masked policies for both teams.
        saved = (trainer.learned, dict(trainer.fixed))
        trainer.learned = ()
        trainer.fixed = {
            t: make_policy("random", trainer.env_config, t) for t in ("pursuer", "evader")
        }
        env_only = jax.jit(lambda s: trainer._rollout(s, s.rng)[1]["done"])
        t_env = best_of(env_only, state, repeats=repeats).wall
        trainer.learned, trainer.fixed = saved
    steps = config.steps_per_iteration
    agents = trainer.env_config.num_agents
    return {
        "preset": config.preset,
        "encoder": config.pursuer.network.encoder,
        "backend": config.backend,
        "num_envs": config.ppo.num_envs,
        "unroll_length": config.ppo.unroll_length,
        "reset": "every step" if eager_reset else "when done",
        "pool": _pool_label(config),
        "compile_s": compile_s,
        "env_steps_per_s": steps / t_iter,
        "agent_steps_per_s": steps * agents / t_iter,
        "share_env": None if t_env is None else t_env / t_iter,
        "share_forward": None if t_env is None else max(t_roll - t_env, 0.0) / t_iter,
        "share_update": max(t_iter - t_roll, 0.0) / t_iter,
        # The most this iteration could do if the env and the rollout's forward passes cost
        # nothing: what the PPO update alone allows.
        "update_bound_env_steps_per_s": steps / max(t_iter - t_roll, 1e-9),
    }


def _pool_label(config: ExperimentConfig) -> str:
    pool = config.pool
    if not pool.on:
        return "off"
    return (
        f"{'both teams' if pool.team == 'both' else pool.team + 's'} vs current "
        f"{pool.p_current:g}, {pool.keep} snapshots "
        f"{pool.p_snapshots:g}, {'/'.join(pool.fixed) or '-'} {pool.p_fixed:g}"
    )


def measure_peer(num_envs: int, unroll: int, repeats: int) -> dict:
    """The peer IPPO's iteration on MPE simple_tag at 20-5-8 counts, timed like ours."""
    from jaxmarl import make

    env = make("MPE_simple_tag_v3", num_good_agents=5, num_adversaries=20, num_obs=8)
    init, iteration = make_iteration(env, num_envs, unroll)
    state = jax.jit(init)(jax.random.key(0))
    step = jax.jit(iteration)
    tic = time.perf_counter()
    jax.block_until_ready(step(state))
    compile_s = time.perf_counter() - tic
    t_iter = best_of(lambda s: step(s)[1], state, repeats=repeats).wall
    steps = num_envs * unroll
    return {
        "preset": "MPE simple_tag 20-5-8",
        "encoder": "JaxMARL-style IPPO (MLP)",
        "backend": "jaxmarl",
        "num_envs": num_envs,
        "unroll_length": unroll,
        "reset": "auto (in step)",
        "pool": "off",
        "compile_s": compile_s,
        "env_steps_per_s": steps / t_iter,
        "agent_steps_per_s": steps * len(env.agents) / t_iter,
        "share_env": None,
        "share_forward": None,
        "share_update": None,
        "update_bound_env_steps_per_s": None,
    }


def main() -> None:
    args = tyro.cli(Args)
    runs = []
    if args.peer:
        result = measure_peer(64, 32, args.repeats)
        print(json.dumps(result), flush=True)
        runs.append(result)
    plan = [("20-5-8", e, args.backend, 64, 32, False, False) for e in args.encoders]
    if args.reset_ablation:
        plan.append(("20-5-8", "mix", args.backend, 64, 32, True, False))
    if args.pool_ablation:
        plan.append(("20-5-8", "mix", args.backend, 64, 32, False, True))
    if not args.quick:
        plan.append(("20-5-8", "mix", "mjx", 64, 32, False, False))
        plan += [("240-60-120", e, args.backend, 8, 16, False, False) for e in args.encoders]
    for preset, encoder, backend, num_envs, unroll, eager_reset, pool in plan:
        config = paper_experiment(encoder, preset, backend=backend).override(
            {"ppo.num_envs": num_envs, "ppo.unroll_length": unroll, "eval_every": 0}
            | (POOL if pool else {})
        )
        result = measure(config, args.repeats, eager_reset)
        print(json.dumps(result), flush=True)
        runs.append(result)
    machine = bench.machine()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"machine": machine, "runs": runs}, indent=1))
    print(table(runs, machine))


def table(runs: list[dict], machine: dict) -> str:
    lines = [
        f"Training throughput ({machine['devices'][0]}, {machine['cores']} cores, jax "
        f"{machine['jax']}, {machine['date']}); default network (width 32, 4 heads, hidden 64), "
        "PPO 2 epochs x 4 minibatches.",
        "",
        "| preset | encoder | backend | reset | opponent pool | envs x unroll | env-steps/s | "
        "agent-steps/s | env | forward | update | update alone allows | compile s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]

    def share(x):
        return "-" if x is None else f"{x:.0%}"

    def bound(r):  # rows of files written before the column existed have none
        x = r.get("update_bound_env_steps_per_s")
        return "-" if x is None else f"{x:,.0f}"

    for r in runs:
        lines.append(
            f"| {r['preset']} | {r['encoder']} | {r['backend']} | {r['reset']} "
            f"| {r.get('pool', 'off')} | {r['num_envs']}x"
            f"{r['unroll_length']} | {r['env_steps_per_s']:,.0f} | {r['agent_steps_per_s']:,.0f} "
            f"| {share(r['share_env'])} | {share(r['share_forward'])} | {share(r['share_update'])} "
            f"| {bound(r)} | {r['compile_s']:.0f} |"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------- Peer IPPO
# A standard JAX IPPO on JaxMARL's MPE simple_tag: the peer trainer that `measure_peer` times
# beside ours (issue 19).
#
# It follows JaxMARL's own IPPO baseline (`baselines/IPPO/ippo_ff_mpe.py`, which the PyPI package
# does not ship): feed-forward actor and critic of 64 tanh units, one parameter set per team
# (adversaries and good agents have different observation sizes), agents folded into the batch,
# a jitted iteration of `unroll` steps of `num_envs` envs (the env auto-resets), GAE, then
# `epochs` x `minibatches` clipped-PPO steps with optax Adam and global-norm clipping. Written
# here because the baseline is a script, not an importable function; nothing of pe-mjx is used.
class ActorCritic(nn.Module):
    num_actions: int

    @nn.compact
    def __call__(self, x: jax.Array) -> tuple[jax.Array, jax.Array]:
        ortho = nn.initializers.orthogonal
        a = nn.tanh(nn.Dense(64, kernel_init=ortho(np.sqrt(2)))(x))
        a = nn.tanh(nn.Dense(64, kernel_init=ortho(np.sqrt(2)))(a))
        logits = nn.Dense(self.num_actions, kernel_init=ortho(0.01))(a)
        c = nn.tanh(nn.Dense(64, kernel_init=ortho(np.sqrt(2)))(x))
        c = nn.tanh(nn.Dense(64, kernel_init=ortho(np.sqrt(2)))(c))
        return logits, nn.Dense(1, kernel_init=ortho(1.0))(c)[..., 0]


class Transition(NamedTuple):
    obs: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    reward: jax.Array
    done: jax.Array


def make_iteration(
    env: Any,
    num_envs: int,
    unroll: int,
    epochs: int = 2,
    minibatches: int = 4,
    lr: float = 1e-3,
    gamma: float = 0.99,
    lam: float = 0.95,
    clip: float = 0.2,
):
    """`(init(key) -> state, iteration(state) -> (state, metrics))` for a JaxMARL env, IPPO
    with one network per team (agents whose names share the prefix before the last "_")."""
    teams: dict[str, list[str]] = {}
    for agent in env.agents:
        teams.setdefault(agent.rsplit("_", 1)[0], []).append(agent)
    nets = {t: ActorCritic(env.action_space(a[0]).n) for t, a in teams.items()}
    opt = optax.chain(optax.clip_by_global_norm(0.5), optax.adam(lr))

    def init(key):
        keys = jax.random.split(key, len(teams) + 1)
        obs, env_state = jax.vmap(env.reset)(jax.random.split(keys[0], num_envs))
        params = {
            t: nets[t].init(k, obs[agents[0]][0])
            for (t, agents), k in zip(teams.items(), keys[1:], strict=True)
        }
        opt_state = {t: opt.init(p) for t, p in params.items()}
        return params, opt_state, env_state, obs, keys[0]

    def step(params, carry, key):
        env_state, obs = carry
        k_act, k_env = jax.random.split(key)
        actions, data = {}, {}
        for (team, agents), k in zip(
            teams.items(), jax.random.split(k_act, len(teams)), strict=True
        ):
            x = _stack(obs, agents)
            action, logp, value = _act(nets[team], params[team], x, k)
            actions.update({a: action[:, i] for i, a in enumerate(agents)})
            data[team] = (x, action, logp, value)
        obs2, env_state2, reward, done, _ = jax.vmap(env.step)(
            jax.random.split(k_env, num_envs), env_state, actions
        )
        out = {
            team: Transition(
                *data[team], _stack(reward, agents), _stack(done, agents).astype(jnp.float32)
            )
            for team, agents in teams.items()
        }
        return (env_state2, obs2), out

    def iteration(state):
        params, opt_state, env_state, obs, key = state
        key, k_roll, k_upd = jax.random.split(key, 3)
        (env_state, obs), traj = jax.lax.scan(
            functools.partial(step, params), (env_state, obs), jax.random.split(k_roll, unroll)
        )
        metrics = {}
        new_params, new_opt = {}, {}
        for (team, agents), k in zip(
            teams.items(), jax.random.split(k_upd, len(teams)), strict=True
        ):
            _, last_value = nets[team].apply(params[team], _stack(obs, agents))
            batch = _ppo_batch(traj[team], last_value, gamma, lam)
            loss = functools.partial(_ppo_loss, nets[team], clip=clip)
            (p, o), losses = _ppo_epochs(
                loss, opt, (params[team], opt_state[team]), batch, k, epochs, minibatches
            )
            new_params[team], new_opt[team] = p, o
            metrics[f"loss/{team}"] = losses.mean()
        return (new_params, new_opt, env_state, obs, key), metrics

    return init, iteration


def _stack(tree: dict[str, jax.Array], agents: list[str]) -> jax.Array:
    """{agent: [B, ...]} -> [B, A, ...]."""
    return jnp.stack([tree[a] for a in agents], axis=1)


def _act(
    net: ActorCritic, params: Any, x: jax.Array, key: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """A team's sampled actions, their log-probabilities and the values, each [B, A], for its
    agents' observations `x` [B, A, D]."""
    logits, value = net.apply(params, x)
    action = jax.random.categorical(key, logits)
    logp = jnp.take_along_axis(jax.nn.log_softmax(logits), action[..., None], axis=-1)[..., 0]
    return action, logp, value


def _advantages(tr: Transition, last_value: jax.Array, gamma: float, lam: float) -> jax.Array:
    """GAE over a team's trajectory `tr` (fields [T, B, A, ...]), bootstrapped from the values
    `last_value` [B, A] after its last step: [T, B, A]."""

    def gae(carry, t):
        adv, next_value = carry
        delta = t.reward + gamma * next_value * (1 - t.done) - t.value
        adv = delta + gamma * lam * (1 - t.done) * adv
        return (adv, t.value), adv

    _, adv = jax.lax.scan(gae, (jnp.zeros_like(last_value), last_value), tr, reverse=True)
    return adv


def _ppo_batch(tr: Transition, last_value: jax.Array, gamma: float, lam: float) -> tuple:
    """A team's trajectory as PPO's batch: (obs, action, log-prob, advantage, value target),
    each with the steps, envs and agents folded into one axis [T * B * A, ...]."""
    adv = _advantages(tr, last_value, gamma, lam)
    batch = (tr.obs, tr.action, tr.log_prob, adv, adv + tr.value)
    n = adv.size
    return jax.tree.map(lambda x: x.reshape(n, *x.shape[3:]), batch)


def _ppo_loss(net: ActorCritic, p: Any, mb: tuple, clip: float) -> jax.Array:
    """Clipped PPO loss of one minibatch `mb` (obs, action, old log-prob, advantage, target),
    with the advantages normalised in the minibatch, value weight 0.5 and entropy 0.01."""
    x, action, old_logp, adv, target = mb
    logits, value = net.apply(p, x)
    logp_all = jax.nn.log_softmax(logits)
    logp = jnp.take_along_axis(logp_all, action[..., None], axis=-1)[..., 0]
    ratio = jnp.exp(logp - old_logp)
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    pg = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - clip, 1 + clip) * adv).mean()
    vf = 0.5 * jnp.square(value - target).mean()
    ent = -(jnp.exp(logp_all) * logp_all).sum(-1).mean()
    return pg + 0.5 * vf - 0.01 * ent


def _ppo_epochs(
    loss_fn: Any,
    opt: optax.GradientTransformation,
    carry: tuple[Any, Any],
    batch: tuple,
    key: jax.Array,
    epochs: int,
    minibatches: int,
) -> tuple[tuple[Any, Any], jax.Array]:
    """`epochs` passes over `batch` (leaves [n, ...]) in `minibatches` shuffled minibatches,
    one optimiser step each, from `carry` = (params, optimiser state): the final carry and the
    losses [epochs, minibatches]."""
    n = jax.tree.leaves(batch)[0].shape[0]

    def minibatch(carry, mb):
        p, o = carry
        loss, grads = jax.value_and_grad(loss_fn)(p, mb)
        updates, o = opt.update(grads, o)
        return (optax.apply_updates(p, updates), o), loss

    def epoch(carry, key):
        perm = jax.random.permutation(key, n)
        shuffled = jax.tree.map(lambda x: x[perm].reshape(minibatches, -1, *x.shape[1:]), batch)
        return jax.lax.scan(minibatch, carry, shuffled)

    return jax.lax.scan(epoch, carry, jax.random.split(key, epochs))


if __name__ == "__main__":
    main()
