"""Actor-critic networks: the four state encoders of SPEC 3.1 (paper III-E, IV-A) and their heads.

Input: one team's observation dict (SPEC 2.5) with any number of leading batch dims::

    own [..., A, 5]  teammates [..., A, T, 6]  opponents [..., A, O, 6]  obstacles [..., A, K, 4]
    teammate_mask / opponent_mask / obstacle_mask: bool [..., A, n]
    action_mask: bool [..., A, n_act]

Agent features are ``[g, d, cos, sin, vx, vy]`` (distance at index 1), obstacle features
``[d, cos, sin, r]`` (distance at index 0). T, O or K may be 0. Padded entities (mask False) are
zeroed before encoding, so whatever they hold never reaches the output.

Output of ``make_network(config, num_actions).apply(params, obs)``: ``(logits [..., A, n_act],
value [..., A])``. The logits are masked with ``jnp.where(action_mask, logits, -1e9)``: finite, so
``entropy`` and ``log_prob`` never produce NaN, and a masked action has probability exactly 0.

Encoders (all produce a fixed-size feature whose parameter tree does not depend on T, O, K, except
MLP). "Type net" below is ``relu(Dense(width))`` with one set of weights per entity type.

* ``"mix"`` (Mix-Attention, paper Fig. 2): type nets turn every entity into a token of size
  ``width``; token order is **own, teammates, opponents, obstacles** (1 + T + O + K tokens). One
  multi-head attention layer (query/key/value and output projections shared by all types; the type
  nets make the types distinguishable) runs over all tokens, padded tokens masked out as keys, with
  a residual ``out = token + attn(token)``. Feature: ``[out_own, mean]`` (``2 * width``), where
  ``mean`` is a masked mean over all valid tokens. Which tokens query is ``mix_queries``:

  - ``"own"`` (default): the agent's own token queries all tokens (the own row of the
    self-attention), O(N) per agent; ``mean`` is the mean of the tokens. It never builds per-token
    keys or values: ``q . (x Wk) = x . (Wk q)`` and ``sum_n a_n x_n Wv = (sum_n a_n x_n) Wv``,
    exactly standard attention with O(N W H) instead of O(N W^2) work. The key bias is dropped (it
    cancels in the softmax).
  - ``"all"``: full self-attention, every token queries every token, O(N^2) per agent; ``mean`` is
    the masked mean of ``out`` over valid tokens, computed exactly by averaging the attention rows
    before multiplying by V (the output projection is affine, each row sums to 1). About 4-6x
    slower on CPU (see tools/bench_networks.py).

  Both are permutation-invariant within each type and have the same parameters.
  The own token's attention weights are sown as ``("intermediates", "attention")`` with shape
  ``[..., A, num_heads, 1 + T + O + K]`` in the token order above and in the *original* entity
  order of the observation (also under ``nearest_k``: entities it dropped, and padded entities,
  get weight 0). Each head's weights sum to 1. Read them with
  ``module.apply(params, obs, mutable=["intermediates"])[1]["intermediates"]["encoder"]
  ["attention"][0]``.
* ``"mean"`` (Mean-Embedding): a 2-layer type net per type (``relu(Dense(width))`` twice), masked
  mean per type (0 for an empty set), concatenated with the own embedding (``4 * width``).
* ``"birnn"``: per entity type, a bidirectional GRU (hidden ``width``) over the entities sorted by
  distance, valid first, with ``seq_lengths`` = number of valid entities; the final forward and
  backward states of the three types are concatenated with the own embedding (``7 * width``).
* ``"mlp"``: entities sorted by type then distance (valid first), padded with zeros or truncated to
  ``mlp_counts`` (the training scene's counts), flattened and concatenated with the own features,
  then ``relu(Dense(4 * width))``. Input size is fixed by ``mlp_counts``: it runs at other counts
  (pad/truncate) but does not generalise, which is the paper's point.

``nearest_k`` (every encoder): before encoding, each entity type keeps only its k nearest valid
entities (``lax.top_k`` on minus the distance, invalid entities pushed to the end, masks carried
along). When k >= the count of a type, that type is left untouched.

Heads: one encoder is shared by actor and critic; on top of it sit two *separate* 2-layer tanh MLPs
of ``hidden`` units, one for the policy logits and one for the per-agent value. Initialisation is
orthogonal (gain sqrt(2) for hidden layers, 0.01 for the policy output, 1 for the value output),
biases zero.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from pe_mjx.experiment import NetworkConfig
from pe_mjx.names import ENCODERS, ENTITY_TYPES, MASK_KEYS

__all__ = ["ENCODERS", "MIX_QUERIES", "NetworkConfig", "make_network"]
MIX_QUERIES = ("own", "all")

DIST_INDEX = {"teammates": 1, "opponents": 1, "obstacles": 0}
MASKED_LOGIT = -1e9
_FAR = 1e9  # sort key of padded entities: after every real one
_LECUN = nn.initializers.lecun_normal()


def _is_int(x: Any) -> bool:
    return isinstance(x, int | np.integer) and not isinstance(x, bool)


# --------------------------------------------------------------------------- helpers


def _dense(features: int, scale: float = math.sqrt(2.0), name: str | None = None) -> nn.Dense:
    return nn.Dense(
        features,
        kernel_init=nn.initializers.orthogonal(scale),
        bias_init=nn.initializers.zeros,
        name=name,
    )


def _distance(kind: str, x: jax.Array) -> jax.Array:
    return x[..., DIST_INDEX[kind]]


def _sorted_indices(kind: str, x: jax.Array, mask: jax.Array, k: int) -> jax.Array:
    """Indices [M, k] of the k nearest entities (valid ones first, nearest first)."""
    key = jnp.where(mask, _distance(kind, x), _FAR)
    _, idx = jax.lax.top_k(-key, k)
    return idx


def _gather(x: jax.Array, idx: jax.Array) -> jax.Array:
    return jnp.take_along_axis(x, idx[..., None], axis=1)


def _flatten(obs: dict[str, jax.Array]) -> tuple[tuple[int, ...], dict[str, jax.Array]]:
    """Flattens all leading dims (batch dims and the agent axis) into one axis M."""
    lead = tuple(obs["own"].shape[:-1])
    m = int(np.prod(lead))
    flat = {"own": obs["own"].reshape(m, obs["own"].shape[-1]).astype(jnp.float32)}
    for kind in ENTITY_TYPES:
        x, mask = obs[kind], obs[MASK_KEYS[kind]]
        n = x.shape[-2]
        mask = mask.reshape(m, n).astype(bool)
        x = x.reshape(m, n, x.shape[-1]).astype(jnp.float32)
        flat[kind] = jnp.where(mask[..., None], x, 0.0)  # padded entities are zeros
        flat[MASK_KEYS[kind]] = mask
    return lead, flat


def _nearest(
    flat: dict[str, jax.Array], k: int | None
) -> tuple[dict[str, jax.Array], dict[str, jax.Array | None]]:
    """Keeps the k nearest valid entities per type; returns the new dict and the kept indices
    per type (None where the type was left untouched)."""
    out, kept = dict(flat), {}
    for kind in ENTITY_TYPES:
        x, mask = flat[kind], flat[MASK_KEYS[kind]]
        if k is None or k >= x.shape[1]:
            kept[kind] = None
            continue
        idx = _sorted_indices(kind, x, mask, k)
        out[kind] = _gather(x, idx)
        out[MASK_KEYS[kind]] = jnp.take_along_axis(mask, idx, axis=1)
        kept[kind] = idx
    return out, kept


def _masked_mean(x: jax.Array, mask: jax.Array) -> jax.Array:
    """Mean of x [M, n, F] over its valid rows (mask [M, n]); zeros when none is valid."""
    w = mask.astype(x.dtype)
    count = jnp.maximum(jnp.sum(w, axis=1, keepdims=True), 1.0)
    return jnp.einsum("mnf,mn->mf", x, w) / count


# --------------------------------------------------------------------------- encoders


class TypeNet(nn.Module):
    """Per-entity MLP (relu), applied to every entity of one type."""

    width: int
    layers: int = 1

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        # On 2-D input: XLA:CPU's backward of a dot with several batch axes is ~3x slower.
        lead = x.shape[:-1]
        x = x.reshape(int(np.prod(lead)), x.shape[-1])
        for i in range(self.layers):
            x = nn.relu(_dense(self.width, name=f"dense_{i}")(x))
        return x.reshape(*lead, self.width)


class MixAttentionEncoder(nn.Module):
    """Mix-Attention: per-type tokens, one masked multi-head self-attention layer, pooled."""

    width: int
    num_heads: int
    queries: str = "own"

    @nn.compact
    def __call__(
        self,
        flat: dict[str, jax.Array],
        kept: dict[str, jax.Array | None],
        sizes: Sequence[int],
        lead: Sequence[int],
    ) -> jax.Array:
        m = flat["own"].shape[0]
        tokens = [TypeNet(self.width, name="own_net")(flat["own"])[:, None, :]]
        masks = [jnp.ones((m, 1), dtype=bool)]
        for kind in ENTITY_TYPES:
            tokens.append(TypeNet(self.width, name=f"{kind}_net")(flat[kind]))
            masks.append(flat[MASK_KEYS[kind]])
        x = jnp.concatenate(tokens, axis=1)  # [M, N, W]
        valid = jnp.concatenate(masks, axis=1)  # [M, N]; the own token is always valid
        h = self.num_heads
        d = self.width // h
        valid_f = valid.astype(x.dtype)
        count = jnp.sum(valid_f, axis=1)  # >= 1
        mean_tok = jnp.einsum("mnw,mn->mw", x, valid_f) / count[:, None]

        w = self.width
        wq_k = self.param("query_kernel", _LECUN, (w, h, d))
        wq_b = self.param("query_bias", nn.initializers.zeros, (h, d))
        wk = self.param("key_kernel", _LECUN, (w, h, d))  # no key bias: it cancels in softmax
        wv_k = self.param("value_kernel", _LECUN, (w, h, d))
        wv_b = self.param("value_bias", nn.initializers.zeros, (h, d))
        out = _dense(w, 1.0, name="out")
        scale = 1.0 / math.sqrt(d)
        if self.queries == "own":
            # Only the own token queries, so keys and values never need materialising per token:
            # q.(x Wk) = x.(Wk q) and sum_n a_n (x_n Wv) = (sum_n a_n x_n) Wv. Exactly standard
            # attention, with O(N W H) instead of O(N W^2) work per agent.
            q = jnp.einsum("mw,whd->mhd", x[:, 0], wq_k) + wq_b
            qk = jnp.einsum("mhd,whd->mhw", q, wk) * scale  # [M, H, W]
            scores = jnp.einsum("mnw,mhw->mhn", x, qk)
            own_w = jax.nn.softmax(jnp.where(valid[:, None, :], scores, MASKED_LOGIT), axis=-1)
            pooled = jnp.einsum("mhn,mnw->mhw", own_w, x)  # [M, H, W]
            heads = jnp.einsum("mhw,whd->mhd", pooled, wv_k) + wv_b
            own_out = x[:, 0] + out(heads.reshape(m, h * d))
            mean_out = mean_tok
        else:
            q = jnp.einsum("mnw,whd->mnhd", x, wq_k) + wq_b
            k = jnp.einsum("mnw,whd->mnhd", x, wk)
            v = jnp.einsum("mnw,whd->mnhd", x, wv_k) + wv_b
            scores = jnp.einsum("mqhd,mkhd->mhqk", q, k) * scale
            scores = jnp.where(valid[:, None, None, :], scores, MASKED_LOGIT)
            weights = jax.nn.softmax(scores, axis=-1)  # [M, H, N, N]
            own_w = weights[:, :, 0, :]
            # The mean over valid queries of the attention rows, then times V (exact: the output
            # projection is affine and every row sums to 1).
            mean_w = jnp.einsum("mhqk,mq->mhk", weights, valid_f) / count[:, None, None]
            rows = jnp.stack([own_w, mean_w], axis=1)  # [M, 2, H, N]
            attn = out(jnp.einsum("mrhk,mkhd->mrhd", rows, v).reshape(m, 2, h * d))
            own_out = x[:, 0] + attn[:, 0]
            mean_out = mean_tok + attn[:, 1]

        if self.is_mutable_collection("intermediates"):
            weights = self._original_order(own_w, kept, sizes)
            self.sow("intermediates", "attention", weights.reshape(*lead, *weights.shape[1:]))
        return jnp.concatenate([own_out, mean_out], axis=-1)

    @staticmethod
    def _original_order(
        own_row: jax.Array, kept: dict[str, jax.Array | None], sizes: Sequence[int]
    ) -> jax.Array:
        """Own-token weights [M, H, 1 + T + O + K] in the observation's entity order."""
        m, h = own_row.shape[:2]
        parts, start = [own_row[:, :, :1]], 1
        for kind, size in zip(ENTITY_TYPES, sizes, strict=True):
            idx = kept[kind]
            n = size if idx is None else idx.shape[1]
            w = own_row[:, :, start : start + n]
            start += n
            if idx is not None:
                full = jnp.zeros((m, h, size), w.dtype)
                rows = jnp.arange(m)[:, None, None]
                heads = jnp.arange(h)[None, :, None]
                w = full.at[rows, heads, idx[:, None, :]].set(w)
            parts.append(w)
        return jnp.concatenate(parts, axis=-1)


