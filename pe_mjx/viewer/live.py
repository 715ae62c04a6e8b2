"""The viewer's live simulation: B arenas of the jitted env, each team's policy, attention weights.

No viser here: `LiveRun` steps the env and hands out numpy `Frame`s, counters and attention
overlays; `pe_mjx.viewer.app` draws them. A team's policy is a `pe_mjx.policy.Policy`: scripted,
random, a checkpoint (`pe-mjx train --out` directory) or the trainer's current parameters. Learned
variables are an *argument* of the jitted step, so the training view swaps in new parameters
every iteration without recompiling.

One step of the loop (`tick`, jitted whole) is ``env.step`` with the actions decided on the
previous state, then the policies on the new state: the attention shown with a frame is the one
that chooses the next move from it. Finished arenas freeze (`rollout.freeze`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from pe_mjx.config import EnvConfig
from pe_mjx.env import PursuitEvasionEnv, State
from pe_mjx.names import BUILTIN_POLICIES, CAPTURE, CAUSE_NAMES, TEAMS
from pe_mjx.outcomes import outcome_counts
from pe_mjx.policy.core import Policy
from pe_mjx.policy.inference import dummy_obs
from pe_mjx.policy.resolve import resolve_policy
from pe_mjx.policy.shipped import resolve_run, retired_note
from pe_mjx.policy.store import CheckpointError
from pe_mjx.rollout import freeze
from pe_mjx.viewer.guard import PolicyAccess
from pe_mjx.viewer.scene import AttentionOverlay, Frame


class PolicyError(ValueError):
    """A policy that cannot play this team in this scene (bad path, wrong team, wrong sizes)."""


def check_fits(policy: Policy, config: EnvConfig, team: str) -> None:
    """Traces the policy on this scene's observation shapes; PolicyError if it does not fit."""
    obs = dummy_obs(config, team)
    a = config.team(team).num_agents
    apply = policy.with_attention()
    try:
        actions, attention = jax.eval_shape(apply, policy.variables, obs, jax.random.key(0))
    except Exception as err:
        raise PolicyError(
            f"the {team} policy {policy.source!r} does not fit scene {config.name!r}: {err}"
        ) from None
    if actions.shape != (a,) or not jnp.issubdtype(actions.dtype, jnp.integer):
        raise PolicyError(
            f"the {team} policy {policy.source!r} returns actions of shape {actions.shape}, "
            f"expected [{a}] integers"
        )
    if attention is not None:
        m = config.num_agents + config.arena.num_obstacles
        if attention.shape != (a, m):
            raise PolicyError(
                f"the {team} policy {policy.source!r} returns attention {attention.shape}, "
                f"expected {(a, m)}"
            )


def load_team_policy(
    spec: str,
    config: EnvConfig,
    team: str,
    deterministic: bool = False,
    access: PolicyAccess | None = None,
) -> Policy:
    """`resolve_policy` behind the viewer's guard: a name ("scripted", "random"), a shipped
    policy or a run directory, checked to fit the scene and, for paths typed into the GUI,
    to lie under the allowed roots.

    Args:
      access: where run directories may be opened from (paths typed into the GUI); None: anywhere
        (the command line). A path outside gets one message, whether or not it exists.

    Raises:
      PolicyError: unknown name, missing or unreadable checkpoint, a run that did not learn this
        team, or a network whose action count or inputs do not fit the scene.
    """
    spec = spec.strip()
    if team not in TEAMS:
        raise PolicyError(f"unknown team {team!r}; expected one of {TEAMS}")
    if spec not in BUILTIN_POLICIES:
        if not spec:
            raise PolicyError(f"no {team} policy given")
        names = " or ".join(BUILTIN_POLICIES)
        if access is not None and not access.allows(spec):
            raise PolicyError(
                f"{team} policy {spec!r}: not {names} and not a run directory "
                f"under {access.describe()} (`pe-mjx view --policy-roots` allows others)"
            )
        if not resolve_run(spec).exists():
            raise PolicyError(
                f"{team} policy {spec!r}: "
                + (
                    retired_note(spec)
                    or f"not one of {', '.join(BUILTIN_POLICIES)} and no such directory"
                )
            )
    try:
        policy = resolve_policy(spec, team, config, deterministic)
    except CheckpointError as err:
        raise PolicyError(str(err)) from None
    if policy.learned:  # host arrays: handed to the jitted step as arguments
        policy = dataclasses.replace(policy, variables=jax.device_get(policy.variables))
    check_fits(policy, config, team)
    return policy


