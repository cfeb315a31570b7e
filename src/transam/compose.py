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
* any other name an env's registry entry lists in ``populations`` (a user's game, registered
  with :func:`transam.registry.register_env`, may bring its own ``"default"``).
* a **population directory** (a path; the choices above take precedence, so write
  ``./default`` for a folder of that name): ``manifest.json`` + ``default.safetensors`` in the
  shipped format (:mod:`transam.partners.learned` describes it), e.g. one written by
  ``transam partners import-authors spread`` or by you.

The learned partners were trained in the default game, so they are offered only for a config
that equals the default in every field except its registry entry's ``blind_fields`` (fields
that change only rewards or the episode length, which the partners' policies never see: they
act on their own observation alone). Any other change (e.g. LBF's grid size, which changes
the observation size; Overcooked's ``controlled_slot``, which puts the partner in the seat it
was not trained for; Tag's ``hard_walls``, which changes the dynamics) raises
:class:`EnvError` rather than silently switching to other partners: pass
``partners="heuristic"`` or a population of your own.

A population directory follows the same rule against the config its manifest names
(``"config"``, e.g. ``{"dynamics": "authors"}``; fields it does not name: their defaults), and
must be made for this env (the manifest's ``"env"``).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Annotated, Any

import tyro

from transam import registry
from transam.envs import ControlledEnv, EnvError, check_config, env_module
from transam.envs.population import Population

PartnerChoice = Annotated[str, tyro.conf.arg(metavar="{default,heldout,heuristic}|DIR")]
"""A ``partners`` value: one of :func:`partner_choices` or a population directory's path
(checked by :func:`check_partners`, not by the type)."""
DIRECTORY_FORMAT = "a population directory (manifest.json + <split>.safetensors, split 'default')"


def partner_choices(env: str | None = None) -> tuple[str, ...]:
    """The named ``partners`` choices of registered env ``env`` (its registry entry's), or of
    any registered env (the paper's: ``default``, ``heldout``, ``heuristic``)."""
    entries = [registry.env_entry(env)] if env else map(registry.env_entry, registry.env_names())
    return tuple(dict.fromkeys(c for e in entries for c in e.partner_choices()))


def check_partners(partners: str | os.PathLike[str], env: str | None = None) -> str:
    """``partners`` as a string when it is a choice of :func:`partner_choices` (of ``env`` when
    given) or a population directory; else :class:`EnvError` naming the value, the valid
    choices and the format."""
    from transam.partners.learned import is_population_dir

    value = os.fspath(partners)
    choices = partner_choices(env)
    if value in choices or is_population_dir(value):
        return value
    why = ""
    if Path(value).is_dir():
        why = f" ({value!r} is a directory without manifest.json)"
    raise EnvError(
        f"unknown partners {value!r}{why}; valid choices: {', '.join(choices)}, or "
        f"{DIRECTORY_FORMAT}"
    )


def resolve_partners(partners: str) -> str:
    """A population directory as an absolute path (runs record it, and may be evaluated or
    resumed from another working directory); the named choices unchanged."""
    value = check_partners(partners)
    return value if value in partner_choices() else str(Path(value).resolve())


def envs_for_partners(partners: str, envs: tuple[str, ...]) -> tuple[str, ...]:
    """The envs of ``envs`` that ``partners`` can play: all of them for a named choice, the
    one env a population directory was made for (:class:`EnvError` where ``envs`` lacks it;
    an unknown ``partners`` value is one too, naming the valid choices)."""
    from transam.partners.learned import read_population_dir

    if check_partners(partners) in partner_choices():
        return envs
    made_for = read_population_dir(partners).get("env")
    if made_for not in envs:
        raise EnvError(
            f"population directory {partners} is for env {made_for!r}; pass --envs {made_for}"
        )
    return (made_for,)


def partner_population(
    name: str, config: Any = None, partners: str | os.PathLike[str] = "default"
) -> Population:
    """The ``partners`` population of env ``name`` for ``config`` (see the module docstring).

    Raises :class:`EnvError` for an unknown choice, or for a learned choice with a config the
    learned partners were not trained for (naming the fields and the way out).
    """
    config = check_config(name, config)
    partners = check_partners(partners, name)
    entry = registry.env_entry(name)
    if partners in entry.populations:
        pop: Population = registry.resolve(entry.populations[partners])(config)
        return pop
    from transam.partners import learned

    made_for, what, label = type(config)(), "the default game", "default"
    manifest = None
    if partners not in entry.partner_choices():
        try:
            manifest = learned.read_population_dir(partners, name)
        except ValueError as err:
            raise EnvError(str(err)) from None
        named = manifest.get("config") or {}
        fields = {f.name for f in dataclasses.fields(made_for)}
        unknown = sorted(set(named) - fields)
        if unknown:
            raise EnvError(
                f"population directory {partners!r}: its config names unknown {name} field(s) "
                f"{', '.join(unknown)}; valid: {', '.join(sorted(fields))}"
            )
        made_for = dataclasses.replace(made_for, **named)
        what = f"the config its manifest names ({_fields(named) or 'the defaults'})"
        label = "made for"
    changed = [
        f"{f.name}={getattr(config, f.name)!r} ({label} {getattr(made_for, f.name)!r})"
        for f in dataclasses.fields(config)
        if f.name not in entry.blind_fields and getattr(config, f.name) != getattr(made_for, f.name)
    ]
    if changed:
        raise EnvError(
            f"partners {partners!r} of env {name!r} are learned in {what} and do not "
            f"fit this config ({', '.join(changed)}); pass partners='heuristic' (valid choices: "
            f"{', '.join(entry.partner_choices())}, or {DIRECTORY_FORMAT}) or a population of "
            "your own"
        )
    try:
        if manifest is not None:
            return learned.directory_population(name, partners)
        return learned.population(name, partners)
    except ValueError as err:
        raise EnvError(str(err)) from None


def _fields(values: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v!r}" for k, v in sorted(values.items()))


def make_env(
    name: str,
    config: Any = None,
    population: Population | None = None,
    partners: str | os.PathLike[str] = "default",
) -> ControlledEnv:
    """Environment ``name`` with ``config`` (defaults when None) and a partner population.

    ``population`` is used as given; otherwise ``partners`` picks one (``"default"``: the
    shipped learned population; ``"heldout"``; ``"heuristic"``; or a population directory's
    path), see the module docstring.
    """
    module = env_module(name)
    config = check_config(name, config)
    partners = os.fspath(partners)
    if population is None:
        population = partner_population(name, config, partners)
    elif partners != "default":
        raise EnvError(f"pass either population or partners={partners!r}, not both")
    return module.make_env(config, population)