class MeanEmbeddingEncoder(nn.Module):
    """Mean-Embedding: per-type 2-layer nets, masked mean per type, concatenated with own."""

    width: int

    @nn.compact
    def __call__(self, flat: dict[str, jax.Array], *_: Any) -> jax.Array:
        feats = [TypeNet(self.width, layers=2, name="own_net")(flat["own"])]
        for kind in ENTITY_TYPES:
            emb = TypeNet(self.width, layers=2, name=f"{kind}_net")(flat[kind])
            feats.append(_masked_mean(emb, flat[MASK_KEYS[kind]]))
        return jnp.concatenate(feats, axis=-1)


class BiRNNEncoder(nn.Module):
    """Bi-RNN: a bidirectional GRU per entity type over the entities sorted by distance."""

    width: int

    @nn.compact
    def __call__(self, flat: dict[str, jax.Array], *_: Any) -> jax.Array:
        m = flat["own"].shape[0]
        feats = [TypeNet(self.width, name="own_net")(flat["own"])]
        for kind in ENTITY_TYPES:
            x, mask = flat[kind], flat[MASK_KEYS[kind]]
            n = x.shape[1]
            rnn = nn.Bidirectional(
                nn.RNN(nn.GRUCell(self.width), name=f"{kind}_fwd"),
                nn.RNN(nn.GRUCell(self.width), name=f"{kind}_bwd"),
                return_carry=True,
                name=f"{kind}_birnn",
            )
            if n == 0:
                # Nothing to scan; still create the parameters so the tree is count-independent.
                x, mask, n = jnp.zeros((m, 1, x.shape[2]), x.dtype), jnp.zeros((m, 1), bool), 1
            idx = _sorted_indices(kind, x, mask, n)
            x, mask = _gather(x, idx), jnp.take_along_axis(mask, idx, axis=1)
            lengths = jnp.sum(mask, axis=1).astype(jnp.int32)
            (fwd, bwd), _ = rnn(x, seq_lengths=lengths)
            # A type with no valid entity gives zeros (the GRU would see its zero padding).
            has = (lengths > 0)[:, None]
            feats += [jnp.where(has, fwd, 0.0), jnp.where(has, bwd, 0.0)]
        return jnp.concatenate(feats, axis=-1)


