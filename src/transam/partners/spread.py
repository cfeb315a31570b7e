"""Heuristic Spread partners: landmark seekers, and the heuristic population built from them.

Each heuristic reads the landmark offsets from its own observation (slots 4:10, landmark k at
4+2k) and takes the one-axis step of :func:`~transam.partners.moves.move_toward` toward its
target, led by its own velocity: it steers at ``offset - LEAD * velocity`` (LEAD = 0.2 s), the
point it is heading for rather than where it is. Plain bang-bang steering (LEAD = 0) overshoots
and circles its landmark at about 0.27 on average; with the lead it settles within about 0.07
(three agents splitting the landmarks this way score about -46 per episode on the default
reward, close to the paper's -49). They never choose no-op. Deterministic: the key is unused.

* ``first`` / ``second`` / ``third``: go to landmark 0 / 1 / 2.
* ``closest``: go to the landmark nearest to this agent (re-chosen every step).
* ``farthest``: go to the landmark farthest from this agent (re-chosen every step, so it
  wanders between landmarks as it approaches one).

Default population (13 teams, slot 0 = agent 0, slot 1 = agent 1), chosen so that the best
response of the controlled agent differs across teams:

* split teams ``first+second``, ``second+third``, ``third+first``: the partners cover two
  distinct landmarks; the controlled agent should take the remaining one.
* crowd teams ``first+first``, ``second+second``, ``third+third``: both partners pile onto one
  landmark (and collide); two landmarks are left, the controlled agent covers the nearer one.
* adaptive teams ``closest+closest``, ``farthest+farthest``, ``closest+farthest``: targets
  depend on where the partners spawned.
* mixed teams ``first+closest``, ``closest+second``, ``third+farthest``, ``farthest+first``: one
  fixed and one adaptive partner, in both slot orders.

The TransAM authors' five heuristics (their ``pretrained_spread_opponents.py``, used by the
default learned population and the imported authors' one): ``after_first_landmark``,
``after_second_landmark``, ``after_third_landmark``, ``after_farthest_landmark``,
``after_closest_landmark``. Plain one-axis bang-bang steering toward the landmark offset (no
lead): x if ``|dx| >= |dy|``, a zero component moves +, never the no-op; farthest/closest by
squared distance, the lowest index on ties. They overshoot and circle their landmark, as theirs.

:func:`landmark_agent` is a controlled-agent rule for scale, not a partner: head for the
landmark whose nearest partner is farthest away, steering as the authors' heuristics do.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from transam.envs.joint import JointView, play
from transam.envs.population import Member, PolicyFn, Population, Team
from transam.envs.spread import CONTROLLED, LANDMARKS, NUM_LANDMARKS, OTHERS, VEL, Config
from transam.partners.moves import move_toward

LEAD = 0.2  # seconds of own velocity subtracted from the target offset (damps overshoot)


def landmark_offsets(obs: jax.Array) -> jax.Array:
    """[3, 2] landmark positions relative to the observing agent."""
    return obs[LANDMARKS].reshape(NUM_LANDMARKS, 2)


def steer(obs: jax.Array, offset: jax.Array, lead: float) -> jax.Array:
    """The move toward ``offset``, corrected for the distance the agent will coast."""
    return move_toward(offset - lead * obs[VEL])


def go_to(k: int, lead: float = LEAD) -> PolicyFn:
    """Policy heading for landmark ``k``."""

    def act(key: jax.Array, obs: jax.Array) -> jax.Array:
        del key
        return steer(obs, landmark_offsets(obs)[k], lead)

    return act


def go_to_ranked(farthest: bool, lead: float = LEAD) -> PolicyFn:
    """Policy heading for the nearest (or farthest) landmark from this agent."""

    def act(key: jax.Array, obs: jax.Array) -> jax.Array:
        del key
        offsets = landmark_offsets(obs)
        dist2 = jnp.sum(offsets**2, axis=-1)
        k = jnp.argmax(dist2) if farthest else jnp.argmin(dist2)
        return steer(obs, offsets[k], lead)

    return act


HEURISTICS: dict[str, PolicyFn] = {
    "first": go_to(0),
    "second": go_to(1),
    "third": go_to(2),
    "closest": go_to_ranked(farthest=False),
    "farthest": go_to_ranked(farthest=True),
}
"""Our led landmark seekers (the ``partners="heuristic"`` population)."""

AUTHORS_HEURISTICS: dict[str, PolicyFn] = {
    "after_first_landmark": go_to(0, lead=0.0),
    "after_second_landmark": go_to(1, lead=0.0),
    "after_third_landmark": go_to(2, lead=0.0),
    "after_farthest_landmark": go_to_ranked(farthest=True, lead=0.0),
    "after_closest_landmark": go_to_ranked(farthest=False, lead=0.0),
}
"""The authors' five rules exactly (module doc), by their names."""


