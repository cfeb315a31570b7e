"""Shared movement primitives for heuristic partners in the particle (MPE) games.

MPE discrete actions, as in PettingZoo/mpe2 and JaxMARL: 0 no-op, 1 -x, 2 +x, 3 -y, 4 +y.
Heuristics are defined by movement meaning, so the LIAM fork's mirrored indices never leak in.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

NOOP, LEFT, RIGHT, DOWN, UP = 0, 1, 2, 3, 4


def move_toward(delta: jax.Array, strict: bool = False) -> jax.Array:
    """The one-axis move that reduces the larger component of ``delta`` = target - self.

    Ties go to the x axis (``|dx| >= |dy|``) unless ``strict`` (``|dx| > |dy|``), as LIAM's
    heuristics do; a zero component moves in the + direction, as theirs do.
    """
    dx, dy = delta[0], delta[1]
    along_x = jnp.where(strict, jnp.abs(dx) > jnp.abs(dy), jnp.abs(dx) >= jnp.abs(dy))
    x_move = jnp.where(dx >= 0, RIGHT, LEFT)
    y_move = jnp.where(dy >= 0, UP, DOWN)
    return jnp.where(along_x, x_move, y_move).astype(jnp.int32)
