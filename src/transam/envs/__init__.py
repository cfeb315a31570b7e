"""The paper's four environments as controlled-agent JAX games.

``make(name)`` builds one with its default configuration and partner population. Modules are
imported lazily so that using one environment does not pay for the others' imports.
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
    "config_class",
    "make",
]


def _module(name: str) -> Any:
    if name not in ENV_NAMES:
        raise EnvError(f"unknown environment {name!r}; valid choices: {', '.join(ENV_NAMES)}")
    return importlib.import_module(f"transam.envs.{name}")


def config_class(name: str) -> type:
    """The typed configuration dataclass of environment ``name``."""
    return _module(name).Config


def make(name: str, config: Any = None, population: Any = None) -> ControlledEnv:
    """Environment ``name`` with ``config`` (defaults when None) and its default population."""
    module = _module(name)
    if config is not None and not isinstance(config, module.Config):
        raise EnvError(
            f"config for env {name!r} must be a {module.Config.__name__}; "
            f"got {type(config).__name__}"
        )
    return module.make_env(config or module.Config(), population)
