"""Tag predators: LIAM's four heuristics and its table of 10 joint policies.

The heuristics follow LIAM's ``pretrained_predators.py`` by movement meaning (never the fork's
mirrored action indices). Each reads its own 16-dim predator observation, in which 8:10 and
10:12 are the other two predators and 12:14 the prey (all relative), and never picks no-op:

* ``after_prey``: toward the prey; the x axis only when ``|dx| > |dy|`` (strict, as LIAM's).
* ``after_agent_far``: of the six numbers obs[8:14], the one of largest magnitude decides the
  axis (x for an even index) and the direction (its sign): toward whoever is farthest along one
  axis.
* ``after_agent_close``: toward the nearest of (predator A, predator B, prey) by squared
  distance (first one on ties).
* ``after_pred``: toward one of the two other predators, re-drawn uniformly EVERY step from the
  key it is given (stochastic).

Population. LIAM draws one of 10 teams per episode from a 10 x 3 table over a pool of the four
heuristics, three IA2C and three MADDPG predators (spec 2.7). :data:`LIAM_TABLE` is that table
with its six learned entries named by slot key (``rl_a0..2`` where LIAM has IA2C agents 0-2,
``rl_b0..2`` for its MADDPG agents 0-2). Who fills the learned slots:

* ``partners="default"``: LIAM's own predators (:mod:`transam.partners.liam`, the manifest's
  teams);
* ``partners="heldout"``: our RL predators ``rl_a0..2`` / ``rl_b0..2`` (recipe ``tag_recipe``);
* ``partners="heuristic"`` (:func:`heuristic_population`): a fixed heuristic stand-in per
  slot (:data:`STAND_INS`), chosen so that the 10 teams are 10 different MULTISETS of
  heuristics (predators are interchangeable, so a team is only distinguishable by what it
  contains) and each heuristic appears 7 or 8 times in the 30 slots.

:func:`liam_population` builds the table with ``learned={key: Member}`` swapped in; team names
(``liam0``..``liam9`` = LIAM's task ids) do not change.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from transam.envs.population import Member, PolicyFn, Population, Team
from transam.partners.moves import DOWN, LEFT, NOOP, RIGHT, UP, move_toward

if TYPE_CHECKING:
    from transam.envs.joint import JointView
    from transam.envs.tag import Config

PRED_A, PRED_B, PREY_REL = slice(8, 10), slice(10, 12), slice(12, 14)


def after_prey(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Chase the prey; ties between |dx| and |dy| go to the y axis (LIAM's strict >)."""
    del key
    return move_toward(obs[PREY_REL], strict=True)


