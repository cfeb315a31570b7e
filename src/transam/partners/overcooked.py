"""Scripted Overcooked (cramped room) cooks, as pure JAX functions of their own observation.

Every scripted cook reads the same few facts off its flattened 520-vector view (own cell and
orientation, the other cook's cell, what it holds, the pot's state, which counters are free),
picks a *task* (a floor cell to stand on, the direction to face there, and whether to
interact), and walks there along a shortest path that avoids the other cook. The path table is
computed with numpy once, at import, from JaxMARL's layout: first move for every (own cell,
target cell, other cook's cell). When the other cook stands on the only way or on the target,
the cook steps toward it anyway (it moves if the other leaves; otherwise it just turns).

Roles:

* ``onion_carrier``: fetch an onion from the nearer free pile and put it in the pot while the
  pot is not full; while the pot cooks, wait at a pile holding an onion. Never plates.
* ``dish_carrier``: while a soup cooks or is ready, take a plate, wait at the pot, pick the
  soup up and deliver it; otherwise wait at the plate pile empty-handed.
* ``full_cook``: the whole cycle alone (three onions, plate, soup, deliver); puts down on a
  free counter whatever it holds that the pot cannot take.
* ``idle``: always stays. ``random``: uniform random actions.

Scripted cooks take a uniformly random action with probability ``eps`` (default 0.05), which
also breaks the rare symmetric stand-offs (both cooks stepping into the same free cell).

Default population (one partner slot; each team is one member): onion, dish, cook, idle,
random. No team delivers soup on its own except ``cook``; the controlled cook has to supply
the missing half (plates for ``onion``, onions for ``dish``, everything for ``idle``/``random``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from transam.envs.overcooked import (
    CH_COOK_TIME,
    CH_ONION,
    CH_OTHER,
    CH_PLATE,
    CH_SELF,
    CH_SELF_DIR,
    CH_SOUP_ONIONS,
    CH_SOUP_READY,
    CHANNELS,
    DISH,
    DOWN,
    EMPTY,
    GOAL_CELLS,
    HEIGHT,
    INTERACT,
    LEFT,
    ONION,
    ONION_PILE_CELLS,
    PLATE,
    PLATE_PILE_CELLS,
    POT_CELLS,
    RIGHT,
    STAY,
    UP,
    WALL_CELLS,
    WIDTH,
)
from transam.envs.population import Member, PolicyFn, Population, Team

if TYPE_CHECKING:
    from transam.envs.joint import JointView
    from transam.envs.overcooked import Config

NUM_CELLS = HEIGHT * WIDTH
MOVE_VEC = {UP: (0, -1), DOWN: (0, 1), RIGHT: (1, 0), LEFT: (-1, 0)}  # action -> (dx, dy)
PREFERENCE = (DOWN, RIGHT, LEFT, UP)  # tie-break among shortest moves (keeps row 2 a dish lane)
FAR = 1000


def _neighbours(cell: int) -> list[tuple[int, int]]:
    """(move action, neighbouring cell) pairs inside the grid."""
    x, y = cell % WIDTH, cell // WIDTH
    out = []
    for a in PREFERENCE:
        dx, dy = MOVE_VEC[a]
        if 0 <= x + dx < WIDTH and 0 <= y + dy < HEIGHT:
            out.append((a, (y + dy) * WIDTH + x + dx))
    return out


FLOOR = np.ones(NUM_CELLS, bool)
FLOOR[list(WALL_CELLS)] = False


def _distances(target: int, blocked: int | None) -> np.ndarray:
    """BFS steps from every floor cell to ``target`` avoiding ``blocked`` (FAR if unreachable)."""
    dist = np.full(NUM_CELLS, FAR, np.int32)
    if not FLOOR[target] or target == blocked:
        return dist
    dist[target], frontier = 0, [target]
    while frontier:
        nxt = []
        for c in frontier:
            for _, n in _neighbours(c):
                if FLOOR[n] and n != blocked and dist[n] == FAR:
                    dist[n] = dist[c] + 1
                    nxt.append(n)
        frontier = nxt
    return dist


def _first_move(pos: int, dist: np.ndarray) -> int:
    """The preferred move along a shortest path (STAY at the target or when unreachable)."""
    if dist[pos] in (0, FAR):
        return STAY
    for a, n in _neighbours(pos):
        if dist[n] == dist[pos] - 1:
            return a
    return STAY


def _build_tables() -> tuple[np.ndarray, np.ndarray]:
    """DIST[pos, target] and NEXT[pos, target, other cook's cell] for the fixed layout."""
    dist = np.stack([_distances(t, None) for t in range(NUM_CELLS)], axis=1)
    nxt = np.full((NUM_CELLS, NUM_CELLS, NUM_CELLS), STAY, np.int32)
    for t in range(NUM_CELLS):
        for b in range(NUM_CELLS):
            around = _distances(t, b)
            for p in range(NUM_CELLS):
                ok = around[p] != FAR
                nxt[p, t, b] = _first_move(p, around if ok else dist[:, t])
    return dist, nxt


def _spot(obj: int) -> tuple[int, int]:
    """(floor cell, facing action) from which a cook reaches object cell ``obj``."""
    spots = [(n, a) for a, n in _neighbours(obj) if FLOOR[n]]
    if len(spots) != 1:
        raise ValueError(f"cell {obj} has {len(spots)} floor neighbours; expected one")
    cell, step_away = spots[0]
    facing = {UP: DOWN, DOWN: UP, LEFT: RIGHT, RIGHT: LEFT}[step_away]
    return cell, facing


DIST_NP, NEXT_NP = _build_tables()
DIST, NEXT = jnp.asarray(DIST_NP), jnp.asarray(NEXT_NP)

# Tasks: (floor cell, facing action, interact there?). Drop sites are reachable empty counters.
POT_SPOT = _spot(POT_CELLS[0])
PLATE_SPOT = _spot(PLATE_PILE_CELLS[0])
GOAL_SPOT = _spot(GOAL_CELLS[0])
PILE_SPOTS = [_spot(c) for c in ONION_PILE_CELLS]
_special = set(POT_CELLS + PLATE_PILE_CELLS + GOAL_CELLS + ONION_PILE_CELLS)
COUNTERS = [
    c for c in WALL_CELLS if c not in _special and sum(FLOOR[n] for _, n in _neighbours(c)) == 1
]
DROP_SPOTS = [_spot(c) for c in COUNTERS]

T_POT, T_PLATE, T_PLATE_WAIT, T_GOAL = 0, 1, 2, 3
T_PILE = 4  # T_PILE + i for onion pile i
T_DROP = T_PILE + len(PILE_SPOTS)  # T_DROP + k for counter k
TASKS = jnp.asarray(
    [(*POT_SPOT, 1), (*PLATE_SPOT, 1), (*PLATE_SPOT, 0), (*GOAL_SPOT, 1)]
    + [(*s, 1) for s in PILE_SPOTS]
    + [(*s, 1) for s in DROP_SPOTS],
    dtype=jnp.int32,
)


class View(NamedTuple):
    """What a scripted cook reads off its own observation."""

    pos: jax.Array  # own flat cell index
    facing: jax.Array  # own orientation as a move action (0 up, 1 down, 2 right, 3 left)
    other: jax.Array  # the other cook's cell
    held: jax.Array  # JaxMARL object code in hand: EMPTY, ONION, PLATE or DISH
    pot_full: jax.Array  # the pot holds a cooking or ready soup
    pot_ready: jax.Array
    counter_free: jax.Array  # [len(COUNTERS)] nothing lies on that counter


def read_view(obs: jax.Array) -> View:
    """Decode a flattened (4, 5, 26) JaxMARL observation (the agent's own layers first)."""
    grid = jnp.asarray(obs).reshape(NUM_CELLS, CHANNELS)
    pos = jnp.argmax(grid[:, CH_SELF]).astype(jnp.int32)
    here = grid[pos]
    held = jnp.select(
        [here[CH_ONION] > 0, here[CH_PLATE] > 0, here[CH_SOUP_READY] > 0],
        [ONION, PLATE, DISH],
        EMPTY,
    )
    pot = grid[POT_CELLS[0]]
    items = grid[jnp.asarray(COUNTERS)][:, jnp.asarray([CH_SOUP_READY, CH_PLATE, CH_ONION])]
    return View(
        pos=pos,
        facing=jnp.argmax(here[CH_SELF_DIR : CH_SELF_DIR + 4]).astype(jnp.int32),
        other=jnp.argmax(grid[:, CH_OTHER]).astype(jnp.int32),
        held=held.astype(jnp.int32),
        pot_full=(pot[CH_SOUP_ONIONS] > 0) | (pot[CH_COOK_TIME] > 0) | (pot[CH_SOUP_READY] > 0),
        pot_ready=pot[CH_SOUP_READY] > 0,
        counter_free=jnp.sum(items, axis=1) == 0,
    )


def _nearest(view: View, spots: list[tuple[int, int]], penalty: jax.Array) -> jax.Array:
    """Index of the spot nearest to the cook, avoiding the other cook's cell and ``penalty``."""
    cells = jnp.asarray([c for c, _ in spots])
    cost = DIST[view.pos, cells] + FAR * (cells == view.other) + penalty
    return jnp.argmin(cost).astype(jnp.int32)


def pile_task(view: View) -> jax.Array:
    return T_PILE + _nearest(view, PILE_SPOTS, jnp.zeros(len(PILE_SPOTS), jnp.int32))


def drop_task(view: View) -> jax.Array:
    return T_DROP + _nearest(view, DROP_SPOTS, 4 * FAR * (~view.counter_free))


def do_task(view: View, task: jax.Array) -> jax.Array:
    """Walk to the task's cell, turn to face its object, then interact (or wait)."""
    cell, face, use = TASKS[task, 0], TASKS[task, 1], TASKS[task, 2]
    there = view.pos == cell
    act_there = jnp.where(view.facing == face, jnp.where(use > 0, INTERACT, STAY), face)
    return jnp.where(there, act_there, NEXT[view.pos, cell, view.other]).astype(jnp.int32)


def onion_carrier_task(view: View) -> jax.Array:
    pot_open = ~view.pot_full
    return jnp.select(
        [(view.held == ONION) & pot_open, (view.held == EMPTY) | (view.held == ONION)],
        [T_POT, pile_task(view)],
        drop_task(view),
    )


def dish_carrier_task(view: View) -> jax.Array:
    wants_plate = view.pot_full
    return jnp.select(
        [
            view.held == DISH,
            (view.held == PLATE) & wants_plate,
            (view.held == EMPTY) & wants_plate,
            view.held == ONION,
        ],
        [T_GOAL, T_POT, T_PLATE, jnp.where(view.pot_full, drop_task(view), T_POT)],
        T_PLATE_WAIT,
    )


def full_cook_task(view: View) -> jax.Array:
    pot_open = ~view.pot_full
    return jnp.select(
        [
            view.held == DISH,
            (view.held == PLATE) & view.pot_full,
            (view.held == ONION) & pot_open,
            (view.held == EMPTY) & pot_open,
            view.held == EMPTY,
        ],
        [T_GOAL, T_POT, T_POT, pile_task(view), T_PLATE],
        drop_task(view),
    )


def scripted(task_fn: Callable[[View], jax.Array], eps: float = 0.05) -> PolicyFn:
    """A policy (key, obs) -> action that follows ``task_fn`` and acts randomly w.p. ``eps``."""

    def act(key: jax.Array, obs: jax.Array) -> jax.Array:
        view = read_view(obs)
        action = do_task(view, task_fn(view))
        if eps <= 0:
            return action
        k_explore, k_action = jax.random.split(key)
        explore = jax.random.uniform(k_explore) < eps
        noise = jax.random.randint(k_action, (), 0, 6, dtype=jnp.int32)
        return jnp.where(explore, noise, action)

    return act


def idle(key: jax.Array, obs: jax.Array) -> jax.Array:
    return jnp.asarray(STAY, jnp.int32)


def uniform_random(key: jax.Array, obs: jax.Array) -> jax.Array:
    return jax.random.randint(key, (), 0, 6, dtype=jnp.int32)


def heuristic_members(eps: float = 0.05) -> list[Member]:
    """All scripted members (``eps``: their random-action probability)."""
    return [
        Member("onion_carrier", scripted(onion_carrier_task, eps)),
        Member("dish_carrier", scripted(dish_carrier_task, eps)),
        Member("full_cook", scripted(full_cook_task, eps)),
        Member("idle", idle),
        Member("random", uniform_random),
    ]


def heuristic_pool() -> dict[str, Member]:
    """The heuristic members a manifest's teams may name, by name."""
    return {m.name: m for m in heuristic_members()}


def joint_view(stand_in: str = "self-play", score: str = "shaped") -> JointView:
    """The training view of both agents in the default game (both learn: no stand-in, one
    score)."""
    del stand_in, score
    from transam.envs import overcooked as game

    return game.OvercookedGame(game.Config()).joint_view()


def heuristic_population(config: Config | None = None) -> Population:
    """The heuristic population (``partners="heuristic"``): one team per scripted member."""
    members = heuristic_members()
    teams = [
        Team("onion", ("onion_carrier",)),
        Team("dish", ("dish_carrier",)),
        Team("cook", ("full_cook",)),
        Team("idle", ("idle",)),
        Team("random", ("random",)),
    ]
    return Population("overcooked-heuristic", members, teams)
