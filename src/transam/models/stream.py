"""Streaming TransAM (``TransAMConfig.attention="stream"``): each token is encoded once.

The window model (:mod:`transam.models.transam`) re-encodes the last K steps at every step, so
acting costs a 3K-token encoder pass per step and training one per step of the rollout. Here
the same tokens (r_{t-1}, a_{t-1}, o_t per step, or one fused token; position-in-episode
embedding of t; the same token layers, blocks and reconstruction head) go through *causal*
attention over a sliding span, Transformer-XL style:

* Span: token g attends to itself and the M = ``memory`` tokens before it (default 3K, the
  window's token count), never to a token of an earlier episode. z_t is E^o, the output of
  step t's observation token (its last token), as in TransAM.
* Carry (:class:`StreamCarry`): per layer, the keys and values of the last M tokens (oldest
  first) and which slots hold a token of the current episode. ``step`` empties it when
  ``x.first``, encodes the step's tokens against it, and shifts them in.
* Training (``embed_rollout``, ``loss``): one causal pass over the rollout's T steps (nT
  tokens), with the rollout's starting carry as a fixed memory in front (``stop_gradient``):
  the cached keys and values are what acting computed, the rollout's own tokens are encoded
  with gradients. Episode ids (a running count of ``first``) mask earlier episodes, the memory
  being episode 0. With the same parameters this equals ``step`` applied in order; the trainer
  already stores each rollout's starting carry (``Trajectory.model_carry0``) and the runner's
  carry (checkpointed), so the memory needs no other bookkeeping.
* Positions: absolute, the step's time t within its episode (what ``LocalStep.t`` carries);
  the cached keys hold their positions, so acting and training see the same ones.
* Loss: each step's z decoded once against its own step's targets (the window model's
  per-position terms, :meth:`TransAM.position_terms`); with causal attention an older position
  is the same output again, so ``recon_at`` does not apply and there is no all-positions metric.
* Not supported: ``pool="mean"`` (TransAM-pool's window mean has no streaming counterpart here).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import partial
from typing import cast

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from transam.envs.core import GameSpec, PartnerRecord
from transam.models.base import ACC_ALL, MSE_ALL, Decoded, LocalStep, Params, position_metrics
from transam.models.dropout import dropout
from transam.models.transam import (
    TransAM,
    TransAMConfig,
    WindowCarry,
    batch_rollouts,
    bert_init,
    block_sublayers,
    check_local,
    step_tokens,
    window_entry,
)


@struct.dataclass
class StreamCarry:
    """The execution-path carry: each layer's keys and values of the last M tokens."""

    key: jax.Array  # [layers, M, heads, head_dim] float32, oldest first
    value: jax.Array  # [layers, M, heads, head_dim] float32
    valid: jax.Array  # [M] bool: the slot holds a token of the current episode


def span_mask(memory_valid: jax.Array, episode: jax.Array, per_step: int) -> jax.Array:
    """Which keys each query attends to: [S, M + S] for S = T * ``per_step`` query tokens
    after M memory tokens. Query i (position M + i) sees keys M + i - M ... M + i that are
    valid and of its episode. ``episode`` [T]: each step's episode id, 0 = the memory's."""
    m = memory_valid.shape[0]
    ep_q = jnp.repeat(episode, per_step)
    s = ep_q.shape[0]
    ep_k = jnp.concatenate([jnp.zeros((m,), ep_q.dtype), ep_q])
    valid_k = jnp.concatenate([memory_valid, jnp.ones((s,), bool)])
    q, k = jnp.arange(s)[:, None], jnp.arange(m + s)[None, :]
    return (k >= q) & (k <= q + m) & valid_k[None] & (ep_k[None] == ep_q[:, None])


class _StreamBlock(nn.Module):
    """One block: causal multi-head attention of the new tokens over the cached keys/values
    (fixed: ``stop_gradient``) and their own, then TransAM's residual and feed-forward."""

    config: TransAMConfig
    deterministic: bool

    @nn.compact
    def __call__(
        self, x: jax.Array, mem_key: jax.Array, mem_value: jax.Array, mask: jax.Array
    ) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
        cfg = self.config
        head_dim = cfg.width // cfg.heads
        bert = bert_init(cfg)
        proj = partial(nn.DenseGeneral, (cfg.heads, head_dim), **bert)
        new: dict[str, jax.Array] = {}

        def attend(h: jax.Array) -> jax.Array:
            q = proj(name="query")(h)  # [S, H, D]
            new["key"], new["value"] = proj(name="key")(h), proj(name="value")(h)
            keys = jnp.concatenate([jax.lax.stop_gradient(mem_key), new["key"]])
            values = jnp.concatenate([jax.lax.stop_gradient(mem_value), new["value"]])
            logits = jnp.einsum("shd,jhd->hsj", q * head_dim**-0.5, keys)
            logits = jnp.where(mask[None], logits, jnp.finfo(logits.dtype).min)
            weights = dropout(cfg.dropout, self.deterministic, cfg.masks)(
                jax.nn.softmax(logits, axis=-1)
            )
            out = jnp.einsum("hsj,jhd->shd", weights, values)
            return cast(
                jax.Array, nn.DenseGeneral(cfg.width, axis=(-2, -1), name="out", **bert)(out)
            )

        x = block_sublayers(cfg, self.deterministic, x, attend)
        return x, (new["key"], new["value"])


