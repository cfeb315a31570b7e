"""CAIL (conditional agent imitation learning): the recurrent encoder trained through a
conditional policy-imitation decoder, after Grover et al. 2018.

* Encoder: :class:`~transam.models.recurrent.RecurrentEncoder`, as LIAM's.
* Decoder: :class:`~transam.models.heads.ImitationHead`, pi_dec(a^{-1,i}_t | o^{-1,i}_t, z_t):
  one MLP shared by the other agents, fed that agent's own observation, z_t and a one-hot of its
  slot (the same decoder as TransAM-im and PEL).
* Loss: cross-entropy of each other agent's action a^{-1,i}_t, averaged over the other agents,
  steps and environments; no observation reconstruction (so no ``obs_mse``). ``key`` is unused.
* Grover et al. condition on an embedding of a *different* episode of the same agent; here, as
  in the paper's online setting, z_t comes from the controlled agent's current episode so far.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import jax
import jax.numpy as jnp
import optax

from transam.envs.core import PartnerRecord
from transam.models.base import ACC_NEWEST, Decoded, LocalStep, Params
from transam.models.heads import ImitationHead
from transam.models.recurrent import LSTMCarry, RecurrentModel


@dataclass(frozen=True)
class CAIL(RecurrentModel):
    """Parameters ``{"encoder", "decoder"}``."""

    name = "cail"
    privileged = False

    @property
    def decoder(self) -> ImitationHead:
        s = self.spec
        return ImitationHead(s.num_others, s.other_num_actions, self.config.decoder_hidden)

    def _init_heads(self, key: jax.Array, z: jax.Array) -> dict[str, Params]:
        other = jnp.zeros((self.spec.num_others, self.spec.other_obs_dim), jnp.float32)
        return {"decoder": self.decoder.init(key, z, other)["params"]}

    def _logits(self, params: Params, z: jax.Array, other_obs: jax.Array) -> jax.Array:
        other = jnp.asarray(other_obs, jnp.float32)
        return cast(jax.Array, self.decoder.apply({"params": params["decoder"]}, z, other))

    def decode(self, params: Params, z: jax.Array, other_obs: jax.Array) -> Decoded:
        return None, self._logits(params, z, other_obs)

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
        logits = self._logits(params, z, targets.other_obs)  # [T, N, others, A]
        tgt = targets.other_actions.astype(jnp.int32)
        ce = optax.softmax_cross_entropy_with_integer_labels(logits, tgt)
        correct = jnp.argmax(logits, axis=-1) == tgt
        total = jnp.mean(ce)
        return total, {
            "action_ce": total,
            ACC_NEWEST: jnp.mean(correct.astype(jnp.float32)),
        }
