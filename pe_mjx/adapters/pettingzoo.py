"""PettingZoo `ParallelEnv` over one pursuit-evasion arena (numpy in, numpy out).

Agents are named "pursuer_0", ..., "evader_0", ... Each agent observes, following PettingZoo's
action-masking convention (its classic environments; `parallel_api_test` samples from it), a dict

    {"observation": float32 [D_team], "action_mask": int8 [n_actions_team]}

where "observation" is `flatten_observation` of the env's observation dict (layout:
`observation_layout`, or `env.observation_layout(agent)`) and "action_mask" is 1 for valid
actions. Actions are `Discrete(n_actions)` indices: 39 for pursuers and 95 for evaders at the
paper's presets (read from the config).

An agent that is incapacitated (wall, obstacle, capture, collision) is `terminated` on that step
and leaves `agents`; when one team is gone every remaining agent is terminated, and at
`max_steps` every remaining agent is `truncated`. Rewards are the env's per-agent rewards (0 for
an agent after it is down, so it is simply not reported). `reset(seed=s)` draws the arena from
`jax.random.key` of a number drawn from `numpy.random.default_rng(s)`; later resets without a seed
continue that stream.

`step` refuses, with a `ValueError` naming the agent and before anything is stepped, an action
for an agent that is not in `possible_agents`, an action that is not an integer index (a float,
even a whole one, a bool, an array of more than one entry), one out of [0, n_actions), and one
the agent's last "action_mask" forbids; actions given for agents that are gone are ignored.

`reset` and `step` are jitted once per (config, backend) and shared by every instance.
"""

from __future__ import annotations

import functools
from typing import Any, ClassVar

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from pettingzoo import ParallelEnv

from pe_mjx.adapters.common import agent_names, flatten_observation, observation_layout
from pe_mjx.config import EnvConfig, get_preset
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.names import TEAMS


@functools.cache
def _compiled(config: EnvConfig, backend: str):
    """(env, jitted reset, jitted step) for one config and backend."""
    env = PursuitEvasionEnv(config, backend=backend)

    def outputs(state):
        obs = {t: flatten_observation(state.obs[t]) for t in TEAMS}
        masks = {t: state.obs[t]["action_mask"].astype(jnp.int8) for t in TEAMS}
        return obs, masks

    def reset(rng):
        state = env.reset(rng)
        return state, outputs(state)

    def step(state, actions):
        state = env.step(state, actions)
        flags = (state.info["terminated"], state.info["truncation"] > 0)
        return state, outputs(state), state.reward, env.active(state), flags

    return env, jax.jit(reset), jax.jit(step)


