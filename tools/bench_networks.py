"""Throughput of the actor-critic networks (pe_mjx.networks), per encoder, on one team's obs.

Measures agent-steps/s of the jitted forward pass (``apply``) and of forward+backward (the
gradient of a PPO-shaped loss: log-prob, value and entropy terms) on a batch of real observations
(``--envs`` arenas of ``--preset``, kinematic backend). Prints a table with parameter counts.

    .venv/bin/python tools/bench_networks.py                       # 20-5-8, 256 envs, pursuers
    .venv/bin/python tools/bench_networks.py --team evader --encoders mix mean
    .venv/bin/python tools/bench_networks.py --preset 240-60-120 --envs 8 --nearest-k 16
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp

import pe_mjx
from pe_mjx import networks as nets
from pe_mjx.bench import best_of


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--preset", default="20-5-8")
    ap.add_argument("--envs", type=int, default=256)
    ap.add_argument("--team", default="pursuer", choices=pe_mjx.config.TEAMS)
    ap.add_argument("--encoders", nargs="+", default=list(nets.ENCODERS))
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--num-heads", type=int, default=4)
    ap.add_argument("--hidden", type=int, default=64)
    ap.add_argument("--nearest-k", type=int, default=None)
    ap.add_argument(
        "--mix-queries", nargs="+", default=["own", "all"], choices=list(nets.MIX_QUERIES)
    )
    ap.add_argument("--repeats", type=int, default=10)
    args = ap.parse_args()

    env = pe_mjx.make(args.preset, backend="kinematic")
    keys = jax.random.split(jax.random.key(0), args.envs)
    obs = jax.jit(jax.vmap(env.reset))(keys).obs[args.team]
    num_agents, num_actions = obs["action_mask"].shape[1:]
    counts = tuple(obs[k].shape[2] for k in nets.ENTITY_TYPES)
    batch = args.envs * num_agents
    print(
        f"preset {args.preset}, team {args.team}: {args.envs} envs x {num_agents} agents = "
        f"{batch} agent-steps per call; entities (T, O, K) = {counts}, {num_actions} actions; "
        f"jax {jax.__version__} on {jax.devices()[0].platform}"
    )

    variants = []
    for enc in args.encoders:
        for mq in args.mix_queries if enc == "mix" else ["own"]:
            variants.append((f"{enc}/{mq}" if enc == "mix" else enc, enc, mq))

    print("agent-steps per wall second (/s) and per CPU second (/cpu-s), best of --repeats")
    header = (
        f"{'encoder':10s} {'params':>8s} {'fwd/s':>9s} {'fwd/cpu-s':>10s} {'fwd+bwd/s':>10s} "
        f"{'f+b/cpu-s':>10s} {'compile s':>10s}"
    )
    print(header)
    print("-" * len(header))
    for label, enc, mq in variants:
        cfg = nets.NetworkConfig(
            encoder=enc,
            width=args.width,
            num_heads=args.num_heads,
            hidden=args.hidden,
            nearest_k=args.nearest_k,
            mlp_counts=counts if enc == "mlp" else None,
            mix_queries=mq,
        )
        net = nets.make_network(cfg, num_actions)
        params = jax.jit(net.init)(jax.random.key(1), obs)
        actions = jnp.zeros(obs["action_mask"].shape[:-1], jnp.int32)

        def loss(params, obs, actions, net=net):
            logits, value = net.apply(params, obs)
            lp = nets.log_prob(logits, actions)
            return -jnp.mean(lp) + 0.5 * jnp.mean(value**2) - 0.01 * jnp.mean(nets.entropy(logits))

        fwd = jax.jit(net.apply)
        bwd = jax.jit(jax.grad(loss))
        c1, t_fwd, cpu_fwd = best_of(fwd, params, obs, repeats=args.repeats)
        c2, t_bwd, cpu_bwd = best_of(bwd, params, obs, actions, repeats=args.repeats)
        print(
            f"{label:10s} {nets.num_params(params):8d} {batch / t_fwd:9.0f} "
            f"{batch / cpu_fwd:10.0f} {batch / t_bwd:10.0f} {batch / cpu_bwd:10.0f} "
            f"{c1 + c2:10.1f}"
        )


if __name__ == "__main__":
    main()
