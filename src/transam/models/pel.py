"""PEL: TAO's Policy Embedding Learning (Jing et al., ICLR 2024), adapted to local data online.

TAO encodes an opponent's trajectory with a transformer, mean-pools the outputs into a policy
embedding, and trains it with a generative loss (conditional imitation of the opponent's actions,
conditioned on an embedding of ANOTHER trajectory of the same policy) plus alpha times a
discriminative one (InfoNCE, positives = same policy). As the TransAM paper adapts it, the
encoder reads the CONTROLLED agent's own trajectory window and trains online, with the partner
index of the episode as the policy label.

Design (choices the sources leave open):

* Encoder: composed, not copied: PEL holds a :class:`~transam.models.transam.TransAM` with
  ``pool="mean"`` (z_t = mean of the window's valid observation-token outputs) and
  ``decoder="imitate"`` (CAIL's :class:`~transam.models.heads.ImitationHead`, width
  ``BaselineConfig.decoder_hidden``). ``step``, ``embed_rollout``, ``decode``, the carry and
  the parameters ``{"encoder", "head"}`` are that model's; only the loss is PEL's own. The
  token layout is TransAM's (r, a, o) per step (``TransAMConfig.tokens`` applies).
* Generative loss: cross-entropy of each other agent's action a^{-1,i}_t given o^{-1,i}_t and a
  z of ANOTHER environment of the batch at the same rollout step whose episode has the same
  partner (TAO's "another trajectory of the same policy"; deterministic: the next such
  environment in index order, cyclically). Where no other environment has that partner at that
  step (with 13 Spread partners and 10 envs, about half the steps) the step's own z is used, so
  every step trains the decoder. Gradients reach both encoders' passes. The metrics
  ``action_ce`` / ``action_accuracy_newest`` are this loss's (paired z); evaluation's
  ``decode`` uses the own z, as execution has only that. One pooled z per window: no
  all-positions metric.
* Discriminative loss: :func:`~transam.models.heads.supervised_contrastive` over all T x N
  window embeddings of the batch (cosine similarity over ``BaselineConfig.temperature``),
  labels = partner index of each step's episode: positives are every other window with the
  same partner (other steps of the same episode included: they share the hidden policy, as
  CARL's episode positives), negatives the rest. Metric ``contrastive``.
* Total = generative + ``BaselineConfig.pel_alpha`` * discriminative. Dropout as TransAM's
  (only when ``loss`` gets a key).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import optax

from transam.envs.core import GameSpec, PartnerRecord
from transam.models.base import ACC_NEWEST, Decoded, LocalStep, ModelDefaults, Params
from transam.models.config import BaselineConfig
from transam.models.heads import supervised_contrastive
from transam.models.transam import TransAM, TransAMConfig, WindowCarry


def paired_index(labels: jax.Array) -> jax.Array:
    """For labels [T, N]: per (t, n), the next environment m != n (cyclically) with the same
    label at step t, or n itself where there is none."""
    n = labels.shape[-1]
    idx = jnp.arange(n)
    other = (labels[..., :, None] == labels[..., None, :]) & (idx[:, None] != idx[None, :])
    distance = (idx[None, :] - idx[:, None] - 1) % n  # [n, m]: 0 for m = n + 1
    nearest = jnp.argmin(jnp.where(other, distance, n), axis=-1)
    return jnp.where(other.any(-1), nearest, idx)


@dataclass(frozen=True)
class PEL(ModelDefaults):
    """PEL as an :class:`~transam.models.base.AgentModel` (one environment, no batch axis).
    ``loss_and_embed`` gives no z (:class:`~transam.models.base.ModelDefaults`): its loss's
    z has dropout, the policy's (acting's) has none, so the trainer makes its own pass."""

    spec: GameSpec
    config: TransAMConfig = field(default_factory=TransAMConfig)
    baseline: BaselineConfig = field(default_factory=BaselineConfig)
    name = "pel"  # class attributes, not fields: fixed for the method
    privileged = False

    def __post_init__(self) -> None:
        b = self.baseline
        if not b.temperature > 0.0 or not b.pel_alpha >= 0.0:
            raise ValueError(
                f"PEL needs temperature > 0 and pel_alpha >= 0; got {b.temperature}, {b.pel_alpha}"
            )
        _ = self.encoder  # validates the transformer settings

    @property
    def encoder(self) -> TransAM:
        """The TransAM variant that PEL's execution path, decoder and parameters are."""
        cfg = dataclasses.replace(self.config, pool="mean", decoder="imitate")
        return TransAM(self.spec, cfg, decoder_hidden=self.baseline.decoder_hidden)

    @property
    def embed_dim(self) -> int:
        return self.config.width

    def init(self, key: jax.Array, spec: GameSpec) -> Params:
        return self.encoder.init(key, spec)

    def init_carry(self, spec: GameSpec) -> WindowCarry:
        return self.encoder.init_carry(spec)

    def step(
        self, params: Params, carry: WindowCarry, x: LocalStep, key: jax.Array | None = None
    ) -> tuple[WindowCarry, jax.Array]:
        """(carry, z_t) without dropout: PEL acts without it (the registry's ``dropout``
        flag), so ``key`` is unused; its loss has dropout."""
        return self.encoder.step(params, carry, x)

    def embed_rollout(
        self, params: Params, carry: WindowCarry, xs: LocalStep, key: jax.Array | None = None
    ) -> jax.Array:
        return self.encoder.embed_rollout(params, carry, xs)

    def decode(self, params: Params, z: jax.Array, other_obs: jax.Array | None = None) -> Decoded:
        return self.encoder.decode(params, z, other_obs)

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
        """Generative + alpha * discriminative loss over a batch (time-major [T, N])."""
        enc = self.encoder
        num_steps, n = xs.first.shape
        keys = None if key is None else jax.random.split(key, n)

        def embed(c: WindowCarry, x: LocalStep, k: jax.Array | None) -> jax.Array:
            win = enc._windows(c, x)
            return enc._pool(enc._encode(params, win, k), win.valid)

        z = jax.vmap(embed, in_axes=(0, 1, 0), out_axes=1)(carry, xs, keys)  # [T, N, width]
        labels = targets.partner.astype(jnp.int32)
        z_pair = jnp.take_along_axis(z, paired_index(labels)[..., None], axis=1)
        _, logits = enc.decode(params, z_pair, targets.other_obs.astype(jnp.float32))
        assert logits is not None
        actions = targets.other_actions.astype(jnp.int32)  # [T, N, num_others]
        ce = optax.softmax_cross_entropy_with_integer_labels(logits, actions).mean()
        flat = z.reshape(num_steps * n, -1)
        dis = supervised_contrastive(flat, labels.reshape(-1), self.baseline.temperature)
        correct = jnp.argmax(logits, axis=-1) == actions
        metrics = {
            "action_ce": ce,
            ACC_NEWEST: jnp.mean(correct.astype(jnp.float32)),
            "contrastive": dis,
        }
        return ce + self.baseline.pel_alpha * dis, metrics
