"""NAM (no agent modeling): the policy sees its observation and its last action only.

As an agent model, NAM's "embedding" is the one-hot previous action (zeros at an episode's
first step); it has no parameters, no carry and no auxiliary loss.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from transam.envs.core import GameSpec, PartnerRecord
from transam.models.base import Carry, Decoded, LocalStep, ModelDefaults, Params


@dataclass(frozen=True)
class NAM(ModelDefaults):
    num_actions: int
    name: str = "nam"
    privileged: bool = False

    @property
    def embed_dim(self) -> int:
        return self.num_actions

    def init(self, key: jax.Array, spec: GameSpec) -> Params:
        return {}

    def init_carry(self, spec: GameSpec) -> Carry:
        return jnp.zeros((), jnp.float32)

    def _z(self, x: LocalStep) -> jax.Array:
        onehot = jax.nn.one_hot(x.prev_action, self.num_actions, dtype=jnp.float32)
        return jnp.where(x.first, 0.0, onehot)

    def step(
        self, params: Params, carry: Carry, x: LocalStep, key: jax.Array | None = None
    ) -> tuple[Carry, jax.Array]:
        return carry, self._z(x)

    def embed_rollout(
        self, params: Params, carry: Carry, xs: LocalStep, key: jax.Array | None = None
    ) -> jax.Array:
        return jax.vmap(self._z)(xs)

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
