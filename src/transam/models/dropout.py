"""Dropout masks for the TransAM encoders: flax's, or packed (``TransAMConfig.dropout_masks``).

Why a second kind: the encoder's dropout stays on while acting (as in the authors' code), and
the random bits of its masks are integer work that counts no FLOPs but cost the streaming
model about 40% of its acting and a quarter of its loss (``benchmarks/profile_training.py``).
flax draws each mask entry from its own 32-bit number; with JAX's partitionable threefry (the
default) each such number is one threefry2x32 block whose two output words are XORed. A packed
mask uses both words of a block and splits each into two 16-bit draws: four mask entries per
block, from the same cipher and key. An entry is dropped where its draw is below
round(rate * 2^16), so the drop probability is that over 2^16 (0.100006 for 0.1); kept entries
are scaled by 1 / (1 - rate), as flax does. The masks differ from flax's, so the numbers do too.
"""

from __future__ import annotations

import math
from typing import Any

import flax.linen as nn
import jax
import jax.extend.random as jax_random
import jax.numpy as jnp
import numpy as np


def packed_keep(key: jax.Array, shape: tuple[int, ...], rate: float) -> jax.Array:
    """A bool mask of ``shape``: True (keep) with probability 1 - round(rate * 2^16) / 2^16."""
    size = math.prod(shape)
    blocks = -(-size // 4)
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        key = jax.random.key_data(key)
    words = jax_random.threefry_2x32(key, jnp.arange(2 * blocks, dtype=jnp.uint32))
    draws = jnp.stack([words & 0xFFFF, words >> 16], axis=-1).reshape(-1)[:size]
    return (draws >= np.uint32(round(rate * 2**16))).reshape(shape)


def packed_dropout(x: jax.Array, rate: float, key: jax.Array) -> jax.Array:
    """``x`` with a packed mask applied (kept entries scaled by 1 / (1 - rate))."""
    keep = packed_keep(key, x.shape, rate)
    return jnp.where(keep, x / (1.0 - rate), jnp.zeros_like(x))


class PackedDropout(nn.Module):
    """``nn.Dropout`` with a packed mask, drawn from the module's ``dropout`` rng."""

    rate: float
    deterministic: bool

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        if self.deterministic or self.rate == 0.0:
            return x
        return packed_dropout(x, self.rate, self.make_rng("dropout"))


def dropout(rate: float, deterministic: bool, masks: str) -> nn.Module:
    """A dropout layer with ``masks`` 'flax' or 'packed' (inside a compact method)."""
    if masks == "packed":
        return PackedDropout(rate, deterministic)
    return nn.Dropout(rate, deterministic=deterministic)


def packed_attention(
    query: jax.Array,
    key: jax.Array,
    value: jax.Array,
    mask: jax.Array | None = None,
    dropout_rng: Any = None,
    dropout_rate: float = 0.0,
    deterministic: bool = True,
) -> jax.Array:
    """``nn.dot_product_attention`` with a packed mask on the attention weights (independent
    entries, as ``broadcast_dropout=False``): an ``attention_fn`` for flax's attention."""
    weights = nn.dot_product_attention_weights(query, key, mask=mask, deterministic=True)
    if not deterministic and dropout_rate > 0.0:
        weights = packed_dropout(weights, dropout_rate, dropout_rng)
    return jnp.einsum("...hqk,...khd->...qhd", weights, value)