class _StreamEncoder(nn.Module):
    """T steps [T] of raw local inputs and a carry -> (E^o [T, width], the steps' keys and
    values per layer [layers, nT, heads, head_dim])."""

    config: TransAMConfig
    num_actions: int
    episode_len: int
    deterministic: bool

    @nn.compact
    def __call__(
        self, steps: WindowCarry, memory: StreamCarry, episode: jax.Array
    ) -> tuple[jax.Array, jax.Array, jax.Array]:
        cfg = self.config
        tokens = step_tokens(cfg, self.num_actions, self.episode_len, steps)  # [T, n, width]
        num_steps, n = tokens.shape[:2]
        x = tokens.reshape(num_steps * n, cfg.width)
        if cfg.embed_ln:
            x = nn.LayerNorm(name="embed_ln")(x)
        mask = span_mask(memory.valid, episode, n)
        blocks = nn.scan(
            _StreamBlock,
            variable_axes={"params": 0},
            split_rngs={"params": True, "dropout": True},
            in_axes=(0, 0, nn.broadcast),
            length=cfg.layers,
        )(cfg, self.deterministic, name="blocks")
        x, (keys, values) = blocks(x, memory.key, memory.value, mask)
        if cfg.norm == "pre":
            x = nn.LayerNorm(name="ln_final")(x)
        return x.reshape(num_steps, n, cfg.width)[:, -1], keys, values


@partial(jax.jit, static_argnums=0)
def _init_params(model: StreamTransAM, key: jax.Array) -> Params:
    """Jitted, without the forward pass (as the window model's)."""
    key_enc, key_head = jax.random.split(key)
    steps = jax.eval_shape(lambda: window_entry(_dummy_steps(model.spec)))
    memory = jax.eval_shape(lambda: model.init_carry(model.spec))
    episode = jax.ShapeDtypeStruct((1,), jnp.int32)
    enc = model._encoder(True).lazy_init(key_enc, steps, memory, episode)["params"]
    # The head is the window model's, initialised the same way.
    head = model.window.init(key_head, model.spec)["head"]
    return {"encoder": enc, "head": head}


def _dummy_steps(spec: GameSpec) -> LocalStep:
    return LocalStep(
        obs=jnp.zeros((1, spec.obs_dim), jnp.float32),
        prev_action=jnp.zeros((1,), jnp.int32),
        prev_reward=jnp.zeros((1,), jnp.float32),
        t=jnp.zeros((1,), jnp.int32),
        first=jnp.ones((1,), bool),
    )


