"""The recurrent encoder shared by the LIAM, CARL and CAIL baselines.

One LSTM over the controlled agent's own trajectory, as LIAM's encoder (Papoudakis et al.
2021, ``predator_prey/models.py``): input concat(o_t, one-hot a_{t-1}) (a zero one-hot at an
episode's first step; no reward, as LIAM), ``LSTM(hidden)`` -> ``ReLU(Linear(hidden))`` ->
``Linear(embed_dim)`` = z_t. The hidden ReLU layer is LIAM's (its ``fc1``); the methods differ
only in what trains this encoder (:mod:`transam.models.liam`, :mod:`~transam.models.carl`,
:mod:`~transam.models.cail`).

* Execution (``step``): the carry is the LSTM state (c, h), zeroed inside ``step`` when
  ``x.first``, so nothing crosses an episode boundary.
* Training (``embed_rollout``): ``lax.scan`` of the very same step function from the stored
  carry, i.e. truncated BPTT over the rollout as in LIAM (the carry itself is a constant).
* Parameters: ``{"encoder": ..., <the method's heads>}``; a method adds its training-only heads
  by overriding :meth:`RecurrentModel._init_heads`.
* z gets no RL gradient by default (``backprop_encoder`` off, as LIAM's ``detach``): each
  method's own loss is what trains the encoder.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from typing import Any, cast

import flax.linen as nn
import jax
import jax.numpy as jnp

from transam.envs.core import GameSpec, PartnerRecord
from transam.models.base import Decoded, LocalStep, ModelDefaults, Params
from transam.models.config import BaselineConfig

LSTMCarry = tuple[jax.Array, jax.Array]
"""(cell state c, hidden state h), each [hidden]."""


class RecurrentEncoder(nn.Module):
    """One step of the encoder on one environment: (carry, LocalStep) -> (carry, z_t)."""

    num_actions: int
    hidden: int
    embed_dim: int

    @nn.compact
    def __call__(self, carry: LSTMCarry, x: LocalStep) -> tuple[LSTMCarry, jax.Array]:
        first = jnp.asarray(x.first, bool)
        carry = (jnp.where(first, 0.0, carry[0]), jnp.where(first, 0.0, carry[1]))
        prev = jax.nn.one_hot(x.prev_action, self.num_actions, dtype=jnp.float32)
        prev = jnp.where(first, 0.0, prev)
        inp = jnp.concatenate([jnp.asarray(x.obs, jnp.float32), prev], axis=-1)
        carry, y = nn.OptimizedLSTMCell(self.hidden, name="lstm")(carry, inp)
        h = nn.relu(nn.Dense(self.hidden, name="fc")(y))
        return carry, nn.Dense(self.embed_dim, name="embed")(h)


def check_local(x: Any, obs_dim: int, rollout: bool, who: str) -> None:
    """Refuse anything but a :class:`LocalStep` of the right shape (partner data included)."""
    if type(x) is not LocalStep:
        raise TypeError(
            f"{who}'s execution/training paths take a LocalStep; got {type(x).__name__}. "
            "Partner data (PartnerRecord) goes to `loss` as targets only."
        )
    have = tuple(x.obs.shape[1:] if rollout else x.obs.shape)
    if have != (obs_dim,):
        where = "xs.obs [T, obs_dim]" if rollout else "x.obs [obs_dim] (one env; vmap for a batch)"
        raise ValueError(f"{who} expects {where} with obs_dim {obs_dim}; got {x.obs.shape}")


@partial(jax.jit, static_argnums=0)
def _init_params(model: RecurrentModel, key: jax.Array) -> Params:
    """Jitted: one compiled program instead of many eager ops."""
    k_enc, k_heads = jax.random.split(key)
    spec = model.spec
    x = LocalStep(
        obs=jnp.zeros((spec.obs_dim,), jnp.float32),
        prev_action=jnp.zeros((), jnp.int32),
        prev_reward=jnp.zeros((), jnp.float32),
        t=jnp.zeros((), jnp.int32),
        first=jnp.ones((), bool),
    )
    enc = model.encoder.init(k_enc, model.init_carry(spec), x)["params"]
    z = jnp.zeros((model.embed_dim,), jnp.float32)
    return {"encoder": enc, **model._init_heads(k_heads, z)}


@dataclass(frozen=True)
class RecurrentModel(ModelDefaults):
    """The encoder half of a recurrent baseline (one environment, no batch axis).

    Subclasses set ``name`` and ``privileged`` and implement ``_init_heads``, ``decode`` and
    ``loss``.
    """

    spec: GameSpec
    config: BaselineConfig = field(default_factory=BaselineConfig)

    @property
    def embed_dim(self) -> int:
        return self.config.embed_dim

    @property
    def encoder(self) -> RecurrentEncoder:
        return RecurrentEncoder(self.spec.num_actions, self.config.hidden, self.config.embed_dim)

    def _init_heads(self, key: jax.Array, z: jax.Array) -> dict[str, Params]:
        """The method's training-only heads, keyed by name (none here)."""
        return {}

    # -- protocol --------------------------------------------------------------------------------

    def init(self, key: jax.Array, spec: GameSpec) -> Params:
        if spec != self.spec:
            raise ValueError(f"model built for {self.spec.name!r}, init called for {spec.name!r}")
        return _init_params(self, key)

    def init_carry(self, spec: GameSpec) -> LSTMCarry:
        zeros = jnp.zeros((self.config.hidden,), jnp.float32)
        return (zeros, zeros)

    def _step(self, params: Params, carry: LSTMCarry, x: LocalStep) -> tuple[LSTMCarry, jax.Array]:
        out = self.encoder.apply({"params": params["encoder"]}, carry, x)
        return cast(tuple[LSTMCarry, jax.Array], out)

    def step(
        self, params: Params, carry: LSTMCarry, x: LocalStep, key: jax.Array | None = None
    ) -> tuple[LSTMCarry, jax.Array]:
        """(carry, z_t); no dropout, so ``key`` is unused."""
        check_local(x, self.spec.obs_dim, rollout=False, who=type(self).__name__)
        return self._step(params, carry, x)

    def embed_rollout(
        self, params: Params, carry: LSTMCarry, xs: LocalStep, key: jax.Array | None = None
    ) -> jax.Array:
        check_local(xs, self.spec.obs_dim, rollout=True, who=type(self).__name__)
        return jax.lax.scan(lambda c, x: self._step(params, c, x), carry, xs)[1]

    def embed_batch(self, params: Params, carry: LSTMCarry, xs: LocalStep) -> jax.Array:
        """z [T, N, embed_dim] of a time-major batch (``carry`` [N, ...], ``xs`` [T, N, ...])."""
        fn = jax.vmap(self.embed_rollout, in_axes=(None, 0, 1), out_axes=1)
        return cast(jax.Array, fn(params, carry, xs))

    def decode(self, params: Params, z: jax.Array, other_obs: jax.Array) -> Decoded:
        return None, None

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
        raise NotImplementedError