class MLPEncoder(nn.Module):
    """MLP: entities sorted by type then distance, padded/truncated to fixed counts, one layer."""

    width: int
    counts: tuple[int, int, int]

    @nn.compact
    def __call__(self, flat: dict[str, jax.Array], *_: Any) -> jax.Array:
        m = flat["own"].shape[0]
        parts = [flat["own"]]
        for kind, want in zip(ENTITY_TYPES, self.counts, strict=True):
            x, mask = flat[kind], flat[MASK_KEYS[kind]]
            n, f = x.shape[1], x.shape[2]
            if n:
                x = _gather(x, _sorted_indices(kind, x, mask, n))  # padded rows are zeros
            x = x[:, :want] if n >= want else jnp.pad(x, ((0, 0), (0, want - n), (0, 0)))
            parts.append(x.reshape(m, want * f))
        return nn.relu(_dense(4 * self.width, name="dense")(jnp.concatenate(parts, axis=-1)))


# --------------------------------------------------------------------------- actor-critic


class ActorCritic(nn.Module):
    """Shared encoder, separate 2-layer tanh policy and value heads, masked logits."""

    config: NetworkConfig
    num_actions: int

    def setup(self) -> None:
        c = self.config
        if c.encoder == "mix":
            self.encoder = MixAttentionEncoder(c.width, c.num_heads, c.mix_queries)
        elif c.encoder == "mean":
            self.encoder = MeanEmbeddingEncoder(c.width)
        elif c.encoder == "birnn":
            self.encoder = BiRNNEncoder(c.width)
        else:
            assert c.mlp_counts is not None
            self.encoder = MLPEncoder(c.width, c.mlp_counts)
        self.policy_hidden = [_dense(c.hidden) for _ in range(2)]
        self.policy_out = _dense(self.num_actions, 0.01)
        self.value_hidden = [_dense(c.hidden) for _ in range(2)]
        self.value_out = _dense(1, 1.0)

    def __call__(self, obs: dict[str, jax.Array]) -> tuple[jax.Array, jax.Array]:
        lead, flat = _flatten(obs)
        sizes = [flat[kind].shape[1] for kind in ENTITY_TYPES]
        flat, kept = _nearest(flat, self.config.nearest_k)
        feat = self.encoder(flat, kept, sizes, lead)  # [M, F]

        h = feat
        for layer in self.policy_hidden:
            h = jnp.tanh(layer(h))
        logits = self.policy_out(h)
        h = feat
        for layer in self.value_hidden:
            h = jnp.tanh(layer(h))
        value = self.value_out(h)[:, 0]

        mask = obs["action_mask"].reshape(logits.shape).astype(bool)
        logits = jnp.where(mask, logits, MASKED_LOGIT)
        return logits.reshape(*lead, self.num_actions), value.reshape(lead)


