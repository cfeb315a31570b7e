"""The shared A2C policy: LSTM(128) -> Linear(128) + ReLU -> actor logits and critic value.

Every agent-modeling method feeds the same policy with concat(o_t, z_t), as the paper and the
authors' code do, so that methods differ only in z. With a ``horizon`` the agent's own clock
t / horizon is appended (the trainer's ``time_feature``; local data, so every method may see
it). The network acts on any leading batch shape (the trainer passes [num_envs]);
:meth:`Policy.unroll` adds a time axis in front.

The LSTM carry is zeroed inside :meth:`Policy.step` whenever ``first`` is set, so a caller
cannot leak memory across an episode boundary.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from transam.models.base import LocalStep
from transam.models.transam import uniform_init as _uniform

Params = Any
LSTMCarry = tuple[jax.Array, jax.Array]
"""(cell state c, hidden state h), each [..., hidden]."""


def _two_uniforms(bound: float) -> Callable[..., jax.Array]:
    """PyTorch's LSTM has two biases per gate (b_ih + b_hh), each U(-bound, bound)."""

    def init(key: jax.Array, shape: Any, dtype: Any = jnp.float32) -> jax.Array:
        k1, k2 = jax.random.split(key)
        one = _uniform(bound)
        return one(k1, shape, dtype) + one(k2, shape, dtype)

    return init


def _dense(features: int, fan_in: int, torch_init: bool, gain: float, name: str) -> nn.Dense:
    """Orthogonal with ``gain`` and zero bias, or PyTorch's nn.Linear default."""
    if torch_init:
        init = _uniform(fan_in**-0.5)
        return nn.Dense(features, kernel_init=init, bias_init=init, name=name)
    return nn.Dense(features, kernel_init=nn.initializers.orthogonal(gain), name=name)


def _trunk(
    hidden: int, carry: LSTMCarry, x: jax.Array, suffix: str, torch_init: bool = False
) -> tuple[LSTMCarry, jax.Array]:
    """LSTM then Linear + ReLU (orthogonal init, gain sqrt 2; or PyTorch's defaults)."""
    lstm_init: dict[str, Any] = {}
    if torch_init:  # every LSTM weight and bias U(-1/sqrt(hidden), 1/sqrt(hidden))
        bound = hidden**-0.5
        lstm_init = {
            "kernel_init": _uniform(bound),
            "recurrent_kernel_init": _uniform(bound),
            "bias_init": _two_uniforms(bound),
        }
    carry, y = nn.OptimizedLSTMCell(hidden, name=f"lstm{suffix}", **lstm_init)(carry, x)
    fc = _dense(hidden, hidden, torch_init, float(np.sqrt(2)), f"fc{suffix}")
    return carry, nn.relu(fc(y))


class ActorCriticLSTM(nn.Module):
    """One step of the recurrent actor-critic on a batch of (o_t, z_t).

    ``critic_z`` (the reference): actor and critic heads share one trunk on (o_t, z_t).
    Otherwise the critic has its own trunk on o_t alone, and the carry is the two trunks'
    carries side by side ([..., 2 * hidden]).
    """

    num_actions: int
    hidden: int = 128
    critic_z: bool = True
    torch_init: bool = False  # PyTorch's default initialisation (the reference) if set
    z_scale: float = 1.0  # the factor on z in the input (a2c.z_scale)

    @nn.compact
    def __call__(
        self, carry: LSTMCarry, obs: jax.Array, z: jax.Array, first: jax.Array
    ) -> tuple[LSTMCarry, jax.Array, jax.Array]:
        keep = ~first[..., None]
        carry = (jnp.where(keep, carry[0], 0.0), jnp.where(keep, carry[1], 0.0))
        x = jnp.concatenate([obs, self.z_scale * z], axis=-1)
        torch_init = self.torch_init
        if self.critic_z:
            carry, h = _trunk(self.hidden, carry, x, "", torch_init)
            h_critic = h
        else:
            n = self.hidden
            actor_carry, h = _trunk(
                self.hidden, (carry[0][..., :n], carry[1][..., :n]), x, "", torch_init
            )
            critic_carry, h_critic = _trunk(
                self.hidden, (carry[0][..., n:], carry[1][..., n:]), obs, "_critic", torch_init
            )
            carry = (
                jnp.concatenate([actor_carry[0], critic_carry[0]], axis=-1),
                jnp.concatenate([actor_carry[1], critic_carry[1]], axis=-1),
            )
        # Orthogonal init with the usual A2C gains: small actor head (near-uniform policy at
        # the start), unit critic head.
        logits = _dense(self.num_actions, self.hidden, torch_init, 0.01, "actor")(h)
        value = _dense(1, self.hidden, torch_init, 1.0, "critic")(h_critic)
        return carry, logits, value[..., 0]


