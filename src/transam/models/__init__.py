"""Agent models (TransAM, its ablations and the baselines) behind one protocol; see
:mod:`transam.models.base`. Every method is built by :func:`make_model` from its name
(its entry in :mod:`transam.registry` names its ``build_*`` function here)."""

from __future__ import annotations

import dataclasses

from transam import registry
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
    "AgentModel",
    "BaselineConfig",
    "LocalStep",
    "PartnerView",
    "TransAMConfig",
    "build_cail",
    "build_carl",
    "build_liam",
    "build_nam",
    "build_oracle",
    "build_pel",
    "build_transam",
    "make_model",
]


def build_transam(
    spec: GameSpec, transformer: TransAMConfig, baseline: BaselineConfig, **ablation: str
) -> AgentModel:
    """TransAM, or an ablation with its settings (its imitation decoder sized as CAIL's): the
    window model, or the streaming one with ``attention="stream"``."""
    config = dataclasses.replace(transformer, **ablation)  # type: ignore[arg-type]
    if config.attention == "stream":
        return StreamTransAM(spec=spec, config=config, decoder_hidden=baseline.decoder_hidden)
    return TransAM(spec=spec, config=config, decoder_hidden=baseline.decoder_hidden)


def build_nam(spec: GameSpec, transformer: TransAMConfig, baseline: BaselineConfig) -> AgentModel:
    return NAM(num_actions=spec.num_actions)


def build_oracle(
    spec: GameSpec, transformer: TransAMConfig, baseline: BaselineConfig
) -> AgentModel:
    return Oracle(spec=spec)  # type: ignore[return-value]


def build_liam(spec: GameSpec, transformer: TransAMConfig, baseline: BaselineConfig) -> AgentModel:
    return LIAM(spec=spec, config=baseline)


def build_carl(spec: GameSpec, transformer: TransAMConfig, baseline: BaselineConfig) -> AgentModel:
    return CARL(spec=spec, config=baseline)


def build_cail(spec: GameSpec, transformer: TransAMConfig, baseline: BaselineConfig) -> AgentModel:
    return CAIL(spec=spec, config=baseline)


def build_pel(spec: GameSpec, transformer: TransAMConfig, baseline: BaselineConfig) -> AgentModel:
    return PEL(spec=spec, config=transformer, baseline=baseline)


def make_model(
    method: str,
    spec: GameSpec,
    transformer: TransAMConfig | None = None,
    baseline: BaselineConfig | None = None,
) -> AgentModel:
    """The agent model ``method`` (a name in :mod:`transam.registry`) for environment ``spec``;
    ``transformer`` configures the transformer encoders (TransAM, its ablations, PEL),
    ``baseline`` the others."""
    try:
        entry = registry.method_entry(method)
    except registry.RegistryError as err:
        raise EnvError(str(err)) from None
    model: AgentModel = registry.resolve(entry.factory)(
        spec, transformer or TransAMConfig(), baseline or BaselineConfig(), **entry.options
    )
    return model
