"""Settings of the baseline agent models (TransAM's own are :class:`TransAMConfig`, which the
transformer baselines share). Defaults give every method comparable capacity; see
docs/methods.md."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class BaselineConfig:
    """Settings of LIAM, CARL, CAIL (recurrent encoders) and the contrastive losses (CARL, PEL)."""

    hidden: int = 128
    """LSTM width of the recurrent encoders (LIAM, CARL, CAIL)"""
    embed_dim: int = 128
    """embedding z width of the recurrent encoders (LIAM used 20; 128 matches TransAM's z)"""
    decoder_hidden: int = 128
    """hidden width of the MLP decoders (LIAM's reconstruction, the imitation decoder)"""
    temperature: float = 0.1
    """InfoNCE temperature (CARL, PEL)"""
    carl_positives: Literal["episode", "partner"] = "partner"
    """CARL positives: steps with the same partner index (supervised contrastive, default) or
    only steps of the same episode (SimCLR-style: on short rollouts the task is near-trivial)"""
    pel_alpha: float = 1.0
    """PEL: weight of the discriminative (contrastive) loss against the generative one"""