@dataclass(frozen=True)
class Policy:
    """Pure-function wrapper around :class:`ActorCriticLSTM` (hashable, so usable as static)."""

    num_actions: int
    hidden: int = 128
    horizon: int | None = None  # append t / horizon to the input (None: observation only)
    critic_z: bool = True  # the critic reads z through the shared trunk (else its own, no z)
    torch_init: bool = False  # PyTorch's default initialisation (the reference's) if set
    z_scale: float = 1.0  # the factor on z in the input (a2c.z_scale)

    @property
    def net(self) -> ActorCriticLSTM:
        return ActorCriticLSTM(
            self.num_actions, self.hidden, self.critic_z, self.torch_init, self.z_scale
        )

    def init(self, key: jax.Array, obs_dim: int, z_dim: int) -> Params:
        """Fresh parameters for observations of width ``obs_dim`` and embeddings of ``z_dim``."""
        clock = 0 if self.horizon is None else 1
        return self.net.init(
            key,
            self.init_carry(),
            jnp.zeros((obs_dim + clock,), jnp.float32),
            jnp.zeros((z_dim,), jnp.float32),
            jnp.ones((), bool),
        )

    def inputs(self, x: LocalStep) -> jax.Array:
        """The observation part of the input: o_t, then t / horizon when there is a horizon."""
        obs = jnp.asarray(x.obs, jnp.float32)
        if self.horizon is None:
            return obs
        clock = jnp.asarray(x.t, jnp.float32)[..., None] / self.horizon
        return jnp.concatenate([obs, clock], axis=-1)

    def init_carry(self, batch_shape: tuple[int, ...] = ()) -> LSTMCarry:
        """The all-zero carry (what ``first=True`` resets to)."""
        width = self.hidden if self.critic_z else 2 * self.hidden
        zeros = jnp.zeros((*batch_shape, width), jnp.float32)
        return (zeros, zeros)

    def step(
        self, params: Params, carry: LSTMCarry, x: LocalStep, z: jax.Array
    ) -> tuple[LSTMCarry, jax.Array, jax.Array]:
        """(new carry, action logits [..., num_actions], value [...]) for one step on what the
        agent knows (``x``: o_t, its clock, ``first``) and the embedding ``z``."""
        out = self.net.apply(params, carry, self.inputs(x), z, x.first)
        return cast(tuple[LSTMCarry, jax.Array, jax.Array], out)

    def unroll(
        self, params: Params, carry: LSTMCarry, xs: LocalStep, z: jax.Array
    ) -> tuple[LSTMCarry, jax.Array, jax.Array]:
        """:meth:`step` over a leading time axis T from ``carry``: (final carry, logits [T, ...],
        values [T, ...]); the training path, differentiable through time."""

        def body(c: LSTMCarry, inp: tuple[Any, jax.Array]) -> tuple[LSTMCarry, tuple[Any, Any]]:
            c, logits, value = self.step(params, c, *inp)
            return c, (logits, value)

        carry, (logits, values) = jax.lax.scan(body, carry, (xs, z))
        return carry, logits, values
