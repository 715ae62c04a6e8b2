"""Trains the evaders with Stable-Baselines3 (MaskablePPO) through the PettingZoo adapter.

    python examples/sb3_train_evader.py --preset 2-1-1 --timesteps 20000 --out sb3_evader.zip

Needs `pip install 'pe-mjx[sb3]'` (torch, stable-baselines3, sb3-contrib; a CPU build of torch is
enough). One team learns, the other is fixed: `OneTeamVecEnv` runs `--arenas` PettingZoo envs,
plays the pursuers with pe_mjx's scripted policy inside, and shows SB3 one env per evader slot,
so one network serves every evader (parameter sharing). The action mask reaches MaskablePPO
through `action_masks()`; the policy sees the "observation" vector. After an evader is down its
slot reports done once, then zero observations and rewards until its arena ends (SuperSuit's
"black death"), as SB3 needs every slot stepped every time.
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np
from sb3_contrib import MaskablePPO
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from pe_mjx.adapters.pettingzoo import PettingZooEnv
from pe_mjx.names import other_team
from pe_mjx.policy.scripted import make_policy


class OneTeamVecEnv(VecEnv):
    """`team`'s agents of `num_arenas` PettingZoo arenas as one SB3 VecEnv; the other team
    plays `opponent` ("scripted" or "random") inside it."""

    def __init__(
        self,
        preset: str,
        backend: str = "kinematic",
        num_arenas: int = 4,
        team: str = "evader",
        opponent: str = "scripted",
        seed: int = 0,
    ):
        self.arenas = [PettingZooEnv(preset, backend=backend) for _ in range(num_arenas)]
        first = self.arenas[0]
        self.team, self.other = team, other_team(team)
        self.slots = [a for a in first.possible_agents if a.startswith(team + "_")]
        others = [a for a in first.possible_agents if a.startswith(self.other + "_")]
        self.others = others
        policy = make_policy(opponent, first.config, self.other)
        self._opponent = jax.jit(policy)
        self._rng = jax.random.key(seed)
        space = first.observation_space(self.slots[0])
        self._mask_size = space["action_mask"].shape[0]
        self.render_mode = None
        super().__init__(
            num_arenas * len(self.slots), space["observation"], first.action_space(self.slots[0])
        )
        self._seed = seed
        self._obs = np.zeros((self.num_envs, *space["observation"].shape), np.float32)
        self._masks = np.ones((self.num_envs, self._mask_size), bool)
        self._actions = np.zeros(self.num_envs, np.int64)

    # -------------------------------------------------------------- per arena

    def _load(self, k: int, obs: dict) -> None:
        """Writes arena k's observations and masks into its slots (zeros for agents gone)."""
        for i, agent in enumerate(self.slots):
            j = k * len(self.slots) + i
            if agent in obs:
                self._obs[j] = obs[agent]["observation"]
                self._masks[j] = obs[agent]["action_mask"].astype(bool)
            else:
                self._obs[j] = 0.0
                self._masks[j] = True

    def _reset_arena(self, k: int, seed: int | None = None) -> None:
        obs, _ = self.arenas[k].reset(seed=seed)
        self._load(k, obs)

    def _opponent_actions(self, arena: PettingZooEnv) -> dict[str, int]:
        self._rng, key = jax.random.split(self._rng)
        actions = np.asarray(self._opponent(arena.pe_state.obs[self.other], key))
        return {a: int(actions[i]) for i, a in enumerate(self.others) if a in arena.agents}

    # -------------------------------------------------------------- VecEnv

    def reset(self) -> np.ndarray:
        for k in range(len(self.arenas)):
            self._reset_arena(k, seed=self._seed + k)
        return self._obs.copy()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        rewards = np.zeros(self.num_envs, np.float32)
        dones = np.zeros(self.num_envs, bool)
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        for k, arena in enumerate(self.arenas):
            base = k * len(self.slots)
            actions = self._opponent_actions(arena)
            for i, agent in enumerate(self.slots):
                if agent in arena.agents:
                    actions[agent] = int(self._actions[base + i])
            obs, rew, term, trunc, _ = arena.step(actions)
            for i, agent in enumerate(self.slots):
                if agent in rew:  # alive at this step
                    j = base + i
                    rewards[j] = rew[agent]
                    if term[agent] or trunc[agent]:
                        dones[j] = True
                        infos[j]["terminal_observation"] = obs[agent]["observation"]
                        infos[j]["TimeLimit.truncated"] = bool(trunc[agent] and not term[agent])
            self._load(k, {a: o for a, o in obs.items() if a in arena.agents})
            if not arena.agents:  # the episode is over: a fresh arena
                self._reset_arena(k)
        return self._obs.copy(), rewards, dones, infos

    def action_masks(self) -> np.ndarray:
        return self._masks.copy()

    def env_method(self, method_name, *args, indices=None, **kwargs):
        if method_name != "action_masks":
            raise NotImplementedError(method_name)
        return list(self._masks[self._get_indices(indices)])

    def has_attr(self, attr_name: str) -> bool:
        return attr_name == "action_masks"

    def get_attr(self, attr_name, indices=None):
        return [getattr(self, attr_name)] * len(list(self._get_indices(indices)))

    def set_attr(self, attr_name, value, indices=None) -> None:
        setattr(self, attr_name, value)

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(list(self._get_indices(indices)))

    def close(self) -> None:
        pass

    def _get_indices(self, indices):
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else indices


