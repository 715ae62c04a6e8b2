"""Everything that acts: the `Policy` type, builtin and learned policies, the one resolver from a
spec to a policy, the store that reads trained ones, shipped policies, export and deployment.

    from pe_mjx.policy import resolve_policy
    policy = resolve_policy("mix-20-5-8", "pursuer", env_config)
    actions = policy(state.obs["pursuer"], rng)
"""

from pe_mjx.policy.core import Policy

__all__ = ["Policy", "load_policy", "resolve_policy"]


def __getattr__(name: str):
    # Lazy: the store's orbax loads only when a trained policy is resolved.
    if name in ("load_policy", "resolve_policy"):
        from pe_mjx.policy import resolve

        return getattr(resolve, name)
    raise AttributeError(f"module 'pe_mjx.policy' has no attribute {name!r}")
