"""A standard JAX IPPO on JaxMARL's MPE simple_tag: the peer trainer that tools/bench_train.py
times beside ours (issue 19).

It follows JaxMARL's own IPPO baseline (`baselines/IPPO/ippo_ff_mpe.py`, which the PyPI package
does not ship): feed-forward actor and critic of 64 tanh units, one parameter set per team
(adversaries and good agents have different observation sizes), agents folded into the batch,
a jitted iteration of `unroll` steps of `num_envs` envs (the env auto-resets), GAE, then
`epochs` x `minibatches` clipped-PPO steps with optax Adam and global-norm clipping. Written
here because the baseline is a script, not an importable function; nothing of pe-mjx is used.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax


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

    def stack(obs, agents):  # {agent: [B, D]} -> [B, A, D]
        return jnp.stack([obs[a] for a in agents], axis=1)

    def iteration(state):
        params, opt_state, env_state, obs, key = state

        def step(carry, key):
            env_state, obs = carry
            k_act, k_env = jax.random.split(key)
            actions, data = {}, {}
            for (team, agents), k in zip(
                teams.items(), jax.random.split(k_act, len(teams)), strict=True
            ):
                x = stack(obs, agents)
                logits, value = nets[team].apply(params[team], x)
                action = jax.random.categorical(k, logits)
                logp = jnp.take_along_axis(jax.nn.log_softmax(logits), action[..., None], axis=-1)[
                    ..., 0
                ]
                actions.update({a: action[:, i] for i, a in enumerate(agents)})
                data[team] = (x, action, logp, value)
            obs2, env_state2, reward, done, _ = jax.vmap(env.step)(
                jax.random.split(k_env, num_envs), env_state, actions
            )
            out = {
                team: Transition(
                    *data[team], stack(reward, agents), stack(done, agents).astype(jnp.float32)
                )
                for team, agents in teams.items()
            }
            return (env_state2, obs2), out

        key, k_roll, k_upd = jax.random.split(key, 3)
        (env_state, obs), traj = jax.lax.scan(
            step, (env_state, obs), jax.random.split(k_roll, unroll)
        )
        metrics = {}
        new_params, new_opt = {}, {}
        for (team, agents), k in zip(
            teams.items(), jax.random.split(k_upd, len(teams)), strict=True
        ):
            tr = traj[team]
            _, last_value = nets[team].apply(params[team], stack(obs, agents))

            def gae(carry, t):
                adv, next_value = carry
                delta = t.reward + gamma * next_value * (1 - t.done) - t.value
                adv = delta + gamma * lam * (1 - t.done) * adv
                return (adv, t.value), adv

            _, adv = jax.lax.scan(gae, (jnp.zeros_like(last_value), last_value), tr, reverse=True)
            targets = adv + tr.value
            batch = (tr.obs, tr.action, tr.log_prob, adv, targets)
            n = unroll * num_envs * len(agents)
            batch = jax.tree.map(lambda x, n=n: x.reshape(n, *x.shape[3:]), batch)

            def loss_fn(p, mb, team=team):
                x, action, old_logp, adv, target = mb
                logits, value = nets[team].apply(p, x)
                logp_all = jax.nn.log_softmax(logits)
                logp = jnp.take_along_axis(logp_all, action[..., None], axis=-1)[..., 0]
                ratio = jnp.exp(logp - old_logp)
                adv = (adv - adv.mean()) / (adv.std() + 1e-8)
                pg = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - clip, 1 + clip) * adv).mean()
                vf = 0.5 * jnp.square(value - target).mean()
                ent = -(jnp.exp(logp_all) * logp_all).sum(-1).mean()
                return pg + 0.5 * vf - 0.01 * ent

            def minibatch(carry, mb):
                p, o = carry
                loss, grads = jax.value_and_grad(loss_fn)(p, mb)
                updates, o = opt.update(grads, o)
                return (optax.apply_updates(p, updates), o), loss

            def epoch(carry, key, batch=batch, n=n):
                perm = jax.random.permutation(key, n)
                shuffled = jax.tree.map(
                    lambda x: x[perm].reshape(minibatches, -1, *x.shape[1:]), batch
                )
                return jax.lax.scan(minibatch, carry, shuffled)

            (p, o), losses = jax.lax.scan(
                epoch, (params[team], opt_state[team]), jax.random.split(k, epochs)
            )
            new_params[team], new_opt[team] = p, o
            metrics[f"loss/{team}"] = losses.mean()
        return (new_params, new_opt, env_state, obs, key), metrics

    return init, iteration
