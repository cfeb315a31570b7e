"""CARL (contrastive agent representation learning): the recurrent encoder trained ONLY with
an InfoNCE loss (SimCLR-style); no decoder, so ``decode`` predicts nothing.

Design choices (the paper gives none beyond "recurrent encoder + InfoNCE"):

* Encoder: :class:`~transam.models.recurrent.RecurrentEncoder`, as LIAM's.
* Items: every step's z_t of the batch, T x N of them (all time steps of all environments).
* Positives (``carl_positives="partner"``, default): any other step of the batch with the
  same partner index (``targets.partner``), the supervised-contrastive variant (Khosla et al.
  2020); this is the issue's definition (same partner policy attracts, different repel) and
  the harder task: with same-episode positives, top-1 accuracy reached ~1.0 within a few
  thousand steps on Spread (adjacent steps of one episode are easy to match), leaving the
  encoder little signal.
* Positives ``"episode"`` (SimCLR-style option): the other steps of the SAME episode in the
  rollout (they share the hidden partner); negatives: every step of any other episode, in other
  environments or on the other side of an episode boundary in the same one. This is SimCLR's
  NT-Xent with several positives per anchor, computed as
  :func:`~transam.models.heads.supervised_contrastive` with the episode as the label. Why not
  one sampled pair per environment: a rollout is short (5 steps x 10 envs by default), so a pair
  per env would give 10 anchors with 9 negatives; using every step gives up to 50 anchors with
  >= 40 negatives each, needs no sampling (the loss is deterministic; ``key`` is unused) and
  handles boundaries by construction: an env whose rollout is split by a boundary contributes
  each side as its own episode, and a step alone in its episode within the rollout has no
  positive, so it is no anchor (it stays a negative for the others). The loss works whenever
  at least two steps of one episode are in the batch (with none it is 0).
* Projection head (SimCLR): the loss compares g(z), g = ``Linear(decoder_hidden)`` -> ReLU ->
  ``Linear(embed_dim)``, and the policy uses z itself, as SimCLR uses the representation before
  the projection: the contrastive objective can discard in g what the policy might need.
* Similarity: cosine over ``BaselineConfig.temperature`` (0.1, SimCLR's range 0.1-0.5).
* Metrics: ``contrastive`` (the loss) and ``contrastive_accuracy``: over the anchors that have a
  positive, how often the most similar other item is one of the positives.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import flax.linen as nn
import jax
import jax.numpy as jnp

from transam.envs.core import PartnerRecord
from transam.models.base import LocalStep, Params
from transam.models.heads import supervised_contrastive
from transam.models.recurrent import LSTMCarry, RecurrentModel


class Projection(nn.Module):
    """SimCLR's projection head g: z [..., E] -> [..., out]."""

    hidden: int
    out: int

    @nn.compact
    def __call__(self, z: jax.Array) -> jax.Array:
        h = nn.relu(nn.Dense(self.hidden, name="fc")(z))
        return nn.Dense(self.out, name="out")(h)


def episode_labels(first: jax.Array) -> jax.Array:
    """A distinct label per (environment, episode) of a time-major batch ``first`` [T, N]:
    env * (T + 1) + number of episode starts in that env up to and including t."""
    num_steps, num_envs = first.shape
    segment = jnp.cumsum(first.astype(jnp.int32), axis=0)  # 0 .. T
    return jnp.arange(num_envs, dtype=jnp.int32)[None, :] * (num_steps + 1) + segment


def top1_accuracy(emb: jax.Array, labels: jax.Array) -> jax.Array:
    """Over the items [B, E] that have another item with their label: the fraction whose most
    similar other item (cosine) has their label."""
    b = emb.shape[0]
    unit = emb / (jnp.linalg.norm(emb, axis=-1, keepdims=True) + 1e-8)
    not_self = ~jnp.eye(b, dtype=bool)
    sim = jnp.where(not_self, unit @ unit.T, -jnp.inf)
    same = (labels[:, None] == labels[None, :]) & not_self
    has_pos = same.any(-1)
    hit = jnp.take_along_axis(same, jnp.argmax(sim, axis=-1)[:, None], axis=-1)[:, 0]
    return jnp.sum(hit & has_pos) / jnp.maximum(has_pos.sum(), 1)


@dataclass(frozen=True)
class CARL(RecurrentModel):
    """Parameters ``{"encoder", "projection"}``; ``decode`` returns ``(None, None)``."""

    name = "carl"
    privileged = False

    @property
    def projection(self) -> Projection:
        return Projection(self.config.decoder_hidden, self.config.embed_dim)

    def _init_heads(self, key: jax.Array, z: jax.Array) -> dict[str, Params]:
        return {"projection": self.projection.init(key, z)["params"]}

    def labels(self, xs: LocalStep, targets: PartnerRecord) -> jax.Array:
        """The positive-pair labels [T, N] of a batch (see the module docstring)."""
        if self.config.carl_positives == "partner":
            return targets.partner.astype(jnp.int32)
        return episode_labels(xs.first)

    def loss(
        self,
        params: Params,
        carry: LSTMCarry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
        prior: PartnerRecord | None = None,
        prior_ok: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        z = self.embed_batch(params, carry, xs)  # [T, N, E]
        proj = cast(jax.Array, self.projection.apply({"params": params["projection"]}, z))
        emb = proj.reshape(-1, proj.shape[-1])
        labels = self.labels(xs, targets).reshape(-1)
        total = supervised_contrastive(emb, labels, self.config.temperature)
        return total, {
            "contrastive": total,
            "contrastive_accuracy": top1_accuracy(jax.lax.stop_gradient(emb), labels),
        }