def make_network(config: NetworkConfig, num_actions: int) -> ActorCritic:
    """The actor-critic module; ``init(rng, obs)`` / ``apply(params, obs) -> (logits, value)``."""
    if not _is_int(num_actions) or num_actions < 1:
        raise ValueError(f"num_actions must be >= 1, got {num_actions}")
    if config.encoder == "mlp" and config.mlp_counts is None:
        raise ValueError(
            "invalid network config: mlp_counts is required for encoder 'mlp' (the training "
            "scene's entity counts; NetworkConfig.for_scene fills them in)"
        )
    return ActorCritic(config=config, num_actions=int(num_actions))


def num_params(params: Any) -> int:
    """Total number of scalars in a parameter tree."""
    return int(sum(np.prod(x.shape) for x in jax.tree.leaves(params)))


# --------------------------------------------------------------------------- distributions


def sample_actions(logits: jax.Array, rng: jax.Array) -> jax.Array:
    """Samples int32 actions [...] from masked logits [..., n_act]; masked ones never come up."""
    return jax.random.categorical(rng, logits, axis=-1).astype(jnp.int32)


def log_prob(logits: jax.Array, actions: jax.Array) -> jax.Array:
    """log pi(a) [...] for logits [..., n_act] and integer actions [...]."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return jnp.take_along_axis(logp, actions[..., None].astype(jnp.int32), axis=-1)[..., 0]


def entropy(logits: jax.Array) -> jax.Array:
    """Entropy [...] of the categorical over logits [..., n_act]; masked actions add 0."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return -jnp.sum(jnp.exp(logp) * logp, axis=-1)


def greedy_actions(logits: jax.Array) -> jax.Array:
    """The most probable action, int32 [...]."""
    return jnp.argmax(logits, axis=-1).astype(jnp.int32)
