"""Plays masked-random episodes through the PettingZoo adapter and prints each agent's return.

    python examples/pettingzoo_rollout.py --preset 4-1-2 --episodes 3

Needs `pip install pe-mjx[pettingzoo]`. Any PettingZoo consumer drives the env the same way:
act only for `env.agents`, sample within obs[agent]["action_mask"], stop when `agents` is empty.
"""

from __future__ import annotations

import argparse

import numpy as np

from pe_mjx.adapters.pettingzoo import PettingZooEnv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="4-1-2", help="env preset (pe_mjx.PRESETS)")
    parser.add_argument("--backend", default="kinematic", choices=["kinematic", "mjx"])
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    env = PettingZooEnv(args.preset, backend=args.backend)
    rng = np.random.default_rng(args.seed)
    obs, _ = env.reset(seed=args.seed)
    for episode in range(args.episodes):
        returns = dict.fromkeys(env.possible_agents, 0.0)
        steps = 0
        while env.agents:
            actions = {a: rng.choice(np.flatnonzero(obs[a]["action_mask"])) for a in env.agents}
            obs, rewards, _, _, _ = env.step(actions)
            for agent, r in rewards.items():
                returns[agent] += r
            steps += 1
        shown = ", ".join(f"{a} {r:+.1f}" for a, r in returns.items())
        print(f"episode {episode}: {steps} steps; returns {shown}")
        obs, _ = env.reset()


if __name__ == "__main__":
    main()