class PettingZooEnv(ParallelEnv):
    """The game as a PettingZoo `ParallelEnv`; see the module docstring for the conventions."""

    metadata: ClassVar[dict[str, Any]] = {
        "name": "pe_mjx_v0",
        "render_modes": [],
        "is_parallelizable": True,
    }

    def __init__(self, preset: str | EnvConfig = "20-5-8", backend: str = "mjx"):
        config = get_preset(preset) if isinstance(preset, str) else preset
        self.env, self._reset, self._step = _compiled(config, backend)
        self.config = config
        self.render_mode = None
        self._names = agent_names(self.env)
        self.possible_agents = [a for t in TEAMS for a in self._names[t]]
        self._team_index = {a: (t, i) for t in TEAMS for i, a in enumerate(self._names[t])}
        self._layout = {t: observation_layout(self.env, t) for t in TEAMS}
        # Built once per agent: the API test wants the same object back, and seeding one agent's
        # space must leave the others' streams alone.
        self.observation_spaces = {a: self._team_space(t) for a, (t, _) in self._team_index.items()}
        self.action_spaces = {
            a: gymnasium.spaces.Discrete(self.env.num_actions(t))
            for a, (t, _) in self._team_index.items()
        }
        self.agents: list[str] = []
        self._np_rng = np.random.default_rng()
        self._state = None
        self._masks: dict[str, np.ndarray] = {}  # team -> int8 [A, n_actions], the last ones

    def _team_space(self, team: str) -> gymnasium.spaces.Dict:
        size = max(sl.stop for sl, _ in self._layout[team].values())
        n = self.env.num_actions(team)
        return gymnasium.spaces.Dict(
            {
                "observation": gymnasium.spaces.Box(-np.inf, np.inf, (size,), np.float32),
                "action_mask": gymnasium.spaces.Box(0, 1, (n,), np.int8),
            }
        )

    def observation_space(self, agent: str) -> gymnasium.spaces.Dict:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> gymnasium.spaces.Discrete:
        return self.action_spaces[agent]

    def observation_layout(self, agent: str) -> dict[str, tuple[slice, tuple]]:
        """{key: (slice, shape)} of the agent's "observation" vector (see `observation_layout`)."""
        return self._layout[self._team_index[agent][0]]

    @property
    def pe_state(self) -> Any:
        """The underlying `pe_mjx.State` (for rendering or analysis), None before `reset`."""
        return self._state

    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, dict], dict[str, dict]]:
        if seed is not None:
            self._np_rng = np.random.default_rng(seed)
        rng = jax.random.key(int(self._np_rng.integers(0, 2**31)))
        self._state, (obs, masks) = self._reset(rng)
        self.agents = list(self.possible_agents)
        obs, masks = jax.device_get((obs, masks))
        self._masks = masks
        return self._per_agent(self.agents, obs, masks), {a: {} for a in self.agents}

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        unknown = [a for a in actions if a not in self._team_index]
        if unknown:
            raise ValueError(
                f"actions for unknown agents {unknown}; the agents are {self.possible_agents}"
            )
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"no action for live agents {missing}")
        team_actions = {t: np.zeros(len(self._names[t]), np.int32) for t in TEAMS}
        for agent in self.agents:  # actions of agents that are gone are ignored
            team, i = self._team_index[agent]
            team_actions[team][i] = self._checked_action(agent, actions[agent])
        self._state, outputs, reward, active, flags = self._step(self._state, team_actions)
        (obs, masks), reward, active, (terminated, truncated) = jax.device_get(
            (outputs, reward, active, flags)
        )
        self._masks = masks
        live = self.agents
        rewards, terminations, truncations = {}, {}, {}
        for agent in live:
            team, i = self._team_index[agent]
            rewards[agent] = float(reward[team][i])
            terminations[agent] = bool(terminated or not active[team][i])
            truncations[agent] = bool(truncated and not terminations[agent])
        observations = self._per_agent(live, obs, masks)
        self.agents = [a for a in live if not (terminations[a] or truncations[a])]
        return observations, rewards, terminations, truncations, {a: {} for a in live}

    def _checked_action(self, agent: str, action: Any) -> int:
        """The action index of `agent`, or a `ValueError` saying what is wrong with it."""
        team, i = self._team_index[agent]
        n = self.action_spaces[agent].n
        value = np.asarray(action) if not isinstance(action, int | np.generic) else action
        if isinstance(value, np.ndarray):
            if value.size != 1:
                raise ValueError(
                    f"{agent}: the action must be one integer in [0, {n}), got an array of shape "
                    f"{value.shape}"
                )
            value = value.reshape(()).item() if value.dtype.kind in "iu" else value.reshape(())
        if isinstance(value, bool | np.bool_) or not isinstance(value, int | np.integer):
            raise ValueError(
                f"{agent}: the action must be an integer index in [0, {n}), got {action!r} "
                f"({type(action).__name__})"
            )
        value = int(value)
        if not 0 <= value < n:
            raise ValueError(f"{agent}: action {value} is out of range [0, {n})")
        if not self._masks[team][i][value]:
            raise ValueError(
                f"{agent}: action {value} is not allowed by its action_mask (its look-ahead arc "
                f"hits the wall or an obstacle, or turns tighter than the minimum radius); "
                f"choose one where obs[{agent!r}]['action_mask'] is 1"
            )
        return value

    def _per_agent(self, agents: list[str], obs: dict, masks: dict) -> dict[str, dict]:
        out = {}
        for agent in agents:
            team, i = self._team_index[agent]
            out[agent] = {"observation": obs[team][i], "action_mask": masks[team][i]}
        return out
