"""LIAM (Papoudakis et al. 2021): the recurrent encoder trained as a deterministic auto-encoder
of the other agents' observations and actions from the controlled agent's own trajectory.

Faithful to the LIAM code (``predator_prey/models.py``, ``agent.py``):

* Encoder: :class:`~transam.models.recurrent.RecurrentEncoder` (LSTM -> ReLU Linear -> z).
* Decoder: two MLP branches on z, each ``Linear(decoder_hidden)`` -> ReLU -> ``Linear`` -> ReLU;
  the observation branch ends in one linear layer to the joint other-agent observation
  o^{-1}_t, the action branch in one linear head per other agent (LIAM's fc6-fc8).
* Loss per step: 0.5 * sum of squared errors over the joint observation + the SUM over the other
  agents of the action NLL (LIAM sums its three heads), averaged over steps and environments.
  The NLL is a cross-entropy on logits (LIAM takes log of a softmax: the same value).
* Deterministic: no sampling, no KL (LIAM's repo has an unused ``kl_coeff``); ``key`` is unused.
* Metrics, comparable with TransAM's: ``obs_mse`` the mean squared error per element,
  ``action_ce`` the cross-entropy averaged over the other agents, ``action_accuracy_newest``
  (one decoded step per z: no all-positions metric, see ``transam.models.base.ACC_ALL``).

Not copied: LIAM clips the encoder's and decoder's gradients separately; the trainer clips the
agent model's parameters as one (its ``max_grad_norm``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from transam.envs.core import PartnerRecord
from transam.models.base import ACC_NEWEST, Decoded, LocalStep, Params
from transam.models.recurrent import LSTMCarry, RecurrentModel


class LIAMDecoder(nn.Module):
    """z [..., E] -> (joint other-agent obs [..., N*D], action logits [..., N, A])."""

    num_others: int
    other_obs_dim: int
    other_num_actions: int
    hidden: int

    @nn.compact
    def __call__(self, z: jax.Array) -> tuple[jax.Array, jax.Array]:
        h = nn.relu(nn.Dense(self.hidden, name="obs_fc1")(z))
        h = nn.relu(nn.Dense(self.hidden, name="obs_fc2")(h))
        obs = nn.Dense(self.num_others * self.other_obs_dim, name="obs_out")(h)
        g = nn.relu(nn.Dense(self.hidden, name="act_fc1")(z))
        g = nn.relu(nn.Dense(self.hidden, name="act_fc2")(g))
        # A kernel [hidden, N, A]: one linear head per other agent.
        logits = nn.DenseGeneral((self.num_others, self.other_num_actions), name="act_out")(g)
        return obs, logits


@dataclass(frozen=True)
class LIAM(RecurrentModel):
    """Parameters ``{"encoder", "decoder"}``."""

    name = "liam"
    privileged = False

    @property
    def decoder(self) -> LIAMDecoder:
        s = self.spec
        return LIAMDecoder(
            s.num_others, s.other_obs_dim, s.other_num_actions, self.config.decoder_hidden
        )

    def _init_heads(self, key: jax.Array, z: jax.Array) -> dict[str, Params]:
        return {"decoder": self.decoder.init(key, z)["params"]}

    def _decode(self, params: Params, z: jax.Array) -> tuple[jax.Array, jax.Array]:
        out = self.decoder.apply({"params": params["decoder"]}, z)
        return cast(tuple[jax.Array, jax.Array], out)

    def decode(self, params: Params, z: jax.Array, other_obs: jax.Array) -> Decoded:
        """(joint other-agent obs, action logits); ``other_obs`` is ignored (reconstruction)."""
        return self._decode(params, z)

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
        pred_obs, logits = self._decode(params, z)
        tgt_obs = targets.other_obs.reshape(pred_obs.shape).astype(jnp.float32)
        tgt_act = targets.other_actions.astype(jnp.int32)  # [T, N, others]
        sq = (pred_obs - tgt_obs) ** 2
        ce = optax.softmax_cross_entropy_with_integer_labels(logits, tgt_act)  # [T, N, others]
        total = jnp.mean(0.5 * sq.sum(-1) + ce.sum(-1))
        correct = jnp.argmax(logits, axis=-1) == tgt_act
        metrics = {
            "obs_mse": jnp.mean(sq),
            "action_ce": jnp.mean(ce),
            ACC_NEWEST: jnp.mean(correct.astype(jnp.float32)),
        }
        return total, metrics
