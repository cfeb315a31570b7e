"""The paper's four environments as controlled-agent JAX games (dynamics only).

Each module defines a ``Config``, a :class:`Game` and ``make_env(config, population)``. Partner
populations live in :mod:`transam.partners` (which may import this package, never the
reverse); :func:`transam.make_env` composes a game with its population. Modules are imported
lazily so that using one environment does not pay for the others' imports.
"""

from __future__ import annotations

import importlib
from typing import Any

from transam.envs.core import (
    ControlledEnv,
    EnvError,
    EnvState,
    Game,
    GameSpec,
    PartnerRecord,
    Timestep,
)

ENV_NAMES: tuple[str, ...] = ("tag", "spread", "overcooked", "lbf")

__all__ = [
    "ENV_NAMES",
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
    if name not in ENV_NAMES:
        raise EnvError(f"unknown environment {name!r}; valid choices: {', '.join(ENV_NAMES)}")
    return importlib.import_module(f"transam.envs.{name}")


def config_class(name: str) -> type:
    """The typed configuration dataclass of environment ``name``."""
    return env_module(name).Config


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
