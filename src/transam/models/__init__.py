"""Agent models (TransAM, its ablations and the baselines) behind one protocol; see
:mod:`transam.models.base`. Every method is built by :func:`make_model` from its name."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from transam.envs.core import EnvError, GameSpec
from transam.models.base import AgentModel, LocalStep, PartnerView
from transam.models.cail import CAIL
from transam.models.carl import CARL
from transam.models.config import BaselineConfig
from transam.models.liam import LIAM
from transam.models.nam import NAM
from transam.models.oracle import Oracle
from transam.models.pel import PEL
from transam.models.stream import StreamTransAM
from transam.models.transam import TransAM, TransAMConfig

__all__ = [
    "METHOD_NAMES",
    "AgentModel",
    "BaselineConfig",
    "LocalStep",
    "PartnerView",
    "TransAMConfig",
    "make_model",
]

Factory = Callable[[GameSpec, TransAMConfig, BaselineConfig], AgentModel]


def _transformer(**ablation: str) -> Factory:
    """TransAM with an ablation's settings (its imitation decoder sized as CAIL's): the
    window model, or the streaming one with ``attention="stream"``."""

    def build(spec: GameSpec, t: TransAMConfig, b: BaselineConfig) -> AgentModel:
        config = dataclasses.replace(t, **ablation)  # type: ignore[arg-type]
        if config.attention == "stream":
            return StreamTransAM(spec=spec, config=config, decoder_hidden=b.decoder_hidden)
        return TransAM(spec=spec, config=config, decoder_hidden=b.decoder_hidden)

    return build


_FACTORIES: dict[str, Factory] = {
    "transam": _transformer(),
    "nam": lambda spec, t, b: NAM(num_actions=spec.num_actions),
    "oracle": lambda spec, t, b: Oracle(spec=spec),  # type: ignore[dict-item,return-value]
    "liam": lambda spec, t, b: LIAM(spec=spec, config=b),
    "carl": lambda spec, t, b: CARL(spec=spec, config=b),
    "cail": lambda spec, t, b: CAIL(spec=spec, config=b),
    "pel": lambda spec, t, b: PEL(spec=spec, config=t, baseline=b),
    "transam-fuse": _transformer(tokens="fuse"),
    "transam-pool": _transformer(pool="mean"),
    "transam-im": _transformer(decoder="imitate"),
}
"""Every method by name: the paper's order is TransAM, baselines, ablations."""

METHOD_NAMES: tuple[str, ...] = tuple(_FACTORIES)


def make_model(
    method: str,
    spec: GameSpec,
    transformer: TransAMConfig | None = None,
    baseline: BaselineConfig | None = None,
) -> AgentModel:
    """The agent model ``method`` for environment ``spec``; ``transformer`` configures the
    transformer encoders (TransAM, its ablations, PEL), ``baseline`` the others."""
    if method not in _FACTORIES:
        raise EnvError(f"unknown method {method!r}; valid choices: {', '.join(METHOD_NAMES)}")
    return _FACTORIES[method](spec, transformer or TransAMConfig(), baseline or BaselineConfig())
