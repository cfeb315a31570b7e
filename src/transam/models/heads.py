"""Decoders and contrastive losses shared by several agent models.

* :class:`ImitationHead`: the conditional-imitation decoder of CAIL, TransAM-im and PEL,
  pi_dec(a^{-1,i}_t | o^{-1,i}_t, z_t): one MLP shared by the other agents, fed that agent's own
  observation, the embedding and a one-hot of the agent's slot (slots may play different roles).
* :func:`info_nce`: SimCLR's NT-Xent between two views of each item (positives: the pair;
  negatives: every other item in the batch), cosine similarity over a temperature.
* :func:`supervised_contrastive`: the supervised variant (Khosla et al. 2020): positives are all
  other items with the same label (e.g. the same partner index), negatives the rest.
"""

from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp


class ImitationHead(nn.Module):
    """(z [..., E], other_obs [..., N, D]) -> action logits [..., N, A]."""

    num_others: int
    num_actions: int
    hidden: int = 128

    @nn.compact
    def __call__(self, z: jax.Array, other_obs: jax.Array) -> jax.Array:
        n = self.num_others
        slot = jnp.broadcast_to(jnp.eye(n), (*other_obs.shape[:-2], n, n))
        zz = jnp.broadcast_to(z[..., None, :], (*other_obs.shape[:-1], z.shape[-1]))
        h = jnp.concatenate([other_obs, zz, slot], axis=-1)
        h = nn.relu(nn.Dense(self.hidden, name="fc1")(h))
        h = nn.relu(nn.Dense(self.hidden, name="fc2")(h))
        return nn.Dense(self.num_actions, name="out")(h)


def _cosine(a: jax.Array, b: jax.Array) -> jax.Array:
    a = a / (jnp.linalg.norm(a, axis=-1, keepdims=True) + 1e-8)
    b = b / (jnp.linalg.norm(b, axis=-1, keepdims=True) + 1e-8)
    return a @ b.T


def info_nce(
    anchors: jax.Array, positives: jax.Array, temperature: float, valid: jax.Array | None = None
) -> jax.Array:
    """Mean NT-Xent of ``anchors`` [B, E] against ``positives`` [B, E] (row i's positive is
    row i; every other valid row is a negative). ``valid`` [B] drops rows (none valid: 0)."""
    b = anchors.shape[0]
    valid = jnp.ones((b,), bool) if valid is None else valid
    logits = _cosine(anchors, positives) / temperature
    logits = jnp.where(valid[None, :], logits, -1e9)
    nll = -jnp.diagonal(jax.nn.log_softmax(logits, axis=-1))
    return jnp.sum(nll * valid) / jnp.maximum(valid.sum(), 1)


def supervised_contrastive(
    emb: jax.Array, labels: jax.Array, temperature: float, valid: jax.Array | None = None
) -> jax.Array:
    """Mean SupCon loss of ``emb`` [B, E]: for each valid anchor with at least one valid
    positive (another row with its label), -mean over positives of log softmax over all other
    valid rows. 0 when no anchor has a positive."""
    b = emb.shape[0]
    valid = jnp.ones((b,), bool) if valid is None else valid
    not_self = ~jnp.eye(b, dtype=bool)
    others = valid[None, :] & not_self
    logits = jnp.where(others, _cosine(emb, emb) / temperature, -1e9)
    logp = jax.nn.log_softmax(logits, axis=-1)
    pos = others & (labels[:, None] == labels[None, :])
    n_pos = pos.sum(-1)
    per_anchor = -jnp.sum(jnp.where(pos, logp, 0.0), -1) / jnp.maximum(n_pos, 1)
    use = valid & (n_pos > 0)
    return jnp.sum(per_anchor * use) / jnp.maximum(use.sum(), 1)
