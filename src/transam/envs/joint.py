"""Joint (all-learners) views of the games, for training and scoring partner policies.

A partner trainer needs every learning agent's observation and its *own* reward, which the
controlled-agent :class:`~transam.envs.core.Game` interface deliberately hides. A
:class:`JointView` exposes them as pure functions. The controlled agent's slot is either a
learner itself (self-play stand-in, cooperative games) or played inside ``step`` by a fixed
stand-in policy (Tag's prey). Each game module builds its own view (``joint_view``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp

from transam.envs.population import PolicyFn

StepFn = Callable[
    [jax.Array, Any, jax.Array, jax.Array], tuple[Any, jax.Array, jax.Array, jax.Array]
]


@dataclass(frozen=True)
class JointView:
    """All learners of one game at once (every function pure and jit/vmap-able).

    * ``reset(key) -> state``; ``observe(state) -> [num_agents, obs_dim]`` float32.
    * ``step(key, state, actions [num_agents], weights [num_agents, 3])`` ->
      ``(state, train_reward [num_agents], score [num_agents], terminal)``. ``weights`` are the
      recipe's per-agent shaping weights (only Overcooked reads them); ``score`` is the
      unshaped objective reported in manifests and comparisons.
    * ``partner_slots``: learner index of each partner slot of the controlled-agent game, in
      slot order; ``controlled``: the learner index standing in for the controlled agent, or
      None when a fixed stand-in plays it inside ``step``.
    """

    name: str
    num_agents: int
    obs_dim: int
    num_actions: int
    episode_len: int
    reset: Callable[[jax.Array], Any]
    observe: Callable[[Any], jax.Array]
    step: StepFn
    partner_slots: tuple[int, ...]
    controlled: int | None


def no_shaping(num_agents: int) -> jax.Array:
    """All-zero shaping weights [num_agents, 3]."""
    return jnp.zeros((num_agents, 3), jnp.float32)


def play(
    view: JointView,
    policies: Sequence[PolicyFn],
    key: jax.Array,
    num_episodes: int,
    weights: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Run ``num_episodes`` full episodes with one policy per learner.

    Returns (mean score per agent [num_agents], obs [E, T, A, D], actions [E, T, A]); an
    episode that terminates early keeps stepping a frozen copy (its later scores are zeroed).
    """
    if len(policies) != view.num_agents:
        raise ValueError(f"{view.name}: need {view.num_agents} policies, got {len(policies)}")
    w = no_shaping(view.num_agents) if weights is None else weights

    def episode(k: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        k0, k1 = jax.random.split(k)
        state = view.reset(k0)

        def body(
            carry: tuple[Any, jax.Array], k: jax.Array
        ) -> tuple[tuple[Any, jax.Array], tuple[jax.Array, jax.Array, jax.Array]]:
            state, over = carry
            obs = view.observe(state)
            ka, ks = jax.random.split(k)
            keys = jax.random.split(ka, view.num_agents)
            acts = jnp.stack(
                [jnp.asarray(p(keys[i], obs[i]), jnp.int32) for i, p in enumerate(policies)]
            )
            nxt, _, score, term = view.step(ks, state, acts, w)
            score = jnp.where(over, 0.0, score)
            nxt = jax.tree.map(lambda a, b: jnp.where(over, a, b), state, nxt)
            return (nxt, over | term), (score, obs, acts)

        keys = jax.random.split(k1, view.episode_len)
        _, (scores, obs, acts) = jax.lax.scan(body, (state, jnp.array(False)), keys)
        return jnp.sum(scores, axis=0), obs, acts

    scores, obs, acts = jax.vmap(episode)(jax.random.split(key, num_episodes))
    return jnp.mean(scores, axis=0), obs, acts