def evaluate(model: MaskablePPO | None, env: OneTeamVecEnv, episodes: int) -> tuple[float, float]:
    """(mean episodic return per agent, fraction of agents still up at the end) over `episodes`
    episodes per slot; `model` None plays uniformly random valid actions."""
    rng = np.random.default_rng(0)
    obs = env.reset()
    returns = np.zeros(env.num_envs)
    finished, survived = [], []
    counts = np.zeros(env.num_envs, int)
    while counts.min() < episodes:
        masks = env.action_masks()
        if model is None:
            actions = np.array([rng.choice(np.flatnonzero(m)) for m in masks])
        else:
            actions, _ = model.predict(obs, action_masks=masks, deterministic=True)
        obs, rewards, dones, infos = env.step(actions)
        returns += rewards
        for j in np.flatnonzero(dones):
            if counts[j] < episodes:
                finished.append(returns[j])
                survived.append(infos[j]["TimeLimit.truncated"])
            counts[j] += 1
            returns[j] = 0.0
    return float(np.mean(finished)), float(np.mean(survived))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="2-1-1", help="env preset (pe_mjx.PRESETS)")
    parser.add_argument("--backend", default="kinematic", choices=["kinematic", "mjx"])
    parser.add_argument("--timesteps", type=int, default=20_000, help="SB3 steps (agent-steps)")
    parser.add_argument("--arenas", type=int, default=4, help="arenas stepped per SB3 step")
    parser.add_argument("--eval-episodes", type=int, default=2, help="per slot, before/after")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="sb3_evader.zip", help="where to save the model")
    args = parser.parse_args()

    env = VecMonitor(OneTeamVecEnv(args.preset, args.backend, args.arenas, seed=args.seed))
    eval_env = OneTeamVecEnv(args.preset, args.backend, args.arenas, seed=args.seed + 1000)
    print(f"{env.num_envs} evader slots ({args.arenas} arenas of {args.preset}), pursuers scripted")
    if args.eval_episodes:
        ret, up = evaluate(None, eval_env, args.eval_episodes)
        print(f"random valid actions: evader return {ret:.1f}, evaders up at the end {up:.2f}")
    n_steps = max(16, min(256, args.timesteps // env.num_envs))
    model = MaskablePPO(
        "MlpPolicy", env, n_steps=n_steps, batch_size=64, seed=args.seed, verbose=1, device="cpu"
    )
    tic = time.perf_counter()
    model.learn(total_timesteps=args.timesteps)
    print(f"trained {model.num_timesteps} agent-steps in {time.perf_counter() - tic:.0f} s")
    model.save(args.out)
    print(f"saved {args.out}")
    if args.eval_episodes:
        ret, up = evaluate(model, eval_env, args.eval_episodes)
        print(f"trained evaders: evader return {ret:.1f}, evaders up at the end {up:.2f}")


if __name__ == "__main__":
    main()
