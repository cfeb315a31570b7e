"""``transam evaluate``: the final evaluation of a trained run.

:func:`evaluate_run` loads a checkpoint of a run directory and plays ``episodes`` episodes in
parallel (one per environment copy, one jitted program: the rollout of
:func:`transam.train.episodes.make_episodes`, which training-time evaluation uses too). It
writes ``eval_{partners}.json`` (schema below), a figure ``eval_{partners}.png`` and the 2-D
projection ``eval_{partners}_pca.npz`` (``coords`` [N, 2], ``partner`` [N], ``team_names``,
``explained_variance``, ``t``) so that a report can redraw it.

Partners are assigned *balanced*, episode i playing partner ``i mod M``, rather than drawn at
random: every partner gets (nearly) the same number of episodes, which removes the sampling
variance of the partner mix from the mean return and gives the probe balanced classes.

Per-step curves (index t = 0 .. T-1 within the episode): ``cum_return[t]`` is the mean over
all episodes of the reward summed up to and including step t (an episode that ended keeps its
return, so the last value is the mean return); the metric curves ``[t]`` are means over the
episodes still running at step t (null where none is).

Agent-modeling metrics (:data:`EVAL_METRICS`, each only where the model predicts it):
``action_accuracy_newest`` and ``obs_mse``, the decoder on the z the policy acted on (the
newest window position; the authors' evaluation metric), and, for methods that decode every
window position (TransAM, -fuse, -im), ``action_accuracy_all_positions`` and
``obs_mse_all_positions``, the authors' training-time form, where later observations in the
bidirectional window reveal older positions' answers (see :mod:`transam.train.episodes`).

Representation quality (:mod:`transam.evaluation.probe`): a linear probe predicts the partner
index from the embedding z_t the policy acted on at step t (TransAM's E^o_t; each baseline's
own z), separately for every t; the projection is PCA of the embeddings at each episode's last
step. NAM has no learned embedding (its z is the one-hot previous action), so it gets neither;
the Oracle's z contains the other agents' observations (privileged), which the JSON notes.

JSON: ``env``, ``method``, ``seed``, ``partners`` ("train"|"heldout"|a population directory,
written to ``eval_pop-NAME.*``), ``population`` (the
partner choice it mapped to), ``population_name``, ``trained_partners``, ``population_digest``
and ``trained_population_digest`` (the shipped population's fingerprint now and the run's
partners.json's; None for scripted partners or runs older than that file), ``checkpoint`` (path
relative to the run directory: the named one, or the newest that verifies, any newer one that
does not being named in ``notes``), ``step``, ``episodes``, ``greedy``, ``act_dropout``
(whether the agent model acted with its dropout), ``return`` {mean, std},
the :data:`EVAL_METRICS` the model predicts, ``policy_entropy`` (the policy's mean entropy
per step, nats), ``obs_norm`` and ``z_norm`` (the mean sizes of the policy's two inputs,
|o_t| and |z_scale * z_t|: :data:`transam.train.episodes.Z_NORM`), ``action_frequency``
[A] (the share of each of the controlled agent's actions over the episodes' steps; on the
MPE games action 0 is "no move"), ``per_partner_return`` {team: mean},
``per_step`` {cum_return, and a curve per metric present, policy_entropy included},
``probe`` {accuracy, per_step, chance, train_episodes, test_episodes, features, ridge} and
``pca`` {explained_variance} (both absent without an embedding), ``notes`` [str].
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from transam import registry
from transam.evaluation.figure import evaluation_figure
from transam.evaluation.probe import linear_probe, pca_2d
from transam.evaluation.weights import is_pretrained, is_shipped, resolve_run, restore_weights
from transam.models.base import ACC_ALL, ACC_NEWEST, MSE_ALL
from transam.rundir import (
    EVAL_PARTNERS,
    evaluation_path,
    load_run_config,
    projection_path,
    recorded_population,
    run_lock,
    starts_evaluation_path,
    write_atomic,
    write_json,
)
from transam.train.config import ConfigError, TrainConfig
from transam.train.episodes import INPUT_SIZES, POLICY_ENTROPY

EVAL_METRICS = (ACC_NEWEST, ACC_ALL, "obs_mse", MSE_ALL)
"""The agent-modeling metrics an evaluation may hold (older files: ``action_accuracy``, the
newest position's, see :data:`~transam.models.base.LEGACY_METRICS`)."""


def population_for(trained: str, partners: str) -> str:
    """The partner choice (make_env's ``partners``) that ``partners`` means for a run trained
    with ``trained``: "train" is the run's own population; "heldout" one it never met (the
    held-out split; for a run trained on the held-out split, the default population); a
    population directory is itself (as an absolute path)."""
    from transam.compose import DIRECTORY_FORMAT, resolve_partners
    from transam.partners.learned import is_population_dir

    if partners not in EVAL_PARTNERS:
        if is_population_dir(partners):
            return resolve_partners(partners)
        raise ConfigError(
            f"unknown partners {partners!r}; valid choices: {', '.join(EVAL_PARTNERS)}, or "
            f"{DIRECTORY_FORMAT}"
        )
    if partners == "train":
        return trained
    return "default" if trained == "heldout" else "heldout"


def balanced_partners(n: int, num_partners: int) -> np.ndarray:
    """Episode i plays partner i mod M (see the module docstring for why)."""
    return (np.arange(n) % num_partners).astype(np.int32)


# ---------------------------------------------------------------- the evaluation


@functools.lru_cache(maxsize=8)
def episodes_program(config: TrainConfig, n: int) -> Callable[..., Any]:
    """The jitted rollout of ``n`` episodes that every evaluation here plays
    (:func:`transam.train.episodes.make_episodes` with the all-positions metrics), for a
    config keyed by :func:`transam.train.programs.program_key`: cached, since a grid
    evaluates many runs of one program in one process."""
    from transam.train.episodes import make_episodes
    from transam.train.programs import env_and_model

    env, model = env_and_model(config)
    return jax.jit(make_episodes(config, env, model, n, positions=True))


def paired_random_returns(
    run_dir: str | Path, episodes: int = 100, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Per-episode returns of the run's policy and of a uniformly random controlled agent (the
    policy with its actor zeroed: every action equally likely) on the episodes ``evaluate_run``
    plays with the same ``episodes`` and ``seed``: the same partners and starts, so the
    difference of the two has a far smaller standard error than either return. After
    ``evaluate_run``, its JSON's ``returns`` and :func:`random_returns` give the same pair
    without playing the policy again."""
    trained, random = _play(run_dir, episodes, seed, (False, True))
    return trained, random


def random_returns(run_dir: str | Path, episodes: int = 100, seed: int = 0) -> np.ndarray:
    """The random half of :func:`paired_random_returns`."""
    return _play(run_dir, episodes, seed, (True,))[0]


def _play(
    run_dir: str | Path, episodes: int, seed: int, random: tuple[bool, ...]
) -> list[np.ndarray]:
    """Per-episode returns of the run's policy (False) or the uniform one (True), for each
    entry of ``random``, on the same episodes; the run is restored once."""
    from transam.train.programs import env_and_model, program_key, uniform_policy_params

    run_dir = resolve_run(run_dir)
    config = load_run_config(run_dir)
    w = restore_weights(config, run_dir, None, [])
    run = episodes_program(program_key(config), episodes)
    num_partners = env_and_model(config)[0].num_partners
    partner_ids = jnp.asarray(balanced_partners(episodes, num_partners))
    out = []
    for uniform in random:
        params = uniform_policy_params(w.policy_params) if uniform else w.policy_params
        ep = run(params, w.model_params, jax.random.key(seed), partner_ids)
        out.append(np.asarray(jax.device_get(ep.reward), np.float64).sum(0))
    return out


def evaluate_starts(
    run_dir: str | Path,
    starts: str | Path,
    checkpoint: str | int | None = None,
    seed: int = 0,
    out: str | Path | None = None,
    dropout: bool = True,
) -> dict[str, Any]:
    """Play a run's checkpoint on the episodes of a starts file (:mod:`transam.envs.starts`:
    given start positions and partner teams, e.g. another codebase's evaluation episodes),
    against the run's own partner population, and write ``eval_starts-STEM.json`` into
    :func:`output_dir`: ``return`` {mean, std, se}, ``per_group`` {group: mean return}, the
    per-episode ``returns``, ``team`` and ``group``, ``policy_entropy`` and the agent-modeling
    metrics the model predicts. Actions are sampled as in every evaluation (``eval.greedy``).
    Without ``dropout`` the agent model acts without its dropout
    (``eval_starts-STEM-nodropout.json``)."""
    from transam.envs.starts import load_starts
    from transam.train.programs import env_and_model, program_key

    _check_seed(seed)
    dest = output_dir(run_dir, out)
    run_dir = resolve_run(run_dir)
    config = load_run_config(run_dir)
    env, _ = env_and_model(config)
    st = load_starts(starts, env)  # a bad file fails before anything is written
    with _locked(run_dir, dest, "transam evaluate --starts"):
        notes: list[str] = []
        w = restore_weights(config, run_dir, checkpoint, notes)
        acting = _acting(config, dropout, notes)
        run = episodes_program(program_key(acting), st.episodes)
        ep = jax.device_get(
            run(
                w.policy_params,
                w.model_params,
                jax.random.key(seed),
                jnp.asarray(st.team),
                st.game,
            )
        )
        live = np.asarray(ep.live, np.float64)
        returns = np.asarray(ep.reward, np.float64).sum(0)
        res: dict[str, Any] = {
            "env": config.env,
            "method": config.method,
            "seed": config.seed,
            "starts": st.source,
            "checkpoint": w.source,
            "step": w.step,
            "episodes": st.episodes,
            "greedy": config.eval.greedy,
            "act_dropout": acting.acting_dropout,
            "return": {
                "mean": float(returns.mean()),
                "std": float(returns.std()),
                "se": float(returns.std(ddof=1) / np.sqrt(len(returns))),
            },
            "per_group": {
                int(g): float(returns[st.group == g].mean()) for g in np.unique(st.group)
            },
        }
        for key in (*EVAL_METRICS, POLICY_ENTROPY, *INPUT_SIZES):
            if key in ep.scores:
                res[key] = float(np.asarray(ep.scores[key], np.float64).sum() / live.sum())
        res["returns"] = [float(r) for r in returns]
        res["team"] = [int(t) for t in st.team]
        res["group"] = [int(g) for g in st.group]
        res["notes"] = notes
        write_json(starts_evaluation_path(dest, starts, dropout), res)
    return res


def _per_step_mean(values: np.ndarray, live: np.ndarray) -> list[float | None]:
    count = live.sum(1)
    return [float(v / c) if c > 0 else None for v, c in zip(values.sum(1), count, strict=True)]


def output_dir(run_dir: str | Path, out: str | Path | None = None) -> Path:
    """Where ``transam evaluate`` writes: ``out``, else the run directory, except for a shipped
    pretrained run (inside the package), whose outputs go to runs/pretrained/NAME."""
    if out is not None:
        return Path(out)
    run_dir = resolve_run(run_dir)
    if is_shipped(run_dir):
        return Path("runs/pretrained") / run_dir.name
    return run_dir


def evaluate_run(
    run_dir: str | Path,
    episodes: int = 100,
    partners: str = "train",
    checkpoint: str | int | None = None,
    seed: int = 0,
    out: str | Path | None = None,
    dropout: bool = True,
) -> dict[str, Any]:
    """Evaluate a run's checkpoint (or a pretrained run: a directory, or the name of a shipped
    one) on ``episodes`` episodes with its training partners or held-out ones; write
    eval_{partners}.json/.png/_pca.npz into :func:`output_dir` and return the JSON's contents.
    Holds that directory's lock meanwhile; without ``checkpoint``, uses the newest checkpoint
    that verifies and notes each newer one that does not. Without ``dropout`` the agent model
    acts without its dropout, and the outputs are named ``eval_{partners}-nodropout.*``."""
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 2:
        raise ConfigError(f"episodes must be an integer >= 2, got {episodes!r}")
    _check_seed(seed)
    dest = output_dir(run_dir, out)
    run_dir = resolve_run(run_dir)
    config = load_run_config(run_dir)
    population_for(config.partners, partners)  # checks ``partners``
    with _locked(run_dir, dest, "transam evaluate") as top:
        return _evaluate_locked(
            run_dir, top, dest, config, episodes, partners, checkpoint, seed, dropout
        )


def _check_seed(seed: Any) -> None:
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"seed must be an integer >= 0, got {seed!r}")


def _acting(config: TrainConfig, dropout: bool, notes: list[str]) -> TrainConfig:
    """The run's config to play with: as trained, or (``dropout`` False) with the agent model's
    dropout off while acting. The reference keeps dropout on in its evaluation, which costs
    the TransAM family some accuracy; without it the evaluation reads what the model knows.
    Only the acting changes (the z the policy sees and the decoder's predictions)."""
    if dropout:
        return config
    if not config.acting_dropout:
        notes.append(
            f"--no-dropout changes nothing here: {config.method} already acts without the "
            f"agent model's dropout (a2c.act_dropout {config.a2c.act_dropout}; a model with "
            f"dropout: {config.model_has_dropout})"
        )
        return config
    notes.append("played without the agent model's dropout (--no-dropout); the run acted with it")
    return dataclasses.replace(config, a2c=dataclasses.replace(config.a2c, act_dropout=False))


@contextlib.contextmanager
def _locked(run_dir: Path, dest: Path, command: str) -> Iterator[Path]:
    """Hold the lock of where an evaluation writes (the run's top directory when it writes
    into the run, else ``dest``); yields the run's top directory (above ``seed_S/``)."""
    top = run_dir if (run_dir / "config.json").exists() else run_dir.parent
    lock = top if dest == run_dir else dest
    lock.mkdir(parents=True, exist_ok=True)
    with run_lock(lock, command):
        yield top


def _evaluate_locked(
    run_dir: Path,
    top: Path,
    dest: Path,
    config: TrainConfig,
    episodes: int,
    partners: str,
    checkpoint: str | int | None,
    seed: int,
    dropout: bool,
) -> dict[str, Any]:
    from transam.partners.learned import population_digest
    from transam.train.programs import env_and_model, program_key

    population = population_for(config.partners, partners)
    notes: list[str] = []
    w = restore_weights(config, run_dir, checkpoint, notes)

    eval_config = dataclasses.replace(_acting(config, dropout, notes), partners=population)
    env, model = env_and_model(eval_config)
    teams = env.population.team_names
    partner_ids = balanced_partners(episodes, env.num_partners)
    run = episodes_program(program_key(eval_config), episodes)
    ep = jax.device_get(
        run(w.policy_params, w.model_params, jax.random.key(seed), jnp.asarray(partner_ids))
    )
    reward = np.asarray(ep.reward, np.float64)
    live = np.asarray(ep.live, np.float64)
    labels = np.asarray(ep.partner)
    returns = reward.sum(0)

    if not (top / "final.json").exists() and not is_pretrained(run_dir):
        notes.append("the run has not finished training (no final.json)")
    if partners == "heldout" and config.partners != "default":
        notes.append(
            f"the run trained with partners={config.partners!r}; 'heldout' means the "
            f"{population!r} population here"
        )
    digest = population_digest(config.env, population)
    recorded = recorded_population(top)
    trained_digest = recorded["digest"] if recorded else None
    if partners == "train" and recorded and trained_digest != digest:
        notes.append(
            f"the run trained against population {trained_digest}; the shipped "
            f"{population!r} population is now {digest}: returns are not comparable with "
            "its training curve"
        )
    out: dict[str, Any] = {
        "env": config.env,
        "method": config.method,
        "seed": config.seed,
        "partners": partners,
        "population": population,
        "population_name": env.population.name,
        "trained_partners": config.partners,
        "population_digest": digest,
        "trained_population_digest": trained_digest,
        "checkpoint": w.source,
        "step": w.step,
        "episodes": episodes,
        "greedy": config.eval.greedy,
        "act_dropout": eval_config.acting_dropout,
        "return": {"mean": float(returns.mean()), "std": float(returns.std())},
        "returns": [float(r) for r in returns],  # per episode, to pair with other players
    }
    per_step: dict[str, Any] = {"cum_return": [float(v) for v in reward.cumsum(0).mean(1)]}
    for key in (*EVAL_METRICS, POLICY_ENTROPY, *INPUT_SIZES):
        if key in ep.scores:
            score = np.asarray(ep.scores[key], np.float64)
            out[key] = float(score.sum() / live.sum())
            per_step[key] = _per_step_mean(score, live)
    actions = np.asarray(ep.action)[live > 0]
    out["action_frequency"] = [
        float(f) for f in np.bincount(actions, minlength=env.spec.num_actions) / len(actions)
    ]
    out["per_partner_return"] = {
        teams[p]: float(returns[labels == p].mean()) for p in np.unique(labels)
    }
    out["per_step"] = per_step

    pca = None
    if not registry.method_entry(config.method).embedding:
        notes.append(f"{config.method} has no learned embedding: no probe or projection")
    else:
        z = np.asarray(ep.z, np.float64)
        out["probe"] = linear_probe(z, live, labels, seed)
        if model.privileged:
            out["probe"]["note"] = "privileged z: it contains the other agents' observations"
        last = live.sum(0).astype(int) - 1  # each episode's last step
        coords, ratio = pca_2d(z[last, np.arange(episodes)])
        out["pca"] = {"explained_variance": ratio}
        pca = (coords, last)
        buf = io.BytesIO()
        np.savez(
            buf,
            coords=coords.astype(np.float32),
            partner=labels,
            team_names=np.asarray(teams),
            explained_variance=np.asarray(ratio),
            t=last,
        )
        write_atomic(projection_path(dest, partners, dropout), buf.getvalue())
    out["notes"] = notes

    path = evaluation_path(dest, partners, dropout)
    write_json(path, out)
    write_atomic(path.with_suffix(".png"), evaluation_figure(out, teams, labels, pca))
    return out
