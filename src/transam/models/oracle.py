"""Oracle (privileged upper bound): the policy also sees the other agents at execution time.

z_t = concat(one-hot a_{t-1}, o^{-1}_t flattened, one-hot a^{-1}_{t-1} per other agent): NAM's
input plus the other agents' current observations and previous actions (zeros where there is
no previous action, at an episode's first step). No parameters, no carry, no auxiliary loss.
This is the only :class:`~transam.models.base.PrivilegedModel`: its ``step`` takes a
:class:`~transam.models.base.PartnerView` that the trainer builds from the environment state.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from transam.envs.core import GameSpec, PartnerRecord
from transam.models.base import Carry, Decoded, LocalStep, ModelDefaults, Params, PartnerView


@dataclass(frozen=True)
class Oracle(ModelDefaults):
    spec: GameSpec
    name = "oracle"
    privileged = True  # PRIVILEGED: the execution path receives partner data
    # loss_and_embed gives no z (ModelDefaults): the Oracle's z needs the partner views,
    # which only run_embed hands it.

    @property
    def embed_dim(self) -> int:
        s = self.spec
        return s.num_actions + s.num_others * (s.other_obs_dim + s.other_num_actions)

    def init(self, key: jax.Array, spec: GameSpec) -> Params:
        return {}

    def init_carry(self, spec: GameSpec) -> Carry:
        return jnp.zeros((), jnp.float32)

    def _z(self, x: LocalStep, partner: PartnerView) -> jax.Array:
        own = jnp.where(x.first, 0.0, jax.nn.one_hot(x.prev_action, self.spec.num_actions))
        others = jax.nn.one_hot(partner.other_prev_actions, self.spec.other_num_actions)
        others = jnp.where(x.first, 0.0, others)  # one_hot(-1) is zero as well
        obs = jnp.asarray(partner.other_obs, jnp.float32).reshape(-1)
        return jnp.concatenate([own, obs, others.reshape(-1)])

    def step(
        self,
        params: Params,
        carry: Carry,
        x: LocalStep,
        partner: PartnerView,
        key: jax.Array | None = None,
    ) -> tuple[Carry, jax.Array]:
        return carry, self._z(x, partner)

    def embed_rollout(
        self,
        params: Params,
        carry: Carry,
        xs: LocalStep,
        partner: PartnerView,
        key: jax.Array | None = None,
    ) -> jax.Array:
        return jax.vmap(self._z)(xs, partner)

    def decode(self, params: Params, z: jax.Array, other_obs: jax.Array) -> Decoded:
        return None, None

    def loss(
        self,
        params: Params,
        carry: Carry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
        prior: PartnerRecord | None = None,
        prior_ok: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        return jnp.zeros((), jnp.float32), {}
