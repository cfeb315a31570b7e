"""What a training run reports as it goes: one metrics.jsonl record per chunk, TensorBoard
scalars and the progress bar.

Every number in a metrics record is computed inside jit from the runner state and keys derived
from the seed, so the same seed gives the same file; wall-clock numbers (steps/s) go only to
TensorBoard and the progress bar for that reason.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from transam.models.base import ACC_NEWEST
from transam.train.a2c import anneal_updates
from transam.train.config import TrainConfig
from transam.train.episodes import INPUT_SIZES, POLICY_ENTROPY
from transam.train.programs import Plan


def _clean_float(x: Any) -> float | None:
    v = float(x)
    return None if math.isnan(v) or math.isinf(v) else v


def make_record(
    chunk: int,
    seed: int,
    update: int,
    episodes: int,
    train: dict[str, Any],
    evaluation: dict[str, Any],
    plan: Plan,
    config: TrainConfig,
) -> dict[str, Any]:
    """One metrics.jsonl line from one seed's host-side chunk and evaluation metrics."""
    n_eps = int(train["episodes"])
    rec: dict[str, Any] = {
        "step": update * plan.steps_per_update,
        "update": update,
        "chunk": chunk,
        "seed": seed,
        "episodes": episodes,
        "train/return": float(train["return_sum"]) / n_eps if n_eps else None,
        "train/episodes": n_eps,
        "train/lr": policy_lr(config, update - 1),
    }
    for k, v in sorted(train.items()):
        if k not in ("episodes", "return_sum"):
            rec[f"train/{k.removeprefix('model/')}"] = _clean_float(v)
    for k in ("return", "return_std", ACC_NEWEST, "obs_mse", POLICY_ENTROPY, *INPUT_SIZES):
        if k in evaluation:  # a method without a decoder has no accuracy / MSE: absent, not 0
            rec[f"eval/{k}"] = _clean_float(evaluation[k])
    return rec


def policy_lr(config: TrainConfig, update: int) -> float:
    """The policy learning rate used by update number ``update`` (0-based), as the optimiser's
    linear schedule computes it (for logging)."""
    a = config.a2c
    if not a.anneal_lr:
        return a.lr
    n = anneal_updates(config)
    return a.lr * (1.0 - min(max(update, 0), n) / n)


class TBWriter:
    """TensorBoard scalars (tensorboardX), or nothing when it is not installed."""

    def __init__(self, logdir: Path, purge_step: int | None) -> None:
        try:
            from tensorboardX import SummaryWriter
        except ImportError:  # optional live view
            self.writer = None
            return
        self.writer = SummaryWriter(str(logdir), purge_step=purge_step, flush_secs=30)

    def write(self, record: dict[str, Any], extra: dict[str, float]) -> None:
        if self.writer is None:
            return
        step = record["step"]
        for k, v in {**record, **extra}.items():
            if "/" in k and isinstance(v, int | float) and not isinstance(v, bool):
                self.writer.add_scalar(k, v, step)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


@contextmanager
def progress(enabled: bool, total: int, description: str) -> Iterator[Callable[..., None]]:
    """A rich progress bar over environment steps; yields ``advance(steps, **fields)``."""
    if not enabled:
        yield lambda steps, **fields: None
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[sps]} steps/s"),
        TextColumn("return {task.fields[ret]}"),
        TextColumn("acc {task.fields[acc]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns) as bar:
        task = bar.add_task(description, total=total, sps="-", ret="-", acc="-")

        def advance(steps: int, **fields: Any) -> None:
            bar.update(task, advance=steps, **fields)

        yield advance


def mean_text(values: list[Any]) -> str:
    """The mean of the values that are not None, for the progress bar ("-" when none are)."""
    vals = [v for v in values if v is not None]
    return f"{np.mean(vals):.4g}" if vals else "-"