def after_agent_far(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Move along the single largest relative coordinate among the others (toward its sign)."""
    del key
    rel = obs[8:14]
    i = jnp.argmax(jnp.abs(rel))
    v = rel[i]
    along_x = i % 2 == 0
    return jnp.where(along_x, jnp.where(v >= 0, RIGHT, LEFT), jnp.where(v >= 0, UP, DOWN)).astype(
        jnp.int32
    )


def after_agent_close(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Move toward the nearest other agent (predator or prey)."""
    del key
    targets = jnp.stack([obs[PRED_A], obs[PRED_B], obs[PREY_REL]])
    nearest = jnp.argmin(jnp.sum(jnp.square(targets), axis=-1))
    return move_toward(targets[nearest])


def after_pred(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Move toward one of the two other predators, drawn afresh every step."""
    pick_b = jax.random.bernoulli(key)
    return move_toward(jnp.where(pick_b, obs[PRED_B], obs[PRED_A]))


def flee_prey(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Prey stand-in for training predators: away from the nearest visible predator, else
    toward the centre (it reads the prey's 14-dim masked observation)."""
    del key
    preds = obs[8:14].reshape(3, 2)
    seen = jnp.all(preds > -4.0, axis=-1)
    d2 = jnp.where(seen, jnp.sum(jnp.square(preds), axis=-1), jnp.inf)
    nearest = preds[jnp.argmin(d2)]
    return move_toward(jnp.where(jnp.any(seen), -nearest, -obs[2:4]))


IN_BOUNDS = 0.7
"""Where :func:`flee_in_bounds` turns back (the boundary penalty starts at 0.99); against
LIAM's predators 0.7 kept the prey inside in 300 of 300 episodes, 0.8 and 0.9 did not."""


def flee_in_bounds(key: jax.Array, obs: jax.Array) -> jax.Array:
    """A hand-written prey (a controlled agent to measure against): :func:`flee_prey`, except
    that when the prey's position two steps ahead at its current velocity, ``pos + 0.2 vel``,
    lies outside ``|x|, |y| <= IN_BOUNDS``, it moves back toward the centre along the axis
    that sticks out most (the game charges -10 per step outside 0.99)."""
    return _back_in_bounds(obs, flee_prey(key, obs))


def stay_in_bounds(key: jax.Array, obs: jax.Array) -> jax.Array:
    """A hand-written prey: no move, except back toward the centre as :func:`flee_in_bounds`
    does (exactly one predator within reach pays +1, two or more cost 1: whether standing still
    beats fleeing is what it measures)."""
    del key
    return _back_in_bounds(obs, jnp.int32(NOOP))


def _back_in_bounds(obs: jax.Array, action: jax.Array) -> jax.Array:
    """``action``, or the move back toward the centre when the prey is about to leave
    ``|x|, |y| <= IN_BOUNDS`` (its position two steps ahead at its current velocity)."""
    ahead = obs[2:4] + 0.2 * obs[0:2]
    out = jnp.any(jnp.abs(ahead) > IN_BOUNDS)
    return jnp.where(out, move_toward(-ahead), action).astype(jnp.int32)


def random_prey(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Uniformly random prey (stand-in for training predators)."""
    del obs
    return jax.random.randint(key, (), 0, 5, dtype=jnp.int32)


PREY_STAND_INS: dict[str, PolicyFn] = {"flee": flee_prey, "random": random_prey}
"""The prey stand-ins the learned predators train against, by recipe name."""

HEURISTICS: tuple[Member, ...] = (
    Member("after_prey", after_prey),
    Member("after_agent_far", after_agent_far),
    Member("after_agent_close", after_agent_close),
    Member("after_pred", after_pred),
)

LEARNED_SLOTS = ("rl_a0", "rl_a1", "rl_a2", "rl_b0", "rl_b1", "rl_b2")
"""Learned-predator keys: rl_a<i> stands where LIAM has IA2C agent i, rl_b<i> MADDPG agent i."""

LIAM_TABLE: tuple[tuple[str, str, str], ...] = (
    ("after_agent_far", "rl_b1", "after_prey"),
    ("after_agent_close", "rl_a1", "rl_b1"),
    ("after_pred", "after_prey", "after_agent_far"),
    ("rl_b1", "rl_b1", "rl_b2"),
    ("rl_a2", "after_prey", "after_agent_far"),
    ("rl_b0", "after_pred", "rl_a0"),
    ("rl_b0", "after_agent_far", "after_agent_close"),
    ("after_pred", "rl_b0", "after_pred"),
    ("rl_b2", "after_pred", "rl_a1"),
    ("after_prey", "rl_a0", "rl_a2"),
)
"""LIAM's 10 teams (task ids 0-9), predator slots 0, 1, 2 (spec 2.7)."""

STAND_INS: dict[str, str] = {
    "rl_a0": "after_agent_close",
    "rl_a1": "after_prey",
    "rl_a2": "after_prey",
    "rl_b0": "after_agent_far",
    "rl_b1": "after_agent_close",
    "rl_b2": "after_pred",
}
"""The heuristic that fills each learned slot until learned predators exist."""


def liam_population(
    learned: Mapping[str, Member] | None = None, name: str = "tag-liam"
) -> Population:
    """LIAM's 10 teams; learned slots from ``learned`` where given, else their stand-ins."""
    learned = dict(learned or {})
    unknown = sorted(set(learned) - set(LEARNED_SLOTS))
    if unknown:
        raise ValueError(f"unknown learned slot(s) {unknown}; valid: {list(LEARNED_SLOTS)}")
    fill = {k: learned[k].name if k in learned else STAND_INS[k] for k in LEARNED_SLOTS}
    members = list(HEURISTICS) + list({m.name: m for m in learned.values()}.values())
    teams = [
        Team(f"liam{i}", tuple(fill.get(s, s) for s in row)) for i, row in enumerate(LIAM_TABLE)
    ]
    return Population(name, members, teams)


def heuristic_pool() -> dict[str, Member]:
    """The heuristic members a manifest's teams may name, by name."""
    return {m.name: m for m in HEURISTICS}


def joint_view(stand_in: str, score: str = "shaped") -> JointView:
    """The training view of all agents in the default game, the prey played by the named
    stand-in (:data:`PREY_STAND_INS`) and scored by ``score`` (see
    :func:`transam.envs.tag.joint_view`)."""
    from transam.envs import tag

    if stand_in not in PREY_STAND_INS:
        valid = ", ".join(PREY_STAND_INS)
        raise ValueError(f"unknown Tag prey stand-in {stand_in!r}; valid choices: {valid}")
    return tag.joint_view(tag.Config(), PREY_STAND_INS[stand_in], score)


def heuristic_population(config: Config | None = None) -> Population:
    """The heuristic Tag population (``partners="heuristic"``): LIAM's table, stand-ins in its
    learned slots."""
    del config  # the heuristics do not depend on the game settings
    return liam_population(name="tag-heuristic")
