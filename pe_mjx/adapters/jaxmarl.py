"""JaxMARL `MultiAgentEnv` over one pursuit-evasion arena: pure, `jit`- and `vmap`-able.

JaxMARL's API speaks in per-agent dicts ("pursuer_0", ..., "evader_0", ...), so this adapter
splits the env's per-team arrays into them and stacks them back:

  * `reset(key) -> (obs, state)`, `state` the env's own `pe_mjx.State`;
  * `step(key, state, actions) -> (obs, state, rewards, dones, infos)`, inherited from JaxMARL's
    `MultiAgentEnv.step`, which auto-resets with `key` when `dones["__all__"]`;
  * obs[agent]: float32 [D_team], `flatten_observation` of the env's observation dict (layout:
    `pe_mjx.adapters.observation_layout`); actions: int indices, `Discrete(n_actions)` spaces;
  * `get_avail_actions(state)[agent]`: bool [n_actions], the env's action mask;
  * dones[agent]: the agent is down or the episode is over; dones["__all__"]: the episode is over
    (one team gone, or `max_steps`). Every agent stays in the dicts (fixed shapes); a downed
    agent's actions are ignored and its reward is 0, so JaxMARL's `LogWrapper`, which sums
    rewards until `__all__`, reports true episode returns;
  * infos: "active" (bool [N]) and "truncation" (float32 [N], 1 where the episode hit
    `max_steps`), one entry per agent in `agents` order, as JaxMARL's baselines reshape infos to
    [num_envs * num_agents].

`jit` it from the outside (JaxMARL's base class already jits `step`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxmarl.environments.multi_agent_env import MultiAgentEnv
from jaxmarl.environments.spaces import Box, Discrete

from pe_mjx.adapters.common import agent_names, flatten_observation, observation_layout
from pe_mjx.config import EnvConfig
from pe_mjx.env import PursuitEvasionEnv, State, make
from pe_mjx.names import TEAMS


class JaxMARLEnv(MultiAgentEnv):
    """The game as a JaxMARL `MultiAgentEnv`; see the module docstring for the conventions."""

    def __init__(self, preset: str | EnvConfig | PursuitEvasionEnv = "20-5-8", backend="mjx"):
        env = preset if isinstance(preset, PursuitEvasionEnv) else make(preset, backend=backend)
        super().__init__(num_agents=env.num_agents)
        self.env = env
        self.team_agents = agent_names(env)
        self.agents = [a for t in TEAMS for a in self.team_agents[t]]
        self.layout = {t: observation_layout(env, t) for t in TEAMS}
        for t in TEAMS:
            size = max(sl.stop for sl, _ in self.layout[t].values())
            for a in self.team_agents[t]:
                self.observation_spaces[a] = Box(-np.inf, np.inf, (size,), jnp.float32)
                self.action_spaces[a] = Discrete(env.num_actions(t))

    @property
    def name(self) -> str:
        return f"pe_mjx_{self.env.config.name}"

    @property
    def agent_classes(self) -> dict[str, list[str]]:
        return dict(self.team_agents)

    def reset(self, key: jax.Array) -> tuple[dict[str, jax.Array], State]:
        state = self.env.reset(key)
        return self.get_obs(state), state

    def step_env(
        self, key: jax.Array, state: State, actions: dict[str, jax.Array]
    ) -> tuple[dict, State, dict, dict, dict]:
        del key  # the dynamics are deterministic; JaxMARL's `step` uses its key for the reset
        team_actions = {
            t: jnp.stack([jnp.asarray(actions[a]) for a in self.team_agents[t]]).astype(jnp.int32)
            for t in TEAMS
        }
        state = self.env.step(state, team_actions)
        over = state.done > 0
        active = self.env.active(state)
        rewards = self._split(state.reward)
        dones = self._split({t: over | ~active[t] for t in TEAMS})
        dones["__all__"] = over
        n = self.num_agents
        infos = {
            "active": jnp.concatenate([active[t] for t in TEAMS]),
            "truncation": jnp.full((n,), state.info["truncation"], jnp.float32),
        }
        return self.get_obs(state), state, rewards, dones, infos

    def get_obs(self, state: State) -> dict[str, jax.Array]:
        return self._split({t: flatten_observation(state.obs[t]) for t in TEAMS})

    def get_avail_actions(self, state: State) -> dict[str, jax.Array]:
        return self._split({t: state.obs[t]["action_mask"] for t in TEAMS})

    def _split(self, per_team: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """{team: [A, ...]} -> {agent name: [...]}."""
        return {a: per_team[t][i] for t in TEAMS for i, a in enumerate(self.team_agents[t])}
