"""Heuristic LBF partners (lbforaging's H1-H4 and two simple variants) and their population.

Every policy is a pure function of (key, the agent's own vector observation, layout in
:mod:`transam.envs.lbf`). H1-H4 follow lbforaging's ``heuristic_agent.py``:

* pick a target food among the visible ones: the one with the smallest squared Euclidean
  distance from a start point, ties to the first in row-major order (the observation's slot
  order, as lbforaging's ``np.nonzero`` scan);
  - ``H1``: start = self, any food;
  - ``H2``: start = the rounded (half to even, as ``np.rint``) centroid of the visible players,
    self included;
  - ``H3``: start = self, foods with level <= own level;
  - ``H4``: start = the centroid, foods with level <= the summed level of the visible players;
* LOAD when the target is at Manhattan distance 1 (whether or not the load can succeed);
* otherwise the first valid move of north (target above), south (below), east (right), west
  (left), in that order;
* with no target, or no such move, a uniformly random valid action drawn from the key.

Valid actions are read from the observation as lbforaging defines them: none always; a move
unless it leaves the grid or enters a visible food; load iff a visible food is 4-adjacent. With
the default full view this is exact. With a limited sight the south/east grid edges cannot be
seen from the observation, so the heuristics treat moves across them as valid (the environment
turns such moves into none).

Variants: ``random`` (uniform over the valid actions, lbforaging's random agent) and ``lazy``
(never moves; loads when a food happens to be adjacent, else none).

Default population: 6 teams of one partner slot, one per member, named after it
(H1, H2, H3, H4, random, lazy). RL partners (MAPPO/IPPO over seeds and discounts) come later.

Note: with 2 agents and the default full view, H4 acts exactly as H2: a food's level never
exceeds the sum of both agents' levels (lbforaging's food-level rule), so H4's cap never binds.
The two differ only with a limited sight (the other agent unseen) or constructed states.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from transam.envs.joint import JointView
from transam.envs.lbf import EAST, LOAD, NONE, NORTH, SOUTH, WEST, Config, split_obs
from transam.envs.population import Member, PolicyFn, Population, Team


def valid_from_obs(obs: jax.Array, config: Config) -> jax.Array:
    """[6] bool: the valid actions of the observing agent, as far as its observation shows."""
    foods, players = split_obs(obs, config.num_foods)
    here = players[0, :2]
    alive = foods[:, 2] > 0
    edge = config.grid_size - 1 if config.full_view else jnp.inf
    moves = jnp.array([[0, 0], [-1, 0], [1, 0], [0, -1], [0, 1]], jnp.float32)
    target = here + moves
    in_grid = jnp.all(target >= 0, axis=-1) & jnp.all(target <= edge, axis=-1)
    on_food = jnp.any(jnp.all(target[:, None] == foods[None, :, :2], axis=-1) & alive, axis=-1)
    adjacent = jnp.any((jnp.sum(jnp.abs(foods[:, :2] - here), axis=-1) == 1) & alive)
    return jnp.concatenate([(in_grid & ~on_food).at[NONE].set(True), adjacent[None]])


def random_valid(key: jax.Array, valid: jax.Array) -> jax.Array:
    """A uniformly random action among ``valid`` (none is always valid): the k-th valid one.

    k comes from one 32-bit draw modulo the count (bias < 1e-9; cheaper to compile than
    ``categorical``, and there is one such draw in every heuristic member).
    """
    upto = jnp.cumsum(valid)
    k = jax.random.bits(key, (), jnp.uint32) % upto[-1].astype(jnp.uint32)
    return jnp.argmax(upto > k.astype(jnp.int32)).astype(jnp.int32)


def heuristic(centroid: bool, level_cap: str | None, config: Config) -> PolicyFn:
    """lbforaging's H1-H4: target start point (self or centroid) and level cap
    (None, ``"own"`` or ``"visible_sum"``)."""

    def act(key: jax.Array, obs: jax.Array) -> jax.Array:
        foods, players = split_obs(obs, config.num_foods)
        valid = valid_from_obs(obs, config)
        here = players[0, :2]
        seen = players[:, 2] > 0
        if centroid:
            mean = jnp.sum(jnp.where(seen[:, None], players[:, :2], 0.0), 0) / jnp.sum(seen)
            start = jnp.round(mean)
        else:
            start = here
        ok = foods[:, 2] > 0
        if level_cap == "own":
            ok &= foods[:, 2] <= players[0, 2]
        elif level_cap == "visible_sum":
            ok &= foods[:, 2] <= jnp.sum(jnp.where(seen, players[:, 2], 0.0))
        dist2 = jnp.sum((foods[:, :2] - start) ** 2, axis=-1)
        target = foods[jnp.argmin(jnp.where(ok, dist2, jnp.inf)), :2]
        dr, dc = target - here
        wants = jnp.array([dr < 0, dr > 0, dc > 0, dc < 0])
        order = jnp.array([NORTH, SOUTH, EAST, WEST])
        step_ok = wants & valid[order]
        move = jnp.where(jnp.any(step_ok), order[jnp.argmax(step_ok)], -1)
        fallback = random_valid(key, valid)
        chosen = jnp.where(jnp.abs(dr) + jnp.abs(dc) == 1, LOAD, move)
        chosen = jnp.where(jnp.any(ok) & (chosen >= 0), chosen, fallback)
        return chosen.astype(jnp.int32)

    return act


def random_policy(config: Config) -> PolicyFn:
    """Uniform over the valid actions."""

    def act(key: jax.Array, obs: jax.Array) -> jax.Array:
        return random_valid(key, valid_from_obs(obs, config))

    return act


def lazy_policy(config: Config) -> PolicyFn:
    """Stay put; load whenever a food is adjacent."""

    def act(key: jax.Array, obs: jax.Array) -> jax.Array:
        del key
        return jnp.where(valid_from_obs(obs, config)[LOAD], LOAD, NONE).astype(jnp.int32)

    return act


def heuristic_members(config: Config) -> tuple[Member, ...]:
    """H1-H4, random and lazy, in that order."""
    return (
        Member("H1", heuristic(False, None, config)),
        Member("H2", heuristic(True, None, config)),
        Member("H3", heuristic(False, "own", config)),
        Member("H4", heuristic(True, "visible_sum", config)),
        Member("random", random_policy(config)),
        Member("lazy", lazy_policy(config)),
    )


def heuristic_pool() -> dict[str, Member]:
    """The heuristic members a manifest's teams may name, by name (default game)."""
    return {m.name: m for m in heuristic_members(Config())}


def joint_view(stand_in: str = "self-play", score: str = "shaped") -> JointView:
    """The training view of all agents in the default game (every agent learns: no stand-in,
    one score)."""
    del stand_in, score
    from transam.envs.lbf import joint_view as lbf_view

    return lbf_view(Config())


def heuristic_population(config: Config) -> Population:
    """The heuristic LBF population (``partners="heuristic"``): one team per heuristic member."""
    members = heuristic_members(config)
    teams = [Team(m.name, (m.name,)) for m in members]
    return Population("lbf-heuristic", members, teams)