def attention_targets(config: EnvConfig, team: str) -> tuple[np.ndarray, tuple[str, ...]]:
    """For every agent of `team`, the global agent indices of its attention tokens.

    Returns:
      agent_index int [A, T + O] (teammates in order without itself, then opponents: the
      observation's entity order) and the kind of each of the T + O + K non-own tokens.
    """
    p, e = config.pursuer.num_agents, config.evader.num_agents
    own = np.arange(p) if team == "pursuer" else np.arange(p, p + e)
    other = np.arange(p, p + e) if team == "pursuer" else np.arange(p)
    rows = [np.concatenate([np.delete(own, i), other]) for i in range(len(own))]
    kinds = ("teammates",) * (len(own) - 1) + ("opponents",) * len(other)
    kinds += ("obstacles",) * config.arena.num_obstacles
    return np.stack(rows).astype(np.int64), kinds


class LiveRun:
    """B arenas of one scene, stepped by the jitted env under each team's policy."""

    def __init__(
        self,
        config: EnvConfig,
        policies: dict[str, Policy],
        num_arenas: int = 1,
        backend: str = "mjx",
        seed: int = 0,
    ):
        if num_arenas < 1:
            raise ValueError(f"arenas must be >= 1, got {num_arenas}")
        self.config = config
        self.backend = backend
        self.num_arenas = num_arenas
        self.env = PursuitEvasionEnv(config, backend=backend)
        self.policies = dict(policies)
        for team in TEAMS:
            check_fits(self.policies[team], config, team)
        self._reset_fn = jax.jit(jax.vmap(self.env.reset))
        self._build()
        self.reset(seed)
        self._warm_up()

    # -- jitted functions (rebuilt when a policy changes; learned params stay arguments)

    def _build(self) -> None:
        env, b = self.env, self.num_arenas
        applies = {t: self.policies[t].with_attention() for t in TEAMS}

        def decide(state: State, params: dict, rng: jax.Array):
            actions, attention = {}, {}
            keys = jax.random.split(rng, len(TEAMS))
            for key, team in zip(keys, TEAMS, strict=True):
                act, att = jax.vmap(applies[team], in_axes=(None, 0, 0))(
                    params[team], state.obs[team], jax.random.split(key, b)
                )
                actions[team] = act
                if att is not None:
                    attention[team] = att
            return actions, attention

        def tick(state: State, actions: dict, params: dict, rng: jax.Array):
            new = freeze(state, jax.vmap(env.step)(state, actions))
            next_actions, attention = decide(new, params, rng)
            return new, next_actions, attention

        self._decide = jax.jit(decide)
        self._tick = jax.jit(tick)

    def _warm_up(self) -> None:
        """Compiles `tick` now (one throw-away step): the first frame of play is not late."""
        jax.block_until_ready(self._tick(self.state, self._actions, self._params(), self._rng))

    def _params(self) -> dict[str, Any]:
        return {t: self.policies[t].variables for t in TEAMS}

    # -- control

    def reset(self, seed: int) -> None:
        """New arenas drawn from `seed` (arena i from ``split(key(seed), B)[i]``)."""
        self.seed = int(seed)
        key = jax.random.key(self.seed)
        reset_key, self._rng = jax.random.split(key)
        self.state = self._reset_fn(jax.random.split(reset_key, self.num_arenas))
        self._decide_now()
        self.episode_steps = 0

    def _decide_now(self) -> None:
        self._rng, key = jax.random.split(self._rng)
        self._actions, attention = self._decide(self.state, self._params(), key)
        self._host = self._fetch(attention)

    def set_policy(self, team: str, policy: Policy) -> None:
        """Swaps a team's policy (recompiles) and re-decides the pending actions."""
        check_fits(policy, self.config, team)
        self.policies[team] = policy
        self._build()
        self._decide_now()
        self._warm_up()

    def set_params(self, team: str, variables: Any) -> None:
        """New learned variables for a team (same structure; no recompilation)."""
        self.policies[team] = dataclasses.replace(self.policies[team], variables=variables)

    def step(self) -> None:
        """One control step of every arena still playing."""
        self._rng, key = jax.random.split(self._rng)
        self.state, self._actions, attention = self._tick(
            self.state, self._actions, self._params(), key
        )
        self._host = self._fetch(attention)
        self.episode_steps += 1

    def _fetch(self, attention: dict[str, jax.Array]) -> dict[str, Any]:
        w = self.state.world
        host = jax.device_get(
            {
                "pos": w.pos,
                "yaw": w.yaw,
                "active": w.active,
                "cause": w.cause,
                "obstacles": w.obstacles,
                "step": w.step,
                "done": self.state.done,
                "attention": attention,
            }
        )
        return host

    # -- what there is to see

    @property
    def done(self) -> bool:
        """Every arena has finished its episode."""
        return bool(np.all(self._host["done"] > 0))

    def frame(self) -> Frame:
        h = self._host
        poses = np.concatenate([h["pos"], h["yaw"][..., None]], axis=-1)
        return Frame(poses=poses, active=h["active"], cause=h["cause"], obstacles=h["obstacles"])

    def positions(self) -> np.ndarray:
        """[B, N, 2]."""
        return np.asarray(self._host["pos"])

    def attention(self, team: str, arena: int, agent: int) -> AttentionOverlay | None:
        """The overlay of agent `agent` (index within its team) of arena `arena`, if MIX."""
        weights = self._host["attention"].get(team)
        if weights is None:
            return None
        cfg = self.config
        arena = int(np.clip(arena, 0, self.num_arenas - 1))
        agent = int(np.clip(agent, 0, cfg.team(team).num_agents - 1))
        index, kinds = attention_targets(cfg, team)
        pos = self._host["pos"][arena]
        targets = np.concatenate([pos[index[agent]], self._host["obstacles"][arena][:, :2]])
        offset = 0 if team == "pursuer" else cfg.pursuer.num_agents
        return AttentionOverlay(
            arena=arena,
            agent=offset + agent,
            targets=targets,
            weights=np.asarray(weights[arena, agent, 1:]),
            kinds=kinds,
        )

    def own_attention(self, team: str, arena: int, agent: int) -> float | None:
        weights = self._host["attention"].get(team)
        if weights is None:
            return None
        return float(weights[arena, agent, 0])

    def counters(self) -> list[dict[str, Any]]:
        """Per arena: time, active agents per team, evaders captured, collisions per cause."""
        return arena_counters(
            self.config,
            self._host["active"],
            self._host["cause"],
            self._host["step"],
            self._host["done"],
        )


def arena_counters(
    config: EnvConfig,
    active: np.ndarray,
    cause: np.ndarray,
    step: np.ndarray,
    done: np.ndarray | None = None,
) -> list[dict[str, Any]]:
    """Counters per arena from active [B, N], cause [B, N] and step [B] (frames of any source)."""
    p = config.pursuer.num_agents
    counts = outcome_counts(np.asarray(cause), np.zeros(np.shape(cause)), p)
    rows = []
    for b in range(active.shape[0]):
        row: dict[str, Any] = {
            "time": float(step[b]) * config.control_dt,
            "pursuers": int(np.sum(active[b, :p])),
            "evaders": int(np.sum(active[b, p:])),
            "captured": int(counts["evaders_capture"][b]),
        }
        for code, name in CAUSE_NAMES.items():
            if code != CAPTURE:
                row[name] = int(counts[f"pursuers_{name}"][b] + counts[f"evaders_{name}"][b])
        row["done"] = bool(done[b] > 0) if done is not None else False
        rows.append(row)
    return rows


__all__ = [
    "LiveRun",
    "PolicyError",
    "arena_counters",
    "attention_targets",
    "check_fits",
    "load_team_policy",
]
