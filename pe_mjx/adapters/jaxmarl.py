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
  * infos: "active" (bool [N]), "truncation" (float32 [N], 1 where the episode hit
    `max_steps`) and "invalid_action" (bool [N], below), one entry per agent in `agents` order, as
    JaxMARL's baselines reshape infos to [num_envs * num_agents].

Invalid actions follow JaxMARL's convention: its environments never raise inside `step` (it runs
under `jit` and `vmap`, where values cannot raise), `get_avail_actions` is for the learner to
mask its logits with, and an action the environment cannot carry out does nothing (SMAX: an
attack on a unit out of range or dead is a no-op). Here an action index out of [0, n_actions) or
one that `get_avail_actions` forbids is played as the stop action (v = 0, the smallest |omega|:
the robot stands still) and marked in `infos["invalid_action"]`; downed agents' actions are
ignored and never marked. What is static under `jit` is checked when `step` is traced, with a
`ValueError`: an agent name that is not in `agents`, a missing agent, a non-integer action dtype.

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
from pe_mjx.stages.dynamics import action_table
from pe_mjx.stages.masks import stop_actions


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
        self.noop = {t: _stand_still(env.config.team(t)) for t in TEAMS}
        """Per team, the action an invalid one is played as (the stop action, module docstring)."""

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
        unknown = sorted(set(actions) - set(self.agents))
        if unknown:
            raise ValueError(f"actions for unknown agents {unknown}; the agents are {self.agents}")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"no action for agents {missing} (every agent stays in the dicts)")
        was_active = self.env.active(state)
        team_actions, invalid = {}, {}
        for t in TEAMS:
            given = []
            for a in self.team_agents[t]:
                x = jnp.asarray(actions[a])
                if not jnp.issubdtype(x.dtype, jnp.integer):
                    raise ValueError(
                        f"{a}: actions must be integer indices of Discrete("
                        f"{self.env.num_actions(t)}), got dtype {x.dtype}"
                    )
                given.append(x.astype(jnp.int32))
            index = jnp.stack(given)
            mask = state.obs[t]["action_mask"]
            n = mask.shape[-1]
            allowed = jnp.take_along_axis(mask, jnp.clip(index, 0, n - 1)[:, None], axis=1)[:, 0]
            ok = (index >= 0) & (index < n) & allowed
            team_actions[t] = jnp.where(ok, index, self.noop[t])
            invalid[t] = ~ok & was_active[t]
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
            "invalid_action": jnp.concatenate([invalid[t] for t in TEAMS]),
        }
        return self.get_obs(state), state, rewards, dones, infos

    def get_obs(self, state: State) -> dict[str, jax.Array]:
        return self._split({t: flatten_observation(state.obs[t]) for t in TEAMS})

    def get_avail_actions(self, state: State) -> dict[str, jax.Array]:
        return self._split({t: state.obs[t]["action_mask"] for t in TEAMS})

    def _split(self, per_team: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """{team: [A, ...]} -> {agent name: [...]}."""
        return {a: per_team[t][i] for t in TEAMS for i, a in enumerate(self.team_agents[t])}


def _stand_still(team) -> int:
    """The stop action (v = 0) with the smallest |omega| that the turning radius allows."""
    _, omega = action_table(team)
    stop = stop_actions(team)
    return int(np.argmin(np.where(stop, np.abs(omega), np.inf)))
