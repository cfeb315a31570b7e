"""What the demo shows: before it trains, the shipped pretrained runs of an environment against
its default partners, beside the references that say whether they learned anything
(:func:`showcase`); after, how far its own run got (:func:`training_summary`).

Return references: a uniformly random controlled agent on the same evaluation episodes
(:func:`~transam.evaluation.final.paired_random_returns`: the same partners and starts, so
each run's gain over it is measured pairwise, with a small standard error) and, on Spread,
the landmark rule of :func:`transam.partners.spread.landmark_agent` (its own episodes, the
same partner mix).
Accuracy references: the population's memoryless level from the controlled agent's own view
(the best a predictor of the partners' actions can do from the current observation alone,
recorded in the population's manifest by ``transam partners diversity --record``) and the
ceiling.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from transam.evaluation.final import evaluate_run, random_returns
from transam.evaluation.weights import pretrained_dir, pretrained_names, read_card
from transam.models.base import ACC_NEWEST
from transam.train.config import TrainConfig


@dataclass(frozen=True)
class Showcase:
    env: str
    episodes: int
    runs: dict[str, dict[str, Any]]  # name -> evaluate_run's result
    gain: dict[str, dict[str, float]]  # name -> {mean, se}: return minus random's, per episode
    random: dict[str, float]  # on the same episodes (the first run's random agent)
    landmark: dict[str, float] | None  # Spread only
    levels: dict[str, Any] | None  # the population's recorded accuracy levels


def shipped_for(env: str) -> list[str]:
    """The shipped pretrained runs of ``env`` that play its default partners, TransAM first."""
    cards = {n: read_card(pretrained_dir(n)) for n in pretrained_names()}
    names = [n for n, c in cards.items() if c.get("env") == env and c.get("partners") == "default"]
    return sorted(names, key=lambda n: (cards[n].get("method") != "transam", n))


def landmark_return(episodes: int, seed: int) -> dict[str, float]:
    """The landmark rule's mean return on Spread's default partners (``episodes`` episodes)."""
    import jax

    from transam.compose import make_env
    from transam.envs.rollout import episode_stats, make_random_rollout
    from transam.partners.spread import landmark_agent

    env = make_env("spread")
    rollout = make_random_rollout(env, episodes, env.spec.episode_len, landmark_agent)
    return mean_se(episode_stats(rollout(jax.random.key(seed))[1]).returns)


def showcase(env: str, episodes: int = 200, seed: int = 0) -> Showcase | None:
    """Evaluate each shipped pretrained run of ``env`` (outputs in runs/pretrained/NAME), or
    None when the package ships none for it."""
    from transam.reproduce.report.results import partner_levels

    names = shipped_for(env)
    if not names:
        return None
    runs = {n: evaluate_run(n, episodes, seed=seed) for n in names}
    paired = {n: (np.asarray(runs[n]["returns"]), random_returns(n, episodes, seed)) for n in names}
    gain = {n: mean_se(t - r) for n, (t, r) in paired.items()}
    return Showcase(
        env=env,
        episodes=episodes,
        runs=runs,
        gain=gain,
        random=mean_se(paired[names[0]][1]),
        landmark=landmark_return(episodes, seed) if env == "spread" else None,
        levels=partner_levels([env])[env],
    )


def mean_se(x: np.ndarray) -> dict[str, float]:
    """Mean, standard deviation and standard error of the mean of per-episode values."""
    return {"mean": float(x.mean()), "std": float(x.std()), "se": float(x.std() / np.sqrt(len(x)))}


def standard_error(r: dict[str, float], n: int) -> float:
    return float(r["std"] / np.sqrt(max(n, 1)))


def accuracy_by_step(res: dict[str, Any], every: int = 4) -> list[tuple[int, float]]:
    """(t, newest-position accuracy) at every ``every``-th step of the episode and the last."""
    curve = res["per_step"].get(ACC_NEWEST) or []
    steps = sorted({*range(0, len(curve), every), len(curve) - 1}) if curve else []
    return [(t, curve[t]) for t in steps if curve[t] is not None]


@dataclass(frozen=True)
class TrainingSummary:
    """How far a finished training run got (what ``transam demo`` prints after training)."""

    first: dict[str, Any]
    """the first evaluation's metrics record (seed ``config.seed``)"""
    last: dict[str, Any]
    """the last evaluation's"""
    random_return: float
    """a uniformly random agent's mean return on the last evaluation's episodes"""
    accuracy: float | None
    """the last evaluation's partner-action accuracy (newest position); None without one"""
    memoryless: float | None
    """the population's recorded memoryless level from the agent's own view (the default
    partners only; None where none is recorded)"""


def training_summary(config: TrainConfig) -> TrainingSummary:
    """The first seed's first and last evaluations of the finished run ``config``, beside a
    uniformly random agent on the same episodes and the memoryless accuracy level."""
    from transam.reproduce.report.results import partner_levels
    from transam.rundir import read_metrics, seed_dirs
    from transam.train.programs import uniform_policy_eval

    records = read_metrics(seed_dirs(config)[0] / "metrics.jsonl")
    first, last = records[0], records[-1]
    rand = uniform_policy_eval(config, config.seed, len(records) - 1)["return"]
    levels = partner_levels([config.env])[config.env] if config.partners == "default" else None
    return TrainingSummary(
        first=first,
        last=last,
        random_return=rand,
        accuracy=last.get(f"eval/{ACC_NEWEST}"),
        memoryless=levels["memoryless_own_accuracy"] if levels else None,
    )
