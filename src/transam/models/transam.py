"""TransAM: a transformer encoder over the controlled agent's own (r, a, o) token trajectory.

* Tokens: per step t, r_{t-1} (scalar), a_{t-1} (one-hot) and o_t, each through its own linear
  layer, plus a learned position-in-episode embedding of t added to all three; LayerNorm on the
  tokens (``embed_ln``; the authors' model defines that LayerNorm but never applies it). At an
  episode's first step there is no previous action or reward: a zero one-hot and r = 0.
* Window: the last K = ``context`` steps (3K tokens, r, a, o interleaved), left-padded; padding
  and steps from before the current episode are masked out of attention (and zeroed).
* Encoder: ``layers`` blocks (``nn.scan``), post-norm (BERT) or pre-norm, ReLU feed-forward,
  dropout on attention weights and residual branches only when ``loss`` gets a key.
  Bidirectional attention inside the window (``causal=True`` for a causal mask); since the window
  ends at t, z_t = E^o at the newest observation token depends only on steps <= t.
* Execution (``step``): the carry is a :class:`WindowCarry`, the raw local inputs of the last K
  steps (not embeddings), so the training path can rebuild every window with gradients.
* Training (``embed_rollout``, ``loss``): all T windows of a rollout built at once from the carry
  and ``xs`` and encoded as one batch (no scan over time); equals ``step`` applied in order.
* Reconstruction head (training only, ``params["head"]``; the encoder is ``params["encoder"]``):
  one linear layer to the joint other-agent observation, one per other agent to its action
  logits. The loss is MSE + mean over the other agents of a proper cross-entropy on logits (the
  authors' code applies PyTorch's cross-entropy to softmax outputs with the other agents as the
  class axis; ``action_loss="authors"`` reproduces it, :func:`authors_action_loss`). With
  ``recon_at="all"`` every valid observation position of every window is reconstructed, except
  positions holding steps from before the rollout (their targets are not in this rollout's
  data; they were supervised in the previous rollout), so a step early in a rollout is
  supervised in more windows than a late one. ``recon_at="window"`` also reconstructs those
  positions when the trainer hands their targets (``prior``), as the authors' loop does.
* Metrics (:func:`~transam.models.base.position_metrics`): ``action_accuracy_newest`` (and
  ``action_ce``, ``obs_mse``) at each window's newest position, what execution decodes and
  evaluation scores; ``action_accuracy_all_positions`` and ``obs_mse_all_positions`` over
  every valid position, what the authors chart in training. At an older position the later
  observations in the (bidirectional) window reveal the answer, so the second is higher.
* Padding: the reference fills padded action slots with a constant; here padded entries are
  masked and zeroed, so their content is irrelevant.

Ablations (the paper's Table of architecture variants), as :class:`TransAMConfig` settings whose
defaults are TransAM; the method names ``transam-fuse``, ``-pool``, ``-im`` select them:

* ``tokens="fuse"``: concat(r_{t-1}, one-hot a_{t-1}, o_t) through ONE linear layer, one token
  per step (K tokens; same position embedding and LayerNorm); z is that token's output.
* ``pool="mean"``: z_t is the mean of the window's observation-token outputs over its valid
  steps (padding and earlier episodes excluded), instead of the newest one. The decoder is
  trained on that pooled z_t against step t's targets (one term per window; ``recon_at`` does
  not apply), so the head is trained on exactly what the policy and ``decode`` see; per-position
  reconstruction would train an encoder identical to TransAM's and evaluate its head off the
  distribution it was trained on.
* ``decoder="imitate"``: the conditional-imitation decoder of CAIL
  (:class:`~transam.models.heads.ImitationHead`, pi(a^{-1,i}_t | o^{-1,i}_t, z), width
  ``decoder_hidden``) in place of the reconstruction head; loss = mean over the other agents of
  the cross-entropy, at the same positions as the reconstruction (``recon_at``), each position
  given o^{-1} of its own step. No observation prediction: ``decode`` returns (None, logits)
  and there is no ``obs_mse`` metric.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, Literal, cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from transam.envs.core import GameSpec, PartnerRecord
from transam.models.base import (
    ACC_ALL,
    MSE_ALL,
    Decoded,
    LocalStep,
    Params,
    position_metrics,
)
from transam.models.dropout import dropout, packed_attention
from transam.models.heads import ImitationHead


@dataclass(frozen=True)
class TransAMConfig:
    """TransAM encoder and reconstruction-head settings (defaults: the authors' model, with
    their action-loss bug fixed)."""

    context: int = 5
    """K, the window in steps (3K tokens: reward, action, observation per step)"""
    width: int = 128
    """model (token) width"""
    layers: int = 4
    """transformer blocks"""
    heads: int = 4
    """attention heads"""
    ff_width: int = 256
    """inner (feed-forward) width"""
    dropout: float = 0.1
    """dropout on attention weights and residual branches (training path only)"""
    norm: Literal["post", "pre"] = "post"
    """post-norm (BERT, as the authors' code) or pre-norm blocks"""
    causal: bool = False
    """causal attention inside the window (the paper's encoder attends to the whole window)"""
    recon_at: Literal["all", "window", "last"] = "window"
    """reconstruct at every valid position whose targets the trainer has, steps of the
    rollouts collected before it included ('window', default, the authors' code), at every
    valid observation position of each window that holds a step of this rollout ('all'), or
    only at the newest ('last'); ignored with ``pool="mean"`` (one pooled z per window)"""
    tokens: Literal["separate", "fuse"] = "separate"
    """a token per modality (r, a, o: 3K tokens) or one fused token per step (TransAM-fuse)"""
    pool: Literal["last", "mean"] = "last"
    """z = the newest observation-token output, or their mean over the window (TransAM-pool)"""
    decoder: Literal["reconstruct", "imitate"] = "reconstruct"
    """reconstruct others' observations and actions, or imitate their actions (TransAM-im)"""
    embed_ln: bool = False
    """LayerNorm on the stacked tokens before the first block (the authors' model defines
    one but never applies it, default: the encoder gets the summed embeddings as they are)"""
    init: Literal["default", "authors"] = "authors"
    """initialisation: the authors' (default: encoder blocks N(0, 0.02) with zero biases as
    BERT; token embeddings and heads PyTorch's uniform +-1/sqrt(fan_in); position embedding
    N(0, 1)), or flax defaults (LeCun normal kernels, zero biases)"""
    action_loss: Literal["ce", "authors"] = "ce"
    """the action term: mean over the other agents of the cross-entropy over actions ('ce'),
    or the authors' bug ('authors'): PyTorch's cross-entropy applied to softmax outputs
    shaped [other agents, actions], whose class axis is the agents, not the actions (see
    :func:`authors_action_loss`)"""
    attention: Literal["window", "stream"] = "window"
    """re-encode the K-step window at every step ('window', the paper's model), or encode each
    token once with causal attention over a key/value cache of the last ``memory`` tokens
    carried between steps ('stream', :mod:`transam.models.stream`; pool="last" only)"""
    memory: int | None = None
    """tokens the streaming encoder attends to before each token (its key/value cache length;
    None: the window's token count, 3K, or K with tokens="fuse"); 'stream' only"""
    dropout_masks: Literal["flax", "packed"] | None = None
    """how dropout masks are drawn: flax's, one threefry block per entry ('flax'), or four
    16-bit draws per block ('packed', :mod:`transam.models.dropout`: faster, other masks);
    None: 'flax' for the window model (keeps its recorded numbers), 'packed' for 'stream'"""

    @property
    def masks(self) -> Literal["flax", "packed"]:
        """``dropout_masks`` resolved: what the encoder uses."""
        if self.dropout_masks is not None:
            return self.dropout_masks
        return "packed" if self.attention == "stream" else "flax"


# --------------------------------------------------------------------------------------------
# The model.
#
# Design (see the module docstring for the summary):
# * The carry is a buffer of the last K steps' *raw* local inputs, not embeddings, so that the
#   training path can rebuild every window from it and recompute z with gradients.
# * One function, ``_Encoder``, maps windows [..., K] to observation-token outputs; ``step`` calls
#   it on one window and ``embed_rollout`` / ``loss`` on all T windows of a rollout at once, so
#   both paths run the same computation on the same inputs.
# * Entries of a window that are invalid (padding, or from an earlier episode) are zeroed before
#   embedding and hidden from every valid query by the attention mask, so they cannot influence z.


@struct.dataclass
class WindowCarry:
    """The execution-path carry: the last K steps' local inputs, oldest first, newest last.

    ``prev_action`` is -1 where the step had no previous action (an episode's first step), which
    one-hot encodes to a zero vector; ``valid`` is False for padding.
    """

    obs: jax.Array  # [K, obs_dim] float32
    prev_action: jax.Array  # [K] int32
    prev_reward: jax.Array  # [K] float32
    t: jax.Array  # [K] int32
    valid: jax.Array  # [K] bool


_LOCAL_FIELDS = ("obs", "prev_action", "prev_reward", "t", "first")


def check_local(x: Any, spec: GameSpec, rollout: bool) -> None:
    """Refuse anything but a :class:`LocalStep` of the right shape (partner data included)."""
    if type(x) is not LocalStep:
        raise TypeError(
            f"TransAM's execution/training paths take a LocalStep (fields {_LOCAL_FIELDS}); got "
            f"{type(x).__name__}. Partner data (PartnerRecord) goes to `loss` as targets only."
        )
    want = (spec.obs_dim,)
    have = tuple(x.obs.shape[1:] if rollout else x.obs.shape)
    if have != want:
        where = "xs.obs [T, obs_dim]" if rollout else "x.obs [obs_dim] (one env; vmap for a batch)"
        raise ValueError(f"TransAM expects {where} with obs_dim {spec.obs_dim}; got {x.obs.shape}")


def window_entry(x: LocalStep) -> WindowCarry:
    """One (or T) LocalStep(s) as buffer entries: no previous action/reward at an episode start."""
    return WindowCarry(
        obs=jnp.asarray(x.obs, jnp.float32),
        prev_action=jnp.where(x.first, -1, jnp.asarray(x.prev_action, jnp.int32)),
        prev_reward=jnp.where(x.first, 0.0, jnp.asarray(x.prev_reward, jnp.float32)),
        t=jnp.asarray(x.t, jnp.int32),
        valid=jnp.ones_like(x.first, dtype=bool),
    )


def block_sublayers(
    cfg: TransAMConfig,
    deterministic: bool,
    x: jax.Array,
    attend: Callable[[jax.Array], jax.Array],
) -> jax.Array:
    """The residual structure of one block around its attention ``attend`` (post-norm as BERT,
    or pre-norm), with the ReLU feed-forward; called inside a block's compact method, whose
    submodules it names, so the window and the streaming blocks share it."""
    bert = bert_init(cfg)
    drop = dropout(cfg.dropout, deterministic, cfg.masks)

    def feed_forward(h: jax.Array) -> jax.Array:
        h = nn.relu(nn.Dense(cfg.ff_width, name="ff_in", **bert)(h))
        return nn.Dense(cfg.width, name="ff_out", **bert)(h)

    if cfg.norm == "post":
        x = nn.LayerNorm(name="ln_attn")(x + drop(attend(x)))
        return nn.LayerNorm(name="ln_ff")(x + drop(feed_forward(x)))
    x = x + drop(attend(nn.LayerNorm(name="ln_attn")(x)))
    return x + drop(feed_forward(nn.LayerNorm(name="ln_ff")(x)))


def bert_init(cfg: TransAMConfig) -> dict[str, Any]:
    """Kernel initialiser of the encoder blocks: BERT's N(0, 0.02) with ``init="authors"``."""
    return {"kernel_init": nn.initializers.normal(0.02)} if cfg.init == "authors" else {}


class _Block(nn.Module):
    """One transformer encoder block over a window (bidirectional or causal mask), for
    ``nn.scan``."""

    config: TransAMConfig
    deterministic: bool

    @nn.compact
    def __call__(self, x: jax.Array, mask: jax.Array) -> tuple[jax.Array, None]:
        cfg = self.config
        attn = nn.MultiHeadDotProductAttention(
            num_heads=cfg.heads,
            qkv_features=cfg.width,
            out_features=cfg.width,
            dropout_rate=cfg.dropout,
            broadcast_dropout=False,  # independent masks per window
            deterministic=self.deterministic,
            name="attn",
            attention_fn=packed_attention if cfg.masks == "packed" else nn.dot_product_attention,
            **bert_init(cfg),
        )
        return block_sublayers(cfg, self.deterministic, x, lambda h: attn(h, mask=mask)), None


def step_tokens(
    cfg: TransAMConfig, num_actions: int, episode_len: int, w: WindowCarry
) -> jax.Array:
    """Tokens [..., K, n, width] of the steps ``w`` [..., K], before any LayerNorm: per step
    r_{t-1}, a_{t-1}, o_t (n = 3, the observation's last) or one fused token (n = 1), each
    plus the position-in-episode embedding of t. Invalid entries are zeroed so that even their
    (masked) tokens carry nothing stale. Called inside an encoder's compact method, whose
    submodules (``embed_*``) it names, so the window and streaming encoders share it."""
    valid = w.valid
    obs = jnp.where(valid[..., None], w.obs, 0.0)
    reward = jnp.where(valid, w.prev_reward, 0.0)[..., None]
    action = jax.nn.one_hot(jnp.where(valid, w.prev_action, -1), num_actions)
    # Clipped: jnp.take would read NaN past the table (an episode longer than episode_len).
    t = jnp.clip(jnp.where(valid, w.t, 0), 0, episode_len - 1)
    authors = cfg.init == "authors"
    embed_init: dict[str, Any] = {}
    if authors:
        embed_init["embedding_init"] = nn.initializers.normal(1.0)
    pos = nn.Embed(episode_len, cfg.width, name="embed_t", **embed_init)(t)

    def embed(h: jax.Array, name: str) -> jax.Array:
        return _dense(cfg.width, h.shape[-1], authors, name)(h)

    if cfg.tokens == "separate":  # (r_{t-1}, a_{t-1}, o_t) per step
        tokens = [embed(reward, "embed_r"), embed(action, "embed_a"), embed(obs, "embed_o")]
    else:  # one token per step from concat(r_{t-1}, a_{t-1}, o_t)
        tokens = [embed(jnp.concatenate([reward, action, obs], axis=-1), "embed_step")]
    return jnp.stack(tokens, axis=-2) + pos[..., None, :]


class _Encoder(nn.Module):
    """Windows [..., K] of raw local inputs -> observation-token outputs E^o [..., K, width]."""

    config: TransAMConfig
    num_actions: int
    episode_len: int
    deterministic: bool

    @nn.compact
    def __call__(self, w: WindowCarry) -> jax.Array:
        cfg = self.config
        k = w.valid.shape[-1]
        batch = w.valid.shape[:-1]
        valid = w.valid
        tokens = step_tokens(cfg, self.num_actions, self.episode_len, w)  # [..., K, n, width]
        n = tokens.shape[-2]
        x = tokens.reshape(*batch, n * k, cfg.width)
        if cfg.embed_ln:
            x = nn.LayerNorm(name="embed_ln")(x)

        tok_valid = jnp.repeat(valid, n, axis=-1)  # [..., nK]
        mask = tok_valid[..., :, None] & tok_valid[..., None, :]  # [..., query, key]
        if cfg.causal:
            mask = mask & jnp.tril(jnp.ones((n * k, n * k), bool))
        # Padding queries attend to themselves only: no fully masked row; valid queries are
        # unaffected (their own key is valid anyway).
        mask = mask | jnp.eye(n * k, dtype=bool)
        blocks = nn.scan(
            _Block,
            variable_axes={"params": 0},
            split_rngs={"params": True, "dropout": True},
            in_axes=nn.broadcast,
            length=cfg.layers,
        )(cfg, self.deterministic, name="blocks")
        x, _ = blocks(x, mask[..., None, :, :])  # heads axis broadcast
        if cfg.norm == "pre":
            x = nn.LayerNorm(name="ln_final")(x)
        return x.reshape(*batch, k, n, cfg.width)[..., -1, :]


def uniform_init(bound: float) -> Callable[..., jax.Array]:
    """An initialiser drawing U(-bound, bound)."""

    def init(key: jax.Array, shape: Any, dtype: Any = jnp.float32) -> jax.Array:
        return jax.random.uniform(key, shape, dtype, -bound, bound)

    return init


def torch_uniform(fan_in: int) -> Callable[..., jax.Array]:
    """PyTorch's default for a Linear layer's weight and bias: U(-1/sqrt(fan_in), +...)."""
    return uniform_init(fan_in**-0.5)


def _dense(features: int, fan_in: int, torch_init: bool, name: str) -> nn.Dense:
    """A Dense layer, initialised as PyTorch's nn.Linear when ``torch_init``."""
    if not torch_init:
        return nn.Dense(features, name=name)
    init = torch_uniform(fan_in)
    return nn.Dense(features, kernel_init=init, bias_init=init, name=name)


class _Head(nn.Module):
    """Reconstruction head: z -> (joint other-agent obs, per-agent action logits)."""

    num_others: int
    other_obs_dim: int
    other_num_actions: int
    torch_init: bool = False

    @nn.compact
    def __call__(self, z: jax.Array) -> tuple[jax.Array, jax.Array]:
        width = z.shape[-1]
        obs = _dense(self.num_others * self.other_obs_dim, width, self.torch_init, "obs")(z)
        # A kernel [width, N, A]: N independent linear layers, one per other agent.
        init: dict[str, Any] = {}
        if self.torch_init:
            init = {"kernel_init": torch_uniform(width), "bias_init": torch_uniform(width)}
        shape = (self.num_others, self.other_num_actions)
        logits = nn.DenseGeneral(shape, name="actions", **init)(z)
        return obs, logits


def authors_action_loss(logits: jax.Array, actions: jax.Array) -> jax.Array:
    """The authors' action term, bug included: [..., N, A] logits and [..., N] actions -> [...].

    Their code passes softmax probabilities shaped (batch, N other agents, A actions) and the
    one-hot actions to ``torch.nn.functional.cross_entropy``, which takes dimension 1 as the
    class axis: for each action a it is a cross-entropy over the *agents* of the probabilities
    p_i(a), and the mean reduction divides by A. Per position::

        -(1/A) sum_a sum_i onehot_i(a) log softmax_i(p_.(a))

    What it changes: it only rewards p_i(a_i) above the other agents' p_j(a_i), not above
    agent i's other actions; with all probabilities in [0, 1] the softmax over agents can only
    reach e/(e + N - 1), so the loss saturates (2 ln 2 / 5 = 0.277 at a uniform head for N = 2,
    their logged start), and where agents take the same action the terms cancel. A weak,
    bounded push towards the right argmax, and small next to the observation MSE.
    """
    probs = jax.nn.softmax(logits, axis=-1)
    onehot = jax.nn.one_hot(actions, logits.shape[-1])
    over_agents = jax.nn.log_softmax(probs, axis=-2)
    return -jnp.sum(onehot * over_agents, axis=(-2, -1)) / logits.shape[-1]


def batch_rollouts(
    rollout_terms: Callable[..., tuple[jax.Array, dict[str, jax.Array], jax.Array]],
    params: Params,
    carry: Any,
    xs: LocalStep,
    targets: PartnerRecord,
    key: jax.Array | None,
    *extra: Any,
) -> tuple[jax.Array, dict[str, jax.Array], jax.Array]:
    """A per-rollout ``(loss, metrics, z [T, width])`` over a time-major batch [T, N]: the
    mean loss, the mean metrics and z [T, N, width]; one dropout key per rollout. ``extra``
    are further time-major arguments (the window model's ``prior``, ``prior_ok``)."""
    n = xs.first.shape[1]
    keys = None if key is None else jax.random.split(key, n)
    in_axes = (None, 0, 1, 1, 0, *([1] * len(extra)))
    fn = jax.vmap(rollout_terms, in_axes=in_axes, out_axes=(0, 0, 1))
    total, metrics, z = fn(params, carry, xs, targets, keys, *extra)
    return total.mean(), {k: v.mean() for k, v in metrics.items()}, z


@partial(jax.jit, static_argnums=0)
def _init_params(model: TransAM, key: jax.Array) -> Params:
    """Jitted (one program, not hundreds of eager ops) and without the forward pass."""
    key_enc, key_head = jax.random.split(key)
    window = jax.eval_shape(lambda: model.init_carry(model.spec))
    enc = model._encoder(True).lazy_init(key_enc, window)["params"]
    z = jax.ShapeDtypeStruct((model.config.width,), jnp.float32)
    if model.config.decoder == "reconstruct":
        head = model._head().lazy_init(key_head, z)["params"]
    else:
        s = model.spec
        other_obs = jax.ShapeDtypeStruct((s.num_others, s.other_obs_dim), jnp.float32)
        head = model._head().lazy_init(key_head, z, other_obs)["params"]
    return {"encoder": enc, "head": head}


@dataclass(frozen=True)
class TransAM:
    """TransAM as an :class:`~transam.models.base.AgentModel` (one environment, no batch axis).

    Parameters: ``{"encoder": ..., "head": ...}``; the head is used only by ``loss``/``decode``.
    ``decoder_hidden`` is the imitation decoder's width (``decoder="imitate"`` only; the factory
    passes ``BaselineConfig.decoder_hidden``, so TransAM-im's decoder is CAIL's).
    """

    spec: GameSpec
    config: TransAMConfig = TransAMConfig()
    decoder_hidden: int = 128
    privileged = False  # a class attribute, not a field: fixed for the method

    def __post_init__(self) -> None:
        cfg = self.config
        if cfg.context < 1 or cfg.layers < 1 or cfg.heads < 1 or cfg.ff_width < 1:
            raise ValueError(f"TransAM context, layers, heads, ff_width must be >= 1; got {cfg}")
        if cfg.width % cfg.heads:
            raise ValueError(f"TransAM width {cfg.width} must be divisible by heads {cfg.heads}")
        if not 0.0 <= cfg.dropout < 1.0:
            raise ValueError(f"TransAM dropout must be in [0, 1); got {cfg.dropout}")
        if cfg.norm not in ("post", "pre") or cfg.recon_at not in ("all", "window", "last"):
            raise ValueError(f"TransAM norm/recon_at invalid: {cfg.norm!r}, {cfg.recon_at!r}")
        if (
            cfg.tokens not in ("separate", "fuse")
            or cfg.pool not in ("last", "mean")
            or cfg.decoder not in ("reconstruct", "imitate")
        ):
            raise ValueError(
                f"TransAM tokens/pool/decoder invalid: {cfg.tokens!r}, {cfg.pool!r}, "
                f"{cfg.decoder!r}; valid: separate|fuse, last|mean, reconstruct|imitate"
            )
        if self.decoder_hidden < 1:
            raise ValueError(f"TransAM decoder_hidden must be >= 1; got {self.decoder_hidden}")
        if cfg.attention != "window":
            raise ValueError(
                f"TransAM is the window model; attention={cfg.attention!r} is "
                "transam.models.stream.StreamTransAM (make_model picks it)"
            )
        if cfg.init not in ("default", "authors") or cfg.action_loss not in ("ce", "authors"):
            raise ValueError(
                f"TransAM init/action_loss invalid: {cfg.init!r}, {cfg.action_loss!r}; "
                "valid: default|authors, ce|authors"
            )
        if cfg.dropout_masks not in (None, "flax", "packed"):
            raise ValueError(
                f"TransAM dropout_masks invalid: {cfg.dropout_masks!r}; valid: flax|packed|None"
            )

    @property
    def name(self) -> str:
        """``transam``, with the ablations in use as suffixes (``transam-fuse``, ...)."""
        cfg = self.config
        parts = ["transam"]
        parts += ["fuse"] if cfg.tokens == "fuse" else []
        parts += ["pool"] if cfg.pool == "mean" else []
        parts += ["im"] if cfg.decoder == "imitate" else []
        return "-".join(parts)

    @property
    def embed_dim(self) -> int:
        return self.config.width

    @property
    def prior_steps(self) -> int:
        """K-1 with ``recon_at="window"`` (the window positions before a rollout are
        reconstructed from the trainer's targets); 0 otherwise, and with ``pool="mean"``,
        whose loss decodes one pooled z per window."""
        cfg = self.config
        return cfg.context - 1 if cfg.recon_at == "window" and cfg.pool == "last" else 0

    # -- modules ---------------------------------------------------------------------------------

    def _encoder(self, deterministic: bool) -> _Encoder:
        return _Encoder(self.config, self.spec.num_actions, self.spec.episode_len, deterministic)

    def _head(self) -> _Head | ImitationHead:
        s = self.spec
        if self.config.decoder == "imitate":
            return ImitationHead(s.num_others, s.other_num_actions, self.decoder_hidden)
        return _Head(
            s.num_others, s.other_obs_dim, s.other_num_actions, self.config.init == "authors"
        )

    def _encode(self, params: Params, w: WindowCarry, key: jax.Array | None = None) -> jax.Array:
        """E^o [..., K, width] of windows ``w``; dropout only when ``key`` is given."""
        variables = {"params": params["encoder"]}
        if key is None or self.config.dropout == 0.0:
            out = self._encoder(True).apply(variables, w)
        else:
            out = self._encoder(False).apply(variables, w, rngs={"dropout": key})
        return cast(jax.Array, out)

    def _pool(self, emb: jax.Array, valid: jax.Array) -> jax.Array:
        """z [..., width] of windows from their E^o [..., K, width]: the newest, or the mean over
        the valid steps (padding and earlier episodes excluded)."""
        if self.config.pool == "last":
            return emb[..., -1, :]
        w = valid[..., None].astype(emb.dtype)
        return jnp.sum(emb * w, axis=-2) / jnp.maximum(jnp.sum(w, axis=-2), 1.0)

    # -- protocol --------------------------------------------------------------------------------

    def init(self, key: jax.Array, spec: GameSpec) -> Params:
        if spec != self.spec:
            raise ValueError(f"TransAM built for {self.spec.name!r}, init called for {spec.name!r}")
        # Settings that do not change the parameters are normalised so that models differing
        # only in them share one compiled init.
        shape_cfg = dataclasses.replace(
            self.config,
            context=1,
            dropout=0.0,
            causal=False,
            recon_at="all",
            pool="last",
            action_loss="ce",
        )
        return _init_params(dataclasses.replace(self, config=shape_cfg), key)

    def init_carry(self, spec: GameSpec) -> WindowCarry:
        k = self.config.context
        return WindowCarry(
            obs=jnp.zeros((k, spec.obs_dim), jnp.float32),
            prev_action=jnp.full((k,), -1, jnp.int32),
            prev_reward=jnp.zeros((k,), jnp.float32),
            t=jnp.zeros((k,), jnp.int32),
            valid=jnp.zeros((k,), bool),
        )

    def push(self, carry: WindowCarry, x: LocalStep) -> WindowCarry:
        """The carry after ``x``: emptied when ``x.first``, then ``x`` shifted in as newest.

        Parameter-free, so a trainer can precompute carries without running the encoder.
        """
        check_local(x, self.spec, rollout=False)
        empty = self.init_carry(self.spec)
        carry = jax.tree.map(lambda e, c: jnp.where(x.first, e, c), empty, carry)
        new = window_entry(x)
        return jax.tree.map(lambda c, n: jnp.concatenate([c[1:], n[None]], axis=0), carry, new)

    def step(
        self, params: Params, carry: WindowCarry, x: LocalStep, key: jax.Array | None = None
    ) -> tuple[WindowCarry, jax.Array]:
        """(carry, z_t); dropout on only when ``key`` is given (the trainer's act_dropout)."""
        carry = self.push(carry, x)
        z = self._pool(self._encode(params, carry, key), carry.valid)
        return carry, z

    def _windows(self, carry: WindowCarry, xs: LocalStep) -> WindowCarry:
        """All T windows of a rollout [T, K]: window i ends at ``xs[i]``, and entries from an
        earlier episode than its newest step are marked invalid (via the ``first`` flags)."""
        check_local(xs, self.spec, rollout=True)
        k = self.config.context
        num_steps = xs.obs.shape[0]
        seq = jax.tree.map(
            lambda c, n: jnp.concatenate([c[1:], n], axis=0), carry, window_entry(xs)
        )  # [K-1+T]
        # Episode id along the sequence: the carry's valid entries all belong to one episode
        # (``push`` empties it at a boundary); each ``first`` in xs starts a new one.
        starts = jnp.concatenate([jnp.zeros((k - 1,), jnp.int32), xs.first.astype(jnp.int32)])
        episode = jnp.cumsum(starts)
        idx = jnp.arange(num_steps)[:, None] + jnp.arange(k)[None, :]  # [T, K]
        win = jax.tree.map(lambda a: a[idx], seq)
        same = episode[idx] == episode[idx[:, -1:]]
        return win.replace(valid=win.valid & same)

    def embed_rollout(
        self, params: Params, carry: WindowCarry, xs: LocalStep, key: jax.Array | None = None
    ) -> jax.Array:
        win = self._windows(carry, xs)
        return self._pool(self._encode(params, win, key), win.valid)

    def decode(self, params: Params, z: jax.Array, other_obs: jax.Array | None = None) -> Decoded:
        """(joint other-agent obs, action logits) from z [..., width]; with
        ``decoder="imitate"``, (None, logits) from z and ``other_obs`` [..., N, D] (required)."""
        variables = {"params": params["head"]}
        if self.config.decoder == "reconstruct":
            return cast(Decoded, self._head().apply(variables, z))
        if other_obs is None:
            raise ValueError("TransAM's imitation decoder needs other_obs (o^{-1}_t)")
        return None, cast(jax.Array, self._head().apply(variables, z, other_obs))

    @property
    def decodes_positions(self) -> bool:
        """True when each window position has its own decoded embedding (not ``pool="mean"``),
        so an all-positions accuracy exists (see :data:`~transam.models.base.ACC_ALL`)."""
        return self.config.pool == "last"

    def decode_window(
        self, params: Params, carry: WindowCarry, other_obs: jax.Array
    ) -> tuple[Decoded, jax.Array]:
        """The decoder at every position of the window in ``carry`` (one env, [K, ...]):
        ((obs [K, N*D] | None, logits [K, N, A]), valid [K]). ``other_obs`` [K, N, D] is each
        position's o^{-1} (the imitation decoder's input). For the all-positions evaluation
        metric; requires :attr:`decodes_positions`."""
        if not self.decodes_positions:
            raise ValueError(f"{self.name} decodes one pooled z per window, not its positions")
        return self.decode(params, self._encode(params, carry), other_obs), carry.valid

    def position_terms(
        self, params: Params, emb: jax.Array, tgt_other: jax.Array, tgt_act: jax.Array
    ) -> tuple[jax.Array, jax.Array, jax.Array | None, jax.Array]:
        """The decoder's loss terms at decoded embeddings ``emb`` [T, P, width] against their
        targets (o^{-1} [T, P, N, D], a^{-1} [T, P, N]): (loss [T, P], cross-entropy [T, P],
        observation MSE [T, P] or None without a reconstruction, action logits [T, P, N, A]).
        The one definition of the per-position loss (the streaming model uses it too)."""
        pred_obs, logits = self.decode(params, emb, tgt_other)  # [T, P, N*D] | None, [T, P, N, A]
        assert logits is not None  # both decoders predict actions
        ce_each = optax.softmax_cross_entropy_with_integer_labels(logits, tgt_act)  # [T, P, N]
        ce = jnp.mean(ce_each, axis=-1)
        action_term = ce
        if self.config.action_loss == "authors":
            action_term = authors_action_loss(logits, tgt_act)
        per_position = action_term
        mse = None
        if pred_obs is not None:
            tgt_obs = tgt_other.reshape(*tgt_other.shape[:2], -1)
            mse = jnp.mean((pred_obs - tgt_obs) ** 2, axis=-1)  # [T, P]
            per_position = per_position + mse
        return per_position, ce, mse, logits

    def loss(
        self,
        params: Params,
        carry: WindowCarry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
        prior: PartnerRecord | None = None,
        prior_ok: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        """:meth:`rollout_loss` averaged over a batch of rollouts (time-major [T, N]);
        ``prior`` [K-1, N] and ``prior_ok`` [K-1, N] as there."""
        total, metrics, _ = self.loss_and_embed(params, carry, xs, targets, key, prior, prior_ok)
        return total, metrics

    def loss_and_embed(
        self,
        params: Params,
        carry: WindowCarry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
        prior: PartnerRecord | None = None,
        prior_ok: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array], jax.Array]:
        """:meth:`loss` and the z [T, N, width] of the same encoder pass (its dropout mask
        included): what ``embed_rollout`` gives with that pass's key. The authors' update reads
        the reconstruction and the policy's (detached) z off one forward pass (the trainer's
        ``z_pass="shared"``)."""
        extra = () if prior is None else (prior, prior_ok)
        return batch_rollouts(self.rollout_terms, params, carry, xs, targets, key, *extra)

    def rollout_loss(
        self,
        params: Params,
        carry: WindowCarry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
        prior: PartnerRecord | None = None,
        prior_ok: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        """Decoder loss over ONE rollout's windows: :meth:`rollout_terms` without its z."""
        total, metrics, _ = self.rollout_terms(params, carry, xs, targets, key, prior, prior_ok)
        return total, metrics

    def rollout_terms(
        self,
        params: Params,
        carry: WindowCarry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
        prior: PartnerRecord | None = None,
        prior_ok: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array], jax.Array]:
        """Decoder loss over ONE rollout's windows (dropout only when ``key`` is given), its
        metrics, and the windows' z [T, width] from the same pass.

        With ``recon_at="window"`` and ``prior`` (the targets of the K-1 steps before the
        rollout, oldest first; ``prior_ok`` [K-1] marks those the trainer has), positions
        holding those steps are reconstructed too, as the authors' loop does for the earlier
        chunks of its episode. Without ``prior``, "window" is "all".

        Window i ends at rollout step i; its observation position k holds rollout step
        j = i + k - (K-1), decoded from E^o at that position (``recon_at="all"``: every
        valid position with j >= 0; positions from before the rollout have no targets here and
        are masked; ``"last"``: only k = K-1). Each position weighs the same. Per position:
        MSE (mean over the joint observation's elements; not with ``decoder="imitate"``) + mean
        over the other agents of the cross-entropy of their action logits (the imitation decoder
        also gets o^{-1}_j). With ``pool="mean"`` the decoded embedding is the pooled z_i (what
        the policy and ``decode`` see), scored against step i only.

        Metrics: ``action_accuracy_newest``, ``action_ce`` and ``obs_mse`` at the newest
        position of each window (what execution uses); ``action_accuracy_all_positions`` and
        ``obs_mse_all_positions`` over every valid position with targets (j >= 0), whatever
        ``recon_at`` trains: the authors' training accuracy, which the window's look-ahead
        inflates. Absent with ``pool="mean"`` (one decoded embedding per window).
        """
        k = self.config.context
        num_steps = xs.obs.shape[0]
        win = self._windows(carry, xs)
        emb = self._encode(params, win, key)  # [T, K, width]
        z = self._pool(emb, win.valid)  # what embed_rollout gives with this key
        j = jnp.arange(num_steps)[:, None] + jnp.arange(k)[None, :] - (k - 1)
        # scored: the positions that have a target (valid, and a step whose record the trainer
        # holds); the metrics average over these whatever recon_at trains.
        if self.config.pool == "mean":  # one decoded embedding per window: [T, 1, width]
            emb, j = z[:, None], jnp.arange(num_steps)[:, None]
            scored = jnp.ones(j.shape, bool)
        elif self.config.recon_at == "window" and prior is not None:
            assert prior_ok is not None
            targets = jax.tree.map(lambda p, t: jnp.concatenate([p, t]), prior, targets)
            have = jnp.concatenate([prior_ok.astype(bool), jnp.ones((num_steps,), bool)])
            j = j + (k - 1)  # index into prior ++ targets
            num_steps = num_steps + k - 1
            scored = win.valid & have[j]
        else:
            scored = win.valid & (j >= 0)
        if self.config.pool == "mean" or self.config.recon_at != "last":
            weight = scored.astype(jnp.float32)
        else:
            weight = jnp.zeros((num_steps, k)).at[:, -1].set(1.0)
        jc = jnp.clip(j, 0, num_steps - 1)  # [T, P] with P = K or 1 positions
        tgt_other = targets.other_obs.astype(jnp.float32)[jc]  # [T, P, N, D]
        tgt_act = targets.other_actions.astype(jnp.int32)[jc]  # [T, P, N]
        per_position, ce, mse, logits = self.position_terms(params, emb, tgt_other, tgt_act)
        # Metrics: newest position, and every valid position with targets (whatever recon_at
        # trains); one pooled z per window has no positions to average over.
        pooled = self.config.pool == "mean"
        metrics = position_metrics(logits, tgt_act, scored, mse)
        if pooled:
            metrics = {name: v for name, v in metrics.items() if name not in (ACC_ALL, MSE_ALL)}
        metrics["action_ce"] = jnp.mean(ce[:, -1])
        total = jnp.sum(per_position * weight) / jnp.maximum(jnp.sum(weight), 1.0)
        return total, metrics, z
