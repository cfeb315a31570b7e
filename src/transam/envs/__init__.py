"""The paper's four environments as controlled-agent JAX games (dynamics only).

Their names and modules are entries of :mod:`transam.registry`. Each module defines a
``Config``, a :class:`Game` and ``make_env(config, population)``. Partner populations live in
:mod:`transam.partners` (which may import this package, never the reverse);
:func:`transam.make_env` composes a game with its population. Modules are imported lazily so
that using one environment does not pay for the others' imports. :mod:`transam.envs.jaxmarl`
turns a user's JaxMARL environment into such a game.
"""

from __future__ import annotations

from typing import Any

from transam import registry
from transam.envs.core import (
    ControlledEnv,
    EnvError,
    EnvState,
    Game,
    GameSpec,
    PartnerRecord,
    Timestep,
)

__all__ = [
    "ControlledEnv",
    "EnvError",
    "EnvState",
    "Game",
    "GameSpec",
    "PartnerRecord",
    "Timestep",
    "check_config",
    "config_class",
    "env_module",
]


def env_module(name: str) -> Any:
    """The game of registered environment ``name``: its ``Config`` and ``make_env``."""
    return _entry(name).module()


def config_class(name: str) -> type:
    """The typed configuration dataclass of environment ``name``."""
    return _entry(name).config_class()


def _entry(name: str) -> registry.EnvEntry:
    try:
        return registry.env_entry(name)
    except registry.RegistryError as err:
        raise EnvError(str(err)) from None


def check_config(name: str, config: Any) -> Any:
    """``config`` (the defaults when None), checked to be ``name``'s Config."""
    cls = config_class(name)
    if config is None:
        return cls()
    if not isinstance(config, cls):
        raise EnvError(
            f"config for env {name!r} must be a {cls.__name__}; got {type(config).__name__}"
        )
    return config
