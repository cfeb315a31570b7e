"""Compose a game with its partner population: the one place that joins envs/ and partners/.

Partner populations (``make_env(..., partners=...)``):

* ``"default"``: the shipped learned population (``transam/partners/data/<env>``, loaded by
  :func:`transam.partners.learned.population`): learned members, mixed with heuristics where
  the manifest's teams name them.
* ``"heldout"``: the shipped held-out population, built the same way from other seeds (and
  other variants), never used for training: for evaluating generalisation to new partners.
  Tag differs: its default population is LIAM's pretrained predators (imported, MIT), its
  held-out one our own learned predators in the same 10-team table.
* ``"heuristic"``: the scripted population of :mod:`transam.partners.<env>`.

The learned partners were trained in the default game, so they are offered only for a config
that equals the default in every field except those in :data:`PARTNER_BLIND_FIELDS` (fields
that change only rewards or the episode length, which the partners' policies never see: they
act on their own observation alone). Any other change (e.g. LBF's grid size, which changes
the observation size; Overcooked's ``controlled_slot``, which puts the partner in the seat it
was not trained for; Tag's ``hard_walls``, which changes the dynamics) raises
:class:`EnvError` rather than silently switching to other partners: pass
``partners="heuristic"`` or a population of your own.
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any, Literal

from transam.envs import ControlledEnv, EnvError, check_config, env_module
from transam.envs.population import Population

PartnerChoice = Literal["default", "heldout", "heuristic"]
PARTNER_CHOICES: tuple[str, ...] = ("default", "heldout", "heuristic")

PARTNER_BLIND_FIELDS: dict[str, frozenset[str]] = {
    "tag": frozenset({"episode_len", "boundary_penalty"}),
    "spread": frozenset({"reward", "self_collision", "local_ratio", "episode_len"}),
    "overcooked": frozenset(
        {"episode_len", "onion_in_pot_reward", "plate_pickup_reward", "soup_pickup_reward"}
    ),
    "lbf": frozenset({"penalty", "episode_len"}),
}
"""Config fields the shipped learned partners may run with at any value: they change only
rewards or the episode length (Overcooked's urgency channel means "under 40 steps left" at any
length). A field not listed here must keep its default for ``partners="default"/"heldout"``."""


def partner_population(name: str, config: Any = None, partners: str = "default") -> Population:
    """The ``partners`` population of env ``name`` for ``config`` (see the module docstring).

    Raises :class:`EnvError` for an unknown choice, or for a learned choice with a config the
    learned partners were not trained for (naming the fields and the way out).
    """
    config = check_config(name, config)
    if partners not in PARTNER_CHOICES:
        raise EnvError(
            f"unknown partners {partners!r}; valid choices: {', '.join(PARTNER_CHOICES)}"
        )
    if partners == "heuristic":
        heuristics = importlib.import_module(f"transam.partners.{name}")
        pop: Population = heuristics.heuristic_population(config)
        return pop
    default = type(config)()
    changed = [
        f"{f.name}={getattr(config, f.name)!r} (default {getattr(default, f.name)!r})"
        for f in dataclasses.fields(config)
        if f.name not in PARTNER_BLIND_FIELDS[name]
        and getattr(config, f.name) != getattr(default, f.name)
    ]
    if changed:
        raise EnvError(
            f"partners {partners!r} of env {name!r} are learned in the default game and do not "
            f"fit this config ({', '.join(changed)}); pass partners='heuristic' (valid choices: "
            f"{', '.join(PARTNER_CHOICES)}) or a population of your own"
        )
    from transam.partners.learned import population

    return population(name, partners)


def make_env(
    name: str,
    config: Any = None,
    population: Population | None = None,
    partners: str = "default",
) -> ControlledEnv:
    """Environment ``name`` with ``config`` (defaults when None) and a partner population.

    ``population`` is used as given; otherwise ``partners`` picks one (``"default"``: the
    shipped learned population; ``"heldout"``; ``"heuristic"``), see the module docstring.
    """
    module = env_module(name)
    config = check_config(name, config)
    if population is None:
        population = partner_population(name, config, partners)
    elif partners != "default":
        raise EnvError(f"pass either population or partners={partners!r}, not both")
    return module.make_env(config, population)
