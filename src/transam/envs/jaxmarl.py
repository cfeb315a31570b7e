"""Bring your own JaxMARL game: any JaxMARL ``MultiAgentEnv`` with discrete actions, seen from
one controlled agent, as a :class:`~transam.envs.core.Game` every method can train on.

:func:`make_env` (or :class:`JaxMARLGame` plus :class:`~transam.envs.core.ControlledEnv`) takes
a JaxMARL environment instance, the name of the controlled agent and a partner
:class:`~transam.envs.population.Population` whose slots are the other agents in the order of
``env.agents`` (:func:`partner_agents`). Register it with :func:`transam.register_env` to train
through the Python API (``examples/jaxmarl_adversary.py``). A population directory
(``partners=DIR``) goes through :func:`transam.make_env` as for any registered env, whose entry
then names ``partner_actions``.

How JaxMARL's conventions map onto ours:

* Observations: each agent's entry of the obs dict, flattened to a vector and cast to float32
  (keys that are not agents, e.g. ``world_state``, are ignored). Partners' observations may
  differ in size: ``other_obs`` rows (what the agent models reconstruct) are zero-padded at the
  end to the largest. Each partner policy still receives its own agent's observation at its
  own size (the population is wrapped to cut the padding off).
* Actions: every agent's space must be discrete (``.n``). The controlled agent has its own
  count; partners' actions are counted up to the largest partner space (a smaller space just
  never uses the top indices). Available-action masks are not applied: the controlled agent
  may pick any action, as the environment's ``step_env`` accepts it.
* Steps use ``step_env`` (no JaxMARL auto-reset): :class:`ControlledEnv` resets, with a freshly
  drawn partner team, when the episode ends.
* Episode end: JaxMARL's ``dones["__all__"]`` is a terminal; the time limit is
  ``episode_len`` transitions (default: the env's ``max_steps``), a truncation. The adapter
  keeps its own step count, so a JaxMARL ``__all__`` raised on the last step by the env's own
  clock (MPE raises it one step later still) is a truncation, not a terminal. One agent's own
  done before ``__all__`` does not end the episode.
* Reward: ``rewards[agent]``, the controlled agent's own.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from transam.envs.core import ControlledEnv, EnvError, GameSpec
from transam.envs.population import Member, Population, Team


@struct.dataclass
class JaxMARLState:
    """The JaxMARL env state plus the observations it produced and the adapter's clock."""

    env: Any
    obs: jax.Array  # [obs_dim] the controlled agent's observation
    other_obs: jax.Array  # [num_others, other_obs_dim], zero-padded rows
    t: jax.Array  # int32 transitions taken in this episode


def partner_agents(env: Any, agent: str) -> tuple[str, ...]:
    """The other agents of ``env`` in the order of the population's slots (``env.agents``)."""
    agents = tuple(env.agents)
    if agent not in agents:
        raise EnvError(
            f"controlled agent {agent!r} is not an agent of {type(env).__name__}; valid "
            f"choices: {', '.join(agents)}"
        )
    if len(agents) < 2:
        raise EnvError(f"{type(env).__name__} has no agent besides {agent!r} to model")
    return tuple(a for a in agents if a != agent)


def num_actions(env: Any, agent: str) -> int:
    """The size of ``agent``'s discrete action space (:class:`EnvError` if not discrete)."""
    n = getattr(env.action_space(agent), "n", None)
    if not isinstance(n, int) or n < 1:
        raise EnvError(
            f"agent {agent!r} of {type(env).__name__} has action space "
            f"{env.action_space(agent)!r}; only discrete spaces (with .n) are supported"
        )
    return n


def obs_dims(env: Any) -> dict[str, int]:
    """Each agent's flattened observation size, from the shapes ``reset`` returns (spaces may
    disagree with what the env emits; the shapes cannot)."""
    obs, _ = jax.eval_shape(env.reset, jax.random.key(0))
    missing = [a for a in env.agents if a not in obs]
    if missing:
        raise EnvError(f"{type(env).__name__}.reset returns no observation for {missing}")
    return {a: math.prod(obs[a].shape) for a in env.agents}


def _flat(x: jax.Array) -> jax.Array:
    return jnp.reshape(x, (-1,)).astype(jnp.float32)


