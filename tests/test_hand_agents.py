"""Hand-written controlled agents (docs/results/scripts/hand_agents.py): Tag's prey rules."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from transam.envs.tag import HIDDEN
from transam.partners.moves import DOWN, LEFT, NOOP, RIGHT, UP
from transam.partners.tag import flee_in_bounds, stay_in_bounds

KEY = jax.random.key(0)


def prey_obs(pos: tuple[float, float], vel=(0.0, 0.0), preds=()) -> jax.Array:
    """A 14-float prey observation: vel, pos, two landmarks (unseen), three predators (rel.;
    unseen unless given)."""
    rel = [HIDDEN] * 6
    for i, p in enumerate(preds):
        rel[2 * i : 2 * i + 2] = p
    return jnp.asarray([*vel, *pos, *[HIDDEN] * 4, *rel], jnp.float32)


def test_flee_in_bounds_flees_inside_and_turns_back_near_the_boundary() -> None:
    # Inside: away from the nearest visible predator (here on its right: go left).
    assert flee_in_bounds(KEY, prey_obs((0.0, 0.0), preds=[(0.2, 0.05)])) == LEFT
    assert flee_in_bounds(KEY, prey_obs((0.0, 0.0), preds=[(0.0, -0.3)])) == UP
    # Near the +x edge, a predator on its left: back toward the centre, not on outward.
    assert flee_in_bounds(KEY, prey_obs((0.75, 0.0), preds=[(-0.2, 0.0)])) == LEFT
    # Inside now but moving out fast (two steps ahead beyond 0.7 on -y): back up.
    assert flee_in_bounds(KEY, prey_obs((0.0, -0.6), vel=(0.0, -1.0))) == UP
    # Nothing in view, inside: toward the centre, as flee_prey.
    assert flee_in_bounds(KEY, prey_obs((-0.3, 0.1))) == RIGHT


def test_stay_in_bounds_stands_still_inside() -> None:
    assert stay_in_bounds(KEY, prey_obs((0.1, 0.2), preds=[(0.1, 0.0)])) == NOOP
    assert stay_in_bounds(KEY, prey_obs((0.2, 0.8))) == DOWN
    assert stay_in_bounds(KEY, prey_obs((-0.9, 0.1))) == RIGHT