def landmark_agent(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Controlled agent: head for the landmark whose nearest partner is farthest away (the
    landmark least likely to be covered), with the authors' one-axis steering."""
    del key
    offsets = landmark_offsets(obs)  # [3, 2] relative to self
    partners = obs[OTHERS].reshape(2, 2)  # [2, 2] relative to self
    gap = jnp.linalg.norm(offsets[:, None, :] - partners[None, :, :], axis=-1)  # [L, P]
    return move_toward(offsets[jnp.argmax(jnp.min(gap, axis=1))])


DEFAULT_TEAMS: tuple[tuple[str, str], ...] = (
    ("first", "second"),
    ("second", "third"),
    ("third", "first"),
    ("first", "first"),
    ("second", "second"),
    ("third", "third"),
    ("closest", "closest"),
    ("farthest", "farthest"),
    ("closest", "farthest"),
    ("first", "closest"),
    ("closest", "second"),
    ("third", "farthest"),
    ("farthest", "first"),
)


def heuristic_members() -> list[Member]:
    """Every Spread heuristic as a population member: our five led landmark seekers and the
    authors' five rules (a population's teams pick among them by name)."""
    return [Member(name, fn) for name, fn in {**HEURISTICS, **AUTHORS_HEURISTICS}.items()]


def heuristic_pool() -> dict[str, Member]:
    """The heuristic members a manifest's teams may name, by name."""
    return {m.name: m for m in heuristic_members()}


def joint_view(stand_in: str = "self-play", score: str = "shaped") -> JointView:
    """The training view of all agents in the default game (every agent learns: no stand-in,
    one score)."""
    del stand_in, score
    from transam.envs.spread import SpreadGame

    return SpreadGame(Config()).joint_view()


def heuristic_population(config: Config | None = None) -> Population:
    """The heuristic Spread population (``partners="heuristic"``): the module doc's 13 teams."""
    del config  # the heuristics read observations only; no option changes them
    teams = [Team(f"{a}+{b}", (a, b)) for a, b in DEFAULT_TEAMS]
    members = [Member(name, fn) for name, fn in HEURISTICS.items()]
    return Population("spread-heuristic", members, teams)


def member_scores(
    view: JointView, members: dict[str, tuple[PolicyFn, int]], episodes: int = 128, seed: int = 1
) -> tuple[dict[str, dict[str, Any]], dict[str, float]]:
    """How competent each learned member is, played as it will act (one jitted program).

    ``members``: name -> (act function, the partner slot it plays in the teams, 0 or 1).
    Per member:

    * ``copies_return``: three copies of the member (its own reward, mean over the agents);
    * ``random_controlled_return``: the return of a uniformly random controlled agent when the
      partners are the member (in its slot) and X in the other, for X = the member itself
      (``self``), each of the authors' heuristics, and a random agent;
    * ``action_freq`` (no-op, -x, +x, -y, +y) and ``reversal_rate`` (share of steps that undo
      the previous move, e.g. -x after +x) of the member among its copies: a greedy actor that
      stands still has a large no-op share, one that oscillates a large reversal rate.

    And ``baseline``: the random controlled agent's return with random partners (``random``)
    and with each heuristic beside a random partner, the numbers the member's row beats.
    """
    names = [*members, *AUTHORS_HEURISTICS, "random"]
    pols = [*(f for f, _ in members.values()), *AUTHORS_HEURISTICS.values(), _random_act]
    rnd = len(names) - 1
    combos: list[tuple[int, int, int]] = []
    index: dict[tuple[str, str], int] = {}

    def add(key: tuple[str, str], slots: tuple[int, int, int]) -> None:
        index[key] = len(combos)
        combos.append(slots)

    for i, (name, (_, slot_of)) in enumerate(members.items()):
        add((name, "copies"), (i, i, i))
        for other in ("self", *AUTHORS_HEURISTICS, "random"):
            j = i if other == "self" else names.index(other)
            pair = (i, j) if slot_of == 0 else (j, i)
            add((name, other), (*pair, rnd))
    add(("baseline", "random"), (rnd, rnd, rnd))
    for h in AUTHORS_HEURISTICS:
        add(("baseline", h), (names.index(h), rnd, rnd))

    def score(slots: jax.Array) -> tuple[jax.Array, jax.Array]:
        def slot(j: int) -> PolicyFn:
            return lambda k, o: jax.lax.switch(slots[j], pols, k, o)

        mean, _, acts = play(view, [slot(0), slot(1), slot(2)], jax.random.PRNGKey(seed), episodes)
        return mean, acts[..., 0]  # [A], [E, T] (slot 0's actions)

    means, acts = jax.jit(jax.vmap(score))(jnp.asarray(combos, jnp.int32))
    means, acts = np.asarray(means), np.asarray(acts)
    out: dict[str, dict[str, Any]] = {}
    for name in members:
        c = index[(name, "copies")]
        a = acts[c]
        prev, cur = a[:, :-1], a[:, 1:]
        undo = (prev > 0) & (cur > 0) & (cur != prev) & ((cur - 1) // 2 == (prev - 1) // 2)
        out[name] = {
            "copies_return": round(float(means[c].mean()), 4),
            "random_controlled_return": {
                other: round(float(means[index[(name, other)]][CONTROLLED]), 4)
                for other in ("self", *AUTHORS_HEURISTICS, "random")
            },
            "action_freq": [round(float(np.mean(a == k)), 3) for k in range(5)],
            "reversal_rate": round(float(undo.mean()), 3),
        }
    baseline = {
        other: round(float(means[index[("baseline", other)]][CONTROLLED]), 4)
        for other in ("random", *AUTHORS_HEURISTICS)
    }
    return out, baseline


def agent_ranks(
    view: JointView, policies: list[PolicyFn], episodes: int = 128, seed: int = 1
) -> list[float]:
    """Per agent of a trained run: a uniformly random controlled agent's return when two copies
    of that agent are its partners (how useful the agent is as a partner; a lazy agent that
    runs away scores below random partners)."""

    def score(i: jax.Array) -> jax.Array:
        agent = lambda k, o: jax.lax.switch(i, policies, k, o)
        return play(view, [agent, agent, _random_act], jax.random.PRNGKey(seed), episodes)[0]

    found = jax.jit(jax.vmap(score))(jnp.arange(len(policies)))
    return [round(float(x), 4) for x in np.asarray(found)[:, CONTROLLED]]


def _random_act(key: jax.Array, obs: jax.Array) -> jax.Array:
    del obs
    return jax.random.randint(key, (), 0, 5, dtype=jnp.int32)