class JaxMARLGame:
    """A JaxMARL ``MultiAgentEnv`` seen from agent ``agent`` (module docstring)."""

    def __init__(
        self,
        env: Any,
        agent: str,
        *,
        name: str | None = None,
        episode_len: int | None = None,
        action_names: Sequence[str] | None = None,
        description: str = "",
    ) -> None:
        self.env = env
        self.agent = agent
        self.others = partner_agents(env, agent)
        episode_len = episode_len if episode_len is not None else getattr(env, "max_steps", None)
        if not isinstance(episode_len, int) or episode_len < 1:
            raise EnvError(
                f"{type(env).__name__} has no max_steps (got {episode_len!r}): pass "
                "episode_len, an integer >= 1"
            )
        n = num_actions(env, agent)
        names = tuple(action_names) if action_names is not None else tuple(map(str, range(n)))
        if len(names) != n:
            raise EnvError(f"action_names has {len(names)} names for {n} actions of {agent!r}")
        dims = obs_dims(env)
        self.other_dims = tuple(dims[a] for a in self.others)
        self.spec = GameSpec(
            name=name or type(env).__name__,
            obs_dim=dims[agent],
            num_actions=n,
            num_others=len(self.others),
            other_obs_dim=max(self.other_dims),
            other_num_actions=max(num_actions(env, a) for a in self.others),
            episode_len=episode_len,
            action_names=names,
            description=description or f"JaxMARL {type(env).__name__}, agent {agent!r}",
        )

    def _wrap(self, env_state: Any, obs: dict[str, jax.Array], t: jax.Array) -> JaxMARLState:
        width = self.spec.other_obs_dim
        pairs = zip(self.others, self.other_dims, strict=True)
        rows = [jnp.pad(_flat(obs[a]), (0, width - d)) for a, d in pairs]
        return JaxMARLState(env_state, _flat(obs[self.agent]), jnp.stack(rows), t)

    def reset(self, key: jax.Array) -> JaxMARLState:
        obs, env_state = self.env.reset(key)
        return self._wrap(env_state, obs, jnp.zeros((), jnp.int32))

    def observe(self, state: JaxMARLState) -> tuple[jax.Array, jax.Array]:
        return state.obs, state.other_obs

    def transition(
        self, key: jax.Array, state: JaxMARLState, action: jax.Array, other_actions: jax.Array
    ) -> tuple[JaxMARLState, jax.Array, jax.Array]:
        actions = {self.agent: jnp.asarray(action, jnp.int32)}
        actions.update({a: other_actions[j].astype(jnp.int32) for j, a in enumerate(self.others)})
        obs, env_state, rewards, dones, _ = self.env.step_env(key, state.env, actions)
        t = state.t + 1
        terminal = jnp.asarray(dones["__all__"], bool) & (t < self.spec.episode_len)
        reward = jnp.asarray(rewards[self.agent], jnp.float32)
        return self._wrap(env_state, obs, t), reward, terminal


def own_observations(population: Population, dims: Sequence[int]) -> Population:
    """``population`` with each slot's members fed the first ``dims[j]`` entries of slot j's
    padded observation (their own agent's observation). Unchanged when all sizes are equal; a
    member used in slots of different sizes becomes one member per size (``name@size``)."""
    if len(set(dims)) <= 1:
        return population
    if len(dims) != population.num_others:
        raise EnvError(
            f"population {population.name!r} controls {population.num_others} agents; the "
            f"game has {len(dims)} other agents"
        )
    by_name = {m.name: m for m in population.members}
    sizes: dict[str, set[int]] = {}
    for team in population.teams:
        for s, d in zip(team.slots, dims, strict=True):
            sizes.setdefault(s, set()).add(d)

    def key(member: str, d: int) -> str:
        return member if len(sizes[member]) == 1 else f"{member}@{d}"

    members = {}
    for name, ds in sizes.items():
        m = by_name[name]
        for d in sorted(ds):
            members[key(name, d)] = _cut(m, key(name, d), d)
    teams = [
        Team(t.name, tuple(key(s, d) for s, d in zip(t.slots, dims, strict=True)))
        for t in population.teams
    ]
    return Population(population.name, list(members.values()), teams)


def _cut(member: Member, name: str, size: int) -> Member:
    """``member`` as ``name``, fed the first ``size`` entries of its (padded) observation."""
    act, probs = member.act, member.probs

    def cut_act(key: jax.Array, obs: jax.Array) -> jax.Array:
        return act(key, obs[:size])

    def cut_probs(obs: jax.Array) -> jax.Array:
        assert probs is not None
        return probs(obs[:size])

    return Member(name, cut_act, member.kind, None if probs is None else cut_probs)


def make_env(
    env: Any,
    agent: str,
    population: Population,
    *,
    name: str | None = None,
    episode_len: int | None = None,
    action_names: Sequence[str] | None = None,
) -> ControlledEnv:
    """JaxMARL ``env`` seen from ``agent`` with partners from ``population`` (slots: the other
    agents in ``env.agents`` order, :func:`partner_agents`)."""
    game = JaxMARLGame(env, agent, name=name, episode_len=episode_len, action_names=action_names)
    if population.num_others != game.spec.num_others:
        raise EnvError(
            f"population {population.name!r} controls {population.num_others} agents but "
            f"{game.spec.name!r} has {game.spec.num_others} other agents "
            f"({', '.join(game.others)}, in that slot order)"
        )
    return ControlledEnv(game, own_observations(population, game.other_dims))
