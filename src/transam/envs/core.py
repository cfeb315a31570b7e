"""Controlled-agent games: one learning agent among partners drawn from a fixed population.

Every paper environment is a :class:`Game` (the multi-agent dynamics) plus a
:class:`~transam.envs.population.Population` (the M fixed joint policies of the other
agents). :class:`ControlledEnv` turns the pair into a single-agent, pure-JAX environment:

* ``reset(key, partner_id=None)`` draws a partner index uniformly (or takes the given one);
* ``step(key, state, action)`` lets the partners act from their own observations, advances the
  game, and auto-resets at the episode end with a freshly drawn partner.

The controlled agent's observation, reward and done are the public outputs. The other agents'
observations and actions and the partner index are a *training-only* record
(:class:`PartnerRecord`): it describes the step just taken, so it lines up in time with the
observation the controlled agent acted on (``record.other_obs`` is o^{-1}_t when the agent acted
on o_t with a_t). Agent models must never feed it to an execution path.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

if TYPE_CHECKING:
    from transam.envs.population import Population

S = TypeVar("S")

MPE_ACTION_NAMES = ("noop", "-x", "+x", "-y", "+y")
"""MPE discrete actions as in PettingZoo/mpe2 and JaxMARL (0 no-op, 1 -x, 2 +x, 3 -y, 4 +y);
the particle-environment fork numbers them 0, +x, -x, +y, -y (converted at its boundary)."""


class EnvError(ValueError):
    """Bad input to an environment: the message names the bad value and the valid choices."""


@dataclass(frozen=True)
class GameSpec:
    """Static metadata of a controlled-agent game (all plain Python values)."""

    name: str
    obs_dim: int
    num_actions: int
    num_others: int
    other_obs_dim: int
    other_num_actions: int
    episode_len: int
    action_names: tuple[str, ...]
    description: str = ""

    @property
    def other_obs_dims(self) -> tuple[int, ...]:
        return (self.other_obs_dim,) * self.num_others

    @property
    def other_action_counts(self) -> tuple[int, ...]:
        return (self.other_num_actions,) * self.num_others


class Game(Protocol, Generic[S]):
    """The multi-agent dynamics of one environment, seen from the controlled agent.

    ``S`` is the game's own state pytree. All methods are pure and jit/vmap-able.
    """

    spec: GameSpec

    def reset(self, key: jax.Array) -> S:
        """A fresh initial state."""
        ...

    def observe(self, state: S) -> tuple[jax.Array, jax.Array]:
        """(controlled obs [obs_dim] float32, other agents' obs [num_others, other_obs_dim])."""
        ...

    def transition(
        self, key: jax.Array, state: S, action: jax.Array, other_actions: jax.Array
    ) -> tuple[S, jax.Array, jax.Array]:
        """Apply the joint action; returns (next state, controlled reward, terminal)."""
        ...


@struct.dataclass
class EnvState:
    """Wrapper state: the game's state plus the hidden partner and the episode clock.

    The observations of the current state are cached so that each step computes them once.
    """

    game: Any
    partner: jax.Array  # int32, index into the population; constant within an episode
    t: jax.Array  # int32, steps taken in the current episode
    obs: jax.Array  # controlled agent's current observation
    other_obs: jax.Array  # [num_others, other_obs_dim], privileged
    other_prev_actions: jax.Array  # [num_others] int32: a^{-1}_{t-1}, -1 at t = 0; privileged


@struct.dataclass
class PartnerRecord:
    """Training-only data about the step just taken (never an input to an execution path)."""

    other_obs: jax.Array  # [num_others, other_obs_dim]: o^{-1}_t, seen when the agent saw o_t
    other_actions: jax.Array  # [num_others] int32: a^{-1}_t, taken alongside the agent's a_t
    partner: jax.Array  # int32 partner index of the episode this step belongs to
    t: jax.Array  # int32 in-episode index of this step (0 for the first step)


@struct.dataclass
class Timestep:
    """What ``step`` returns besides the next state."""

    obs: jax.Array  # next observation (the first of a new episode when ``done``)
    reward: jax.Array  # float32 reward of the controlled agent for this step
    done: jax.Array  # bool: this step ended the episode (terminal or time limit)
    truncated: jax.Array  # bool: ended by the time limit only (for bootstrapping choices)
    record: PartnerRecord


class ForkIntegrator:
    """Mixin for a JaxMARL MPE environment: the particle-environment fork's integrator.

    One entity's step: damp the velocity, add the force, clip the speed (``max_speed`` < 0: no
    cap), then move with the NEW velocity (JaxMARL and mpe2 move with the old one first). The
    TransAM authors' Spread and LIAM's Tag run on the fork. Put it before the JaxMARL class.
    """

    damping: float
    dt: float

    @partial(jax.vmap, in_axes=[None, 0, 0, 0, 0, 0, 0])
    def _integrate_state(
        self,
        p_force: jax.Array,
        p_pos: jax.Array,
        p_vel: jax.Array,
        mass: jax.Array,
        moveable: jax.Array,
        max_speed: jax.Array,
    ) -> tuple[jax.Array, jax.Array]:
        p_vel = p_vel * (1 - self.damping) + (p_force / mass) * self.dt * moveable
        speed = jnp.sqrt(jnp.sum(jnp.square(p_vel)))
        clipped = p_vel / jnp.maximum(speed, 1e-12) * max_speed
        p_vel = jnp.where((speed > max_speed) & (max_speed >= 0), clipped, p_vel)
        return p_pos + p_vel * self.dt, p_vel


def is_concrete(x: Any) -> bool:
    """True when ``x`` holds a value now (not a tracer), so it can be checked eagerly."""
    return not isinstance(x, jax.core.Tracer)


class ControlledEnv:
    """A :class:`Game` plus a partner population, as a single-agent JAX environment."""

    def __init__(self, game: Game[Any], population: Population) -> None:
        if population.num_others != game.spec.num_others:
            raise EnvError(
                f"population {population.name!r} controls {population.num_others} agents but "
                f"game {game.spec.name!r} has {game.spec.num_others} other agents"
            )
        self.game = game
        self.population = population
        self.spec = game.spec

    @property
    def num_partners(self) -> int:
        return self.population.size

    def check_partner(self, partner_id: Any) -> None:
        """Raise :class:`EnvError` for an out-of-range concrete partner index."""
        if partner_id is None or not is_concrete(partner_id):
            return
        arr = np.asarray(partner_id)
        if arr.shape != () or not np.issubdtype(arr.dtype, np.integer):
            raise EnvError(
                f"partner_id must be a scalar integer in [0, {self.num_partners}) for env "
                f"{self.spec.name!r}; got {partner_id!r}"
            )
        if not 0 <= int(arr) < self.num_partners:
            raise EnvError(
                f"partner_id {int(arr)} out of range for env {self.spec.name!r}: valid choices "
                f"are 0..{self.num_partners - 1} ({', '.join(self.population.team_names)})"
            )

    def check_action(self, action: Any) -> None:
        """Raise :class:`EnvError` for an action of the wrong shape or dtype, or out of range.

        Shape and dtype are checked even under ``jit`` (they are static); the range only when
        the value is concrete.
        """
        arr = action if isinstance(action, jax.Array | np.ndarray) else np.asarray(action)
        n = self.spec.num_actions
        choices = ", ".join(f"{i}={a}" for i, a in enumerate(self.spec.action_names))
        if arr.shape != () or not jnp.issubdtype(arr.dtype, jnp.integer):
            raise EnvError(
                f"action for env {self.spec.name!r} must be one integer in [0, {n}) per "
                f"environment ({choices}); got shape {tuple(arr.shape)} dtype {arr.dtype} "
                "(vmap over environments for a batch)"
            )
        if is_concrete(action) and not 0 <= int(arr) < n:
            raise EnvError(
                f"action {int(arr)} out of range for env {self.spec.name!r}: valid choices are "
                f"{choices}"
            )

    def reset(self, key: jax.Array, partner_id: Any = None) -> tuple[EnvState, jax.Array]:
        """Start an episode with partner ``partner_id`` (uniformly drawn when None)."""
        self.check_partner(partner_id)
        key_partner, key_game = jax.random.split(key)
        if partner_id is None:
            partner = jax.random.randint(key_partner, (), 0, self.num_partners, dtype=jnp.int32)
        else:
            partner = jnp.asarray(partner_id, dtype=jnp.int32)
        return self.reset_to(self.game.reset(key_game), partner)

    def reset_to(self, game_state: Any, partner_id: Any) -> tuple[EnvState, jax.Array]:
        """Start an episode from a given game state (e.g. another codebase's start positions:
        :mod:`transam.envs.starts`) with partner ``partner_id``."""
        self.check_partner(partner_id)
        partner = jnp.asarray(partner_id, dtype=jnp.int32)
        obs, other_obs = self.game.observe(game_state)
        state = EnvState(
            game=game_state,
            partner=partner,
            t=jnp.zeros((), jnp.int32),
            obs=obs,
            other_obs=other_obs,
            other_prev_actions=jnp.full((self.spec.num_others,), -1, jnp.int32),
        )
        return state, obs

    def step(self, key: jax.Array, state: EnvState, action: Any) -> tuple[EnvState, Timestep]:
        """Advance one step; auto-resets (new partner drawn) when the episode ends."""
        self.check_action(action)
        action = jnp.asarray(action, jnp.int32)
        key_partner, key_game, key_reset = jax.random.split(key, 3)
        other_actions = self.population.act(key_partner, state.partner, state.other_obs)
        game_state, reward, terminal = self.game.transition(
            key_game, state.game, action, other_actions
        )
        t = state.t + 1
        timeout = t >= self.spec.episode_len
        done = terminal | timeout
        obs, other_obs = self.game.observe(game_state)
        cont = EnvState(
            game=game_state,
            partner=state.partner,
            t=t,
            obs=obs,
            other_obs=other_obs,
            other_prev_actions=jnp.asarray(other_actions, jnp.int32),
        )
        fresh, _ = self.reset(key_reset)
        next_state = jax.tree.map(lambda a, b: jnp.where(done, a, b), fresh, cont)
        record = PartnerRecord(
            other_obs=state.other_obs,
            other_actions=other_actions,
            partner=state.partner,
            t=state.t,
        )
        timestep = Timestep(
            obs=next_state.obs,
            reward=jnp.asarray(reward, jnp.float32),
            done=done,
            truncated=timeout & ~terminal,
            record=record,
        )
        return next_state, timestep
