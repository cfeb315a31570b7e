"""Partner populations: M fixed joint policies over the other agents' slots.

A *member* is one agent's policy, a pure function ``(key, obs) -> action`` of that agent's own
observation. Heuristic members are plain JAX functions; a learned member is the same kind of
function closing over its (fixed) network parameters, so heuristic and neural members mix
freely. A *team* (joint policy m) assigns one member to each slot of the other agents.

At each step, slot j runs just the members that ever appear in slot j, so a population pays
only for the policies it can actually use there. Every such member acts and the team's own
action is picked (not ``lax.switch``): environments are vmapped with a different team per copy,
and switch's batching rule then runs every branch anyway, after broadcasting each branch's
closed-over constants (a learned member's weights) to the batch: for Overcooked's 8 learned
members and 1024 copies, 1.07 s per step instead of 12.6 ms (2 CPU cores). The chosen member
gets the same key, so the actions are those a switch would give.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

PolicyFn = Callable[[jax.Array, jax.Array], jax.Array]
"""One agent's policy: (PRNG key, its own observation) -> int32 action."""
ProbsFn = Callable[[jax.Array], jax.Array]
"""One agent's action probabilities [num_actions] from its own observation."""


@dataclass(frozen=True)
class Member:
    """One agent policy usable in any slot of a team."""

    name: str
    act: PolicyFn
    kind: str = "heuristic"  # "heuristic" or a learned recipe name
    probs: ProbsFn | None = None
    """The distribution ``act`` draws from, where known (learned members); None: not declared
    (heuristics), so a measurement that needs it samples ``act`` instead."""


@dataclass(frozen=True)
class Team:
    """A joint policy: one member name per other-agent slot."""

    name: str
    slots: tuple[str, ...]


class Population:
    """M joint policies (teams) over a shared pool of members."""

    def __init__(self, name: str, members: Sequence[Member], teams: Sequence[Team]) -> None:
        if not teams:
            raise ValueError(f"population {name!r} has no teams")
        index = {m.name: i for i, m in enumerate(members)}
        if len(index) != len(members):
            raise ValueError(f"population {name!r} has duplicate member names")
        widths = {len(t.slots) for t in teams}
        if len(widths) != 1:
            raise ValueError(f"population {name!r}: teams differ in slot count {sorted(widths)}")
        for t in teams:
            unknown = [s for s in t.slots if s not in index]
            if unknown:
                raise ValueError(
                    f"team {t.name!r} names unknown member(s) {unknown}; members: {list(index)}"
                )
        self.name = name
        self.members = tuple(members)
        self.teams = tuple(teams)
        self.num_others = widths.pop()
        table = np.array([[index[s] for s in t.slots] for t in teams], dtype=np.int32)
        self.table = table  # [M, num_others] member index per team and slot
        # Per slot: the members that occur there, and each team's branch index among them.
        self._slot_members: list[tuple[int, ...]] = []
        self._slot_branch: list[jax.Array] = []
        for j in range(self.num_others):
            used = tuple(sorted(set(table[:, j].tolist())))
            self._slot_members.append(used)
            self._slot_branch.append(
                jnp.asarray([used.index(int(m)) for m in table[:, j]], dtype=jnp.int32)
            )

    @property
    def size(self) -> int:
        return len(self.teams)

    @property
    def team_names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.teams)

    def act(self, key: jax.Array, partner: jax.Array, other_obs: jax.Array) -> jax.Array:
        """Joint action [num_others] int32 of team ``partner`` from each slot's own obs."""
        keys = jax.random.split(key, self.num_others)
        actions = []
        for j in range(self.num_others):
            branches = [self.members[m].act for m in self._slot_members[j]]
            acts = jnp.stack([jnp.asarray(b(keys[j], other_obs[j]), jnp.int32) for b in branches])
            actions.append(acts[self._slot_branch[j][partner]] if len(branches) > 1 else acts[0])
        return jnp.stack(actions)

    def subset(self, team_names: Sequence[str], name: str | None = None) -> Population:
        """A population of only the named teams (e.g. for held-out splits)."""
        by_name = {t.name: t for t in self.teams}
        missing = [n for n in team_names if n not in by_name]
        if missing:
            raise ValueError(f"unknown team(s) {missing}; teams: {list(by_name)}")
        return Population(name or self.name, self.members, [by_name[n] for n in team_names])
