"""The env's stages as pure functions over typed states, composed by `pe_mjx.env`.

In the order of a step: `dynamics` (actions -> motion, kinematic or MJX), `geometry` (offsets and
distances shared by what follows), `events` (who is incapacitated, and why), `rewards` (named
terms), `masks` (the action mask), `observations` and `metrics`; `placement` draws a fresh arena
for `reset`. `world` holds the game state they all read. Every function takes the `EnvConfig` (a
static, hashable value) and arrays; none keeps state, so each can be jitted and timed alone
(`tools/bench_env.py`).
"""