@dataclass(frozen=True)
class StreamTransAM:
    """TransAM with streaming attention as an :class:`~transam.models.base.AgentModel` (one
    environment, no batch axis). Parameters: ``{"encoder": ..., "head": ...}``, the head and
    the decoder settings being the window model's (:attr:`window`)."""

    spec: GameSpec
    config: TransAMConfig
    decoder_hidden: int = 128
    privileged = False

    def __post_init__(self) -> None:
        cfg = self.config
        if cfg.attention != "stream":
            raise ValueError(f"StreamTransAM needs attention='stream'; got {cfg.attention!r}")
        if cfg.pool != "last":
            raise ValueError("streaming TransAM reads z from the newest token: pool='last' only")
        if cfg.memory is not None and (isinstance(cfg.memory, bool) or cfg.memory < 1):
            raise ValueError(f"TransAM memory must be >= 1 tokens; got {cfg.memory!r}")
        _ = self.window  # validates the shared settings

    @property
    def window(self) -> TransAM:
        """The window model with the same settings: its head, decoder and loss terms."""
        cfg = dataclasses.replace(self.config, attention="window", memory=None)
        return TransAM(self.spec, cfg, self.decoder_hidden)

    @property
    def name(self) -> str:
        return f"{self.window.name}-stream"

    @property
    def embed_dim(self) -> int:
        return self.config.width

    @property
    def tokens_per_step(self) -> int:
        return 3 if self.config.tokens == "separate" else 1

    @property
    def prior_steps(self) -> int:
        """0: each step is decoded once, in its own rollout (``recon_at`` does not apply)."""
        return 0

    @property
    def memory(self) -> int:
        """M, the tokens each token attends to before itself (the cache length)."""
        m = self.config.memory
        return self.tokens_per_step * self.config.context if m is None else m

    def _encoder(self, deterministic: bool) -> _StreamEncoder:
        return _StreamEncoder(
            self.config, self.spec.num_actions, self.spec.episode_len, deterministic
        )

    def _encode(
        self,
        params: Params,
        steps: WindowCarry,
        memory: StreamCarry,
        episode: jax.Array,
        key: jax.Array | None,
    ) -> tuple[jax.Array, jax.Array, jax.Array]:
        """(E^o [T, width], keys, values [layers, nT, ...]); dropout only when ``key`` is given."""
        variables = {"params": params["encoder"]}
        if key is None or self.config.dropout == 0.0:
            out = self._encoder(True).apply(variables, steps, memory, episode)
        else:
            out = self._encoder(False).apply(
                variables, steps, memory, episode, rngs={"dropout": key}
            )
        return cast(tuple[jax.Array, jax.Array, jax.Array], out)

    # -- protocol --------------------------------------------------------------------------------

    def init(self, key: jax.Array, spec: GameSpec) -> Params:
        if spec != self.spec:
            raise ValueError(f"TransAM built for {self.spec.name!r}, init called for {spec.name!r}")
        # Settings that do not change the parameters share one compiled init.
        shape_cfg = dataclasses.replace(self.config, context=1, dropout=0.0, memory=1)
        return _init_params(dataclasses.replace(self, config=shape_cfg), key)

    def init_carry(self, spec: GameSpec) -> StreamCarry:
        cfg = self.config
        shape = (cfg.layers, self.memory, cfg.heads, cfg.width // cfg.heads)
        return StreamCarry(
            key=jnp.zeros(shape, jnp.float32),
            value=jnp.zeros(shape, jnp.float32),
            valid=jnp.zeros((self.memory,), bool),
        )

    def step(
        self, params: Params, carry: StreamCarry, x: LocalStep, key: jax.Array | None = None
    ) -> tuple[StreamCarry, jax.Array]:
        """(carry, z_t): the carry emptied at an episode's first step, the step's tokens
        encoded against it and shifted in; dropout only when ``key`` is given."""
        check_local(x, self.spec, rollout=False)
        empty = self.init_carry(self.spec)
        carry = jax.tree.map(lambda e, c: jnp.where(x.first, e, c), empty, carry)
        steps = jax.tree.map(lambda a: a[None], window_entry(x))
        z, keys, values = self._encode(params, steps, carry, jnp.zeros((1,), jnp.int32), key)
        m = self.memory
        carry = StreamCarry(
            key=jnp.concatenate([carry.key, keys], axis=1)[:, -m:],
            value=jnp.concatenate([carry.value, values], axis=1)[:, -m:],
            valid=jnp.concatenate([carry.valid, jnp.ones((keys.shape[1],), bool)])[-m:],
        )
        return carry, z[0]

    def embed_rollout(
        self, params: Params, carry: StreamCarry, xs: LocalStep, key: jax.Array | None = None
    ) -> jax.Array:
        """z [T, width]: one causal pass over the rollout with ``carry`` as fixed memory."""
        check_local(xs, self.spec, rollout=True)
        episode = jnp.cumsum(xs.first.astype(jnp.int32))  # 0: the carry's episode
        return self._encode(params, window_entry(xs), carry, episode, key)[0]

    def decode(self, params: Params, z: jax.Array, other_obs: jax.Array | None = None) -> Decoded:
        return self.window.decode(params, z, other_obs)

    def loss(
        self,
        params: Params,
        carry: StreamCarry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
        prior: PartnerRecord | None = None,
        prior_ok: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        """:meth:`rollout_loss` averaged over a batch of rollouts (time-major [T, N]); no
        ``prior`` (``prior_steps`` is 0)."""
        total, metrics, _ = self.loss_and_embed(params, carry, xs, targets, key)
        return total, metrics

    def loss_and_embed(
        self,
        params: Params,
        carry: StreamCarry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
        prior: PartnerRecord | None = None,
        prior_ok: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array], jax.Array]:
        """:meth:`loss` and the z [T, N, width] of the same pass (as
        :meth:`TransAM.loss_and_embed`)."""
        return batch_rollouts(self.rollout_terms, params, carry, xs, targets, key)

    def rollout_loss(
        self,
        params: Params,
        carry: StreamCarry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        """Decoder loss over ONE rollout: :meth:`rollout_terms` without its z."""
        total, metrics, _ = self.rollout_terms(params, carry, xs, targets, key)
        return total, metrics

    def rollout_terms(
        self,
        params: Params,
        carry: StreamCarry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array], jax.Array]:
        """Decoder loss over ONE rollout: each step's z against its own step's targets (the
        window model's terms, each step weighing the same), its metrics, and that z [T, width].
        Metrics: ``action_accuracy_newest`` (every z is a newest position), ``action_ce`` and
        ``obs_mse`` where reconstructed."""
        z = self.embed_rollout(params, carry, xs, key)  # [T, width]
        tgt_other = targets.other_obs.astype(jnp.float32)[:, None]  # [T, 1, N, D]
        tgt_act = targets.other_actions.astype(jnp.int32)[:, None]  # [T, 1, N]
        per_step, ce, mse, logits = self.window.position_terms(
            params, z[:, None], tgt_other, tgt_act
        )
        metrics = position_metrics(logits, tgt_act, jnp.ones(ce.shape, bool), mse)
        metrics = {k: v for k, v in metrics.items() if k not in (ACC_ALL, MSE_ALL)}
        metrics["action_ce"] = jnp.mean(ce)
        return jnp.mean(per_step), metrics, z
