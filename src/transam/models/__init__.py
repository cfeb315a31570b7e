"""Agent models (TransAM and the baselines) behind one protocol; see :mod:`transam.models.base`."""

from __future__ import annotations

from typing import Any

from transam.envs.core import EnvError, GameSpec
from transam.models.base import AgentModel, LocalStep

METHOD_NAMES: tuple[str, ...] = ("transam", "nam")

__all__ = ["METHOD_NAMES", "AgentModel", "LocalStep", "make_model"]


def make_model(method: str, spec: GameSpec, config: Any = None) -> AgentModel:
    """The agent model ``method`` for environment ``spec`` (``config``: its typed settings)."""
    if method == "nam":
        from transam.models.nam import NAM

        return NAM(num_actions=spec.num_actions)
    if method == "transam":
        from transam.models.transam import TransAM, TransAMConfig

        return TransAM(spec=spec, config=config or TransAMConfig())
    raise EnvError(f"unknown method {method!r}; valid choices: {', '.join(METHOD_NAMES)}")
