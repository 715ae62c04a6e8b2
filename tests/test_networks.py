"""Tests of pe_mjx.networks: shapes, masking, distributions, invariances, transfer across scales."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import pe_mjx
from pe_mjx import networks as nets
from pe_mjx.networks import NetworkConfig

ENTITY_FEATURES = {"teammates": 6, "opponents": 6, "obstacles": 4}
KEYS = tuple(nets.MASK_KEYS.items())


def fake_obs(
    seed: int, lead: tuple[int, ...], counts: tuple[int, int, int], num_actions: int = 39
) -> dict[str, jnp.ndarray]:
    """A random, well-formed team observation with leading dims `lead` (..., A)."""
    rng = np.random.default_rng(seed)

    def bearing(shape):
        a = rng.uniform(-np.pi, np.pi, shape)
        return np.cos(a), np.sin(a)

    own_c, own_s = bearing(lead)
    obs = {
        "own": np.stack(
            [
                rng.integers(0, 2, lead),
                rng.uniform(0, 1, lead),
                own_c,
                own_s,
                rng.uniform(0, 1, lead),
            ],
            axis=-1,
        )
    }
    for kind, n in zip(nets.ENTITY_TYPES, counts, strict=True):
        shape = (*lead, n)
        c, s = bearing(shape)
        d = rng.uniform(0.05, 2.0, shape)
        if kind == "obstacles":
            x = np.stack([d, c, s, rng.uniform(0.05, 0.1, shape)], axis=-1)
        else:
            v = rng.normal(0, 0.5, (*shape, 2))
            x = np.stack([rng.integers(0, 2, shape), d, c, s, v[..., 0], v[..., 1]], axis=-1)
        obs[kind] = x
        obs[nets.MASK_KEYS[kind]] = np.ones(shape, bool)
    mask = rng.uniform(size=(*lead, num_actions)) < 0.7
    mask[..., 0] = True
    obs["action_mask"] = mask
    return {k: jnp.asarray(v, jnp.float32 if v.dtype != bool else bool) for k, v in obs.items()}


def config(encoder: str, counts=(19, 5, 8), **kw) -> NetworkConfig:
    return NetworkConfig(encoder=encoder, mlp_counts=counts if encoder == "mlp" else None, **kw)


@pytest.fixture(scope="module")
def env_obs():
    env = pe_mjx.make("20-5-8", backend="kinematic")
    return jax.jit(env.reset)(jax.random.key(0)).obs


@pytest.fixture(scope="module")
def obs20():
    """[A=20] pursuer-shaped obs at 20-5-8 (T=19, O=5, K=8), 39 actions."""
    return fake_obs(0, (20,), (19, 5, 8))


# Networks and their jitted functions are cached per config, so that tests sharing a config and
# input shapes share one compilation.


@functools.cache
def network(cfg: NetworkConfig, num_actions: int = 39):
    return nets.make_network(cfg, num_actions)


@functools.cache
def _jitted(net, method: str):
    return jax.jit(getattr(net, method))


@functools.cache
def _params(cfg: NetworkConfig, num_actions: int):
    # Random normal params with the tree of `init` (traced, not compiled: compiling `init` costs
    # seconds per network, mostly its random number generation). Real `init` is tested once below.
    obs = fake_obs(0, (20,), (19, 5, 8), num_actions)
    shapes = jax.eval_shape(network(cfg, num_actions).init, jax.random.key(0), obs)
    rng = np.random.default_rng(0)
    return jax.tree.map(lambda s: jnp.asarray(rng.normal(0, 0.3, s.shape), s.dtype), shapes)


def build(cfg: NetworkConfig, num_actions: int = 39):
    """(network, params). Params are made once per shaping config (nearest_k and mix_queries do
    not change them) for a 20-5-8 pursuer obs and apply to any entity counts."""
    shared = cfg.replace(nearest_k=None, mix_queries="own")
    return network(cfg, num_actions), _params(shared, num_actions)


def run(net, params, obs):
    """The jitted apply."""
    return _jitted(net, "apply")(params, obs)


def _close(a, b, tol=1e-5):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), atol=tol, rtol=tol)


def _permute(obs, seed):
    rng = np.random.default_rng(seed)
    out = dict(obs)
    for kind, mkey in KEYS:
        perm = rng.permutation(obs[kind].shape[-2])
        out[kind], out[mkey] = obs[kind][..., perm, :], obs[mkey][..., perm]
    return out


# ----------------------------------------------------------------- config


def test_an_mlp_needs_its_training_counts():
    """The experiment config leaves mlp_counts to the scene (`for_scene`); building an MLP
    network without them fails with the field named."""
    with pytest.raises(ValueError, match="mlp_counts"):
        nets.make_network(NetworkConfig(encoder="mlp"), 39)
    env = pe_mjx.get_preset("20-5-8")
    assert NetworkConfig(encoder="mlp").for_scene(env, "pursuer").mlp_counts == (19, 5, 8)


# ----------------------------------------------------------------- shapes and masking


@pytest.mark.parametrize("encoder", nets.ENCODERS)
def test_output_shapes_any_leading_dims(encoder, env_obs):
    for team, counts, lead in (("pursuer", (19, 5, 8), (3,)), ("evader", (4, 20, 8), (2, 3))):
        obs = env_obs[team]
        a, n_act = obs["action_mask"].shape
        net, params = build(config(encoder, counts), n_act)
        apply = _jitted(net, "apply")
        batched = jax.tree.map(lambda x, lead=lead: jnp.broadcast_to(x, (*lead, *x.shape)), obs)
        logits_b, value_b = apply(params, batched)
        assert logits_b.shape == (*lead, a, n_act) and value_b.shape == (*lead, a)
        if team == "pursuer":  # (A,) as well; the evader checks (B1, B2, A)
            logits, value = apply(params, obs)
            assert logits.shape == (a, n_act) and value.shape == (a,)
            _close((logits_b[0], value_b[0]), (logits, value))
        assert np.all(np.isfinite(logits_b)) and np.all(np.isfinite(value_b))
        masked = ~np.broadcast_to(np.asarray(obs["action_mask"]), logits_b.shape)
        assert np.all(np.asarray(logits_b)[masked] == nets.MASKED_LOGIT)


def test_init_gives_a_near_uniform_policy(env_obs):
    obs = env_obs["pursuer"]
    net = network(NetworkConfig(), 39)
    params = jax.jit(net.init)(jax.random.key(0), obs)
    assert jax.tree.map(jnp.shape, params) == jax.tree.map(jnp.shape, build(NetworkConfig())[1])
    logits, value = run(net, params, obs)
    valid = np.asarray(obs["action_mask"])
    assert np.abs(np.asarray(logits)[valid]).max() < 0.5  # policy output scale 0.01
    np.testing.assert_allclose(nets.entropy(logits), np.log(valid.sum(-1)), rtol=0.02)
    assert np.all(np.isfinite(value))


def test_masked_actions_are_never_sampled(obs20):
    net, params = build(NetworkConfig())
    mask = np.zeros((20, 39), bool)
    mask[:, 30:33] = True  # only three actions allowed
    obs = dict(obs20, action_mask=jnp.asarray(mask))
    logits, _ = run(net, params, obs)
    keys = jax.random.split(jax.random.key(1), 1000)
    actions = np.asarray(jax.vmap(nets.sample_actions, (None, 0))(logits, keys))
    assert actions.shape == (1000, 20) and actions.dtype == np.int32
    assert np.all((actions >= 30) & (actions < 33))
    assert len(np.unique(actions)) == 3
    greedy = np.asarray(nets.greedy_actions(logits))
    assert greedy.dtype == np.int32 and np.all((greedy >= 30) & (greedy < 33))
    assert np.all(np.isfinite(nets.entropy(logits)))


def test_entropy_and_log_prob_by_hand():
    logits = jnp.array([[1.0, 2.0, nets.MASKED_LOGIT, 0.5], [0.0, 0.0, 0.0, 0.0]])
    p0 = np.exp([1.0, 2.0, 0.5]) / np.exp([1.0, 2.0, 0.5]).sum()
    ent = np.array([-(p0 * np.log(p0)).sum(), np.log(4.0)])
    np.testing.assert_allclose(nets.entropy(logits), ent, rtol=1e-6)
    actions = jnp.array([1, 3])
    np.testing.assert_allclose(nets.log_prob(logits, actions), [np.log(p0[1]), np.log(0.25)], 1e-6)
    assert float(nets.log_prob(logits, jnp.array([2, 0]))[0]) < -1e8  # masked: ~ -1e9, finite
    grad = jax.grad(lambda z: jnp.sum(nets.entropy(z) + nets.log_prob(z, actions)))(logits)
    assert np.all(np.isfinite(grad)) and float(grad[0, 2]) == 0.0
    np.testing.assert_array_equal(nets.greedy_actions(logits), [1, 0])


# ----------------------------------------------------------------- invariances


@pytest.mark.parametrize(
    "cfg",
    [NetworkConfig(), NetworkConfig(mix_queries="all"), NetworkConfig(encoder="mean")],
    ids=["mix", "mix-all", "mean"],
)
def test_permutation_invariance(cfg, obs20):
    net, params = build(cfg)
    out = run(net, params, obs20)
    for seed in range(3):
        _close(run(net, params, _permute(obs20, seed)), out)


@pytest.mark.parametrize("encoder", nets.ENCODERS)
def test_padded_entities_do_not_matter(encoder, obs20):
    net, params = build(config(encoder))
    out = run(net, params, obs20)
    padded = dict(obs20)
    for j, (kind, mkey) in enumerate(KEYS):
        x, m = obs20[kind], obs20[mkey]
        junk = jnp.full((20, 3, x.shape[-1]), 1e3 * (j + 1)).at[:, 0, 0].set(jnp.nan)
        # Interleave: a padded entity in front, two at the back.
        padded[kind] = jnp.concatenate([junk[:, :1], x, junk[:, 1:]], axis=1)
        fill = jnp.zeros((20, 1), bool)
        padded[mkey] = jnp.concatenate([fill, m, fill, fill], axis=1)
    # (MLP: the counts now exceed mlp_counts; sorting puts padding last, truncation drops it.)
    _close(run(net, params, padded), out)


# ----------------------------------------------------------------- transfer across scales

SCALES = {  # (teammates, opponents, obstacles) of the pursuer and evader teams
    "16-4-4": [(16, (15, 4, 4)), (4, (3, 16, 4))],
    "24-6-12": [(24, (23, 6, 12)), (6, (5, 24, 12))],
    "240-60-120": [(240, (239, 60, 120)), (60, (59, 240, 120))],
}


@pytest.mark.parametrize("encoder", ["mix", "mean", "birnn"])
def test_params_transfer_across_entity_counts(encoder, obs20):
    net, params = build(config(encoder))
    shapes = jax.tree.map(jnp.shape, params)
    apply = _jitted(net, "apply")
    # One team per scale keeps the test fast; both teams' shapes are covered across the scales.
    for i, (name, (a, counts)) in enumerate(
        [
            ("16-4-4", SCALES["16-4-4"][0]),
            ("24-6-12", SCALES["24-6-12"][1]),
            ("240-60-120", SCALES["240-60-120"][0]),
        ]
    ):
        obs = fake_obs(i, (a,), counts)
        logits, value = apply(params, obs)
        assert logits.shape == (a, 39) and value.shape == (a,), name
        assert np.all(np.isfinite(logits)) and np.all(np.isfinite(value)), name
        init_shapes = jax.eval_shape(net.init, jax.random.key(1), obs)
        assert jax.tree.map(jnp.shape, init_shapes) == shapes, name


def test_mlp_pads_and_truncates(obs20):
    net, params = build(config("mlp"))
    out = run(net, params, obs20)
    # Fewer teammates (padded), more opponents and obstacles (truncated) than at training.
    logits, value = run(net, params, fake_obs(1, (20,), (15, 6, 12)))
    assert logits.shape == (20, 39) and np.all(np.isfinite(logits))
    assert np.all(np.isfinite(value))
    # Truncation keeps the nearest: extra entities farther than all others change nothing.
    far = dict(obs20)
    for kind, mkey in KEYS:
        extra = obs20[kind][:, :2]
        extra = extra.at[..., nets.DIST_INDEX[kind]].set(5.0)
        far[kind] = jnp.concatenate([extra, obs20[kind]], axis=1)
        far[mkey] = jnp.concatenate([obs20[mkey][:, :2], obs20[mkey]], axis=1)
    _close(run(net, params, far), out)
    # Padding is zeros: dropping entities equals masking them out.
    fewer = dict(obs20)
    masked = dict(obs20)
    for kind, mkey in KEYS:
        d = obs20[kind][..., nets.DIST_INDEX[kind]]
        order = jnp.argsort(d, axis=1)
        nearest = jnp.take_along_axis(obs20[kind], order[..., None], axis=1)
        fewer[kind], fewer[mkey] = nearest[:, :3], obs20[mkey][:, :3]
        masked[kind] = nearest
        masked[mkey] = obs20[mkey].at[:, 3:].set(False)
    _close(run(net, params, fewer), run(net, params, masked))


# ----------------------------------------------------------------- nearest-k


def _nearest_only(obs, k):
    out = dict(obs)
    for kind, mkey in KEYS:
        d = np.asarray(obs[kind][..., nets.DIST_INDEX[kind]])
        idx = np.argsort(d, axis=-1, kind="stable")[..., :k]
        out[kind] = jnp.take_along_axis(obs[kind], jnp.asarray(idx)[..., None], axis=-2)
        out[mkey] = jnp.take_along_axis(obs[mkey], jnp.asarray(idx), axis=-1)
    return out


@pytest.mark.parametrize("encoder", nets.ENCODERS)
def test_nearest_k_equals_nearest_only_obs(encoder, obs20):
    k = 2
    net, params = build(config(encoder, (k, k, k), nearest_k=k))
    _close(run(net, params, obs20), run(net, params, _nearest_only(obs20, k)))
    if encoder != "mix":
        return  # the selection below is shared code; checking it with one encoder is enough
    # Invalid entities are never among the kept ones: masking the nearest teammate out
    # equals removing it.
    obs = dict(obs20)
    d = obs20["teammates"][..., 1]
    first = jnp.argmin(d, axis=1)
    obs["teammate_mask"] = obs20["teammate_mask"].at[jnp.arange(20), first].set(False)
    ref = dict(obs)
    keep = np.ones((20, 19), bool)
    keep[np.arange(20), np.asarray(first)] = False
    ref["teammates"] = obs20["teammates"][keep].reshape(20, 18, 6)
    ref["teammate_mask"] = jnp.ones((20, 18), bool)
    _close(run(net, params, obs), run(net, params, ref))


def test_nearest_k_at_least_count_changes_nothing(obs20):
    base, params = build(NetworkConfig())
    big = network(NetworkConfig(nearest_k=19), 39)
    _close(run(big, params, obs20), run(base, params, obs20))


# ----------------------------------------------------------------- attention weights


def _attention(net, params, obs):
    out, state = jax.jit(functools.partial(net.apply, mutable=["intermediates"]))(params, obs)
    (weights,) = state["intermediates"]["encoder"]["attention"]
    return out, np.asarray(weights)


@pytest.mark.parametrize("queries", nets.MIX_QUERIES)
def test_attention_weights_are_sown(queries, obs20):
    net, params = build(NetworkConfig(mix_queries=queries))
    obs = dict(obs20, obstacle_mask=obs20["obstacle_mask"].at[:, -2:].set(False))
    out, w = _attention(net, params, obs)
    _close(out, run(net, params, obs))  # sowing changes nothing
    assert w.shape == (20, 4, 1 + 19 + 5 + 8)
    np.testing.assert_allclose(w.sum(-1), 1.0, atol=1e-5)
    assert np.all(w >= 0) and np.all(w[..., -2:] == 0)  # padded obstacles get nothing
    batched = jax.tree.map(lambda x: jnp.stack([x, x]), obs)
    _, wb = _attention(net, params, batched)
    assert wb.shape == (2, 20, 4, 33)
    np.testing.assert_allclose(wb[1], w, atol=1e-6)
    # Token order own, teammates, opponents, obstacles, in the observation's entity order:
    # permuting the teammates permutes their weights.
    perm = np.random.default_rng(0).permutation(19)
    permuted = dict(obs, teammates=obs["teammates"][:, perm])
    _, wp = _attention(net, params, permuted)
    np.testing.assert_allclose(wp[..., 1:20], w[..., 1:20][..., perm], atol=1e-5)


def test_attention_weights_with_nearest_k(obs20):
    net, params = build(NetworkConfig(nearest_k=2))
    _, w = _attention(net, params, obs20)
    assert w.shape == (20, 4, 33)
    np.testing.assert_allclose(w.sum(-1), 1.0, atol=1e-5)
    for kind, start, n in (("teammates", 1, 19), ("opponents", 20, 5), ("obstacles", 25, 8)):
        d = np.asarray(obs20[kind][..., nets.DIST_INDEX[kind]])
        far = np.argsort(d, axis=-1)[:, 2:]
        got = np.take_along_axis(w[..., start : start + n], far[:, None, :], axis=-1)
        assert np.all(got == 0), kind  # only the 2 nearest of each type are attended to
        assert np.all(w[..., start : start + n].sum(-1) > 0), kind


# ----------------------------------------------------------------- edge cases


@pytest.mark.parametrize("encoder", nets.ENCODERS)
def test_empty_entity_sets_and_gradients(encoder):
    net, params = build(config(encoder))
    for counts in [(0, 3, 2), (2, 0, 0)]:
        obs = fake_obs(2, (1, 3), counts)

        def loss(p, obs=obs, net=net):
            logits, value = net.apply(p, obs)
            acts = nets.greedy_actions(logits)
            loss = jnp.sum(value**2 - nets.log_prob(logits, acts) - nets.entropy(logits))
            return loss, (logits, value)

        (_, (logits, value)), grads = jax.jit(jax.value_and_grad(loss, has_aux=True))(params)
        assert logits.shape == (1, 3, 39) and value.shape == (1, 3)
        assert np.all(np.isfinite(logits)) and np.all(np.isfinite(value))
        assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(grads))


def test_parameter_counts_do_not_depend_on_entity_counts():
    small, big = fake_obs(0, (4,), (3, 1, 1)), fake_obs(0, (4,), (30, 10, 20))
    for encoder in ("mix", "mean", "birnn"):
        net = nets.make_network(config(encoder), 39)
        n_small = nets.num_params(jax.eval_shape(net.init, jax.random.key(0), small))
        assert n_small == nets.num_params(jax.eval_shape(net.init, jax.random.key(0), big))
