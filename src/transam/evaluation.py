"""``transam evaluate``: the final evaluation of a trained run, and what its embeddings encode.

:func:`evaluate_run` loads a checkpoint of a run directory and plays ``episodes`` episodes in
parallel (one per environment copy, one jitted program: the rollout of
:func:`transam.train.evaluate.make_episodes`, which training-time evaluation uses too). It
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
bidirectional window reveal older positions' answers (see :mod:`transam.train.evaluate`).

Representation quality. A linear probe predicts the partner index from the embedding z_t the
policy acted on at step t (TransAM's E^o_t; each baseline's own z), separately for every t:
episodes are split half/half, stratified by partner, with a fixed seed; features are
standardised with the training half's statistics; the probe is ridge regression on one-hot
partner targets (closed form, ``PROBE_RIDGE``), predicting the argmax. It is deterministic
and needs no iterative fitting. The projection is PCA of the embeddings at each episode's last
step. NAM has no learned embedding (its z is the one-hot previous action), so it gets neither;
the Oracle's z contains the other agents' observations (privileged), which the JSON notes.

JSON: ``env``, ``method``, ``seed``, ``partners`` ("train"|"heldout"|a population directory,
written to ``eval_pop-NAME.*``), ``population`` (the
partner choice it mapped to), ``population_name``, ``trained_partners``, ``population_digest``
and ``trained_population_digest`` (the shipped population's fingerprint now and the run's
partners.json's; None for scripted partners or runs older than that file), ``checkpoint`` (path
relative to the run directory: the named one, or the newest that verifies, any newer one that
does not being named in ``notes``), ``step``, ``episodes``, ``greedy``, ``return`` {mean, std},
the :data:`EVAL_METRICS` the model predicts, ``per_partner_return`` {team: mean},
``per_step`` {cum_return, and a curve per metric present},
``probe`` {accuracy, per_step, chance, train_episodes, test_episodes, features, ridge} and
``pca`` {explained_variance} (both absent without an embedding), ``notes`` [str].
"""

from __future__ import annotations

import dataclasses
import functools
import io
import json
import math
import re
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from transam import registry
from transam.models.base import ACC_ALL, ACC_NEWEST, MSE_ALL
from transam.train.config import ConfigError, TrainConfig, with_added_settings

EVAL_PARTNERS: tuple[str, ...] = ("train", "heldout")
EvalPartners = Annotated[str, tyro.conf.arg(metavar="{train,heldout}|DIR")]
"""``train``, ``heldout`` or a population directory (checked by :func:`population_for`)."""
PROBE_RIDGE = 1.0
"""Ridge penalty of the probe, on standardised features (unit variance each): small next to
the ~N/2 training episodes, so it only regularises directions the data barely constrain (with
embed_dim > N/2 the unpenalised least squares would interpolate the training half)."""
EVAL_METRICS = (ACC_NEWEST, ACC_ALL, "obs_mse", MSE_ALL)
"""The agent-modeling metrics an evaluation may hold (older files: ``action_accuracy``, the
newest position's, see :data:`~transam.models.base.LEGACY_METRICS`)."""


def evaluation_label(partners: str) -> str:
    """The name part of ``partners``' output files: ``train``, ``heldout``, or ``pop-NAME``
    for a population directory NAME (characters outside ``[A-Za-z0-9_.-]`` become ``_``)."""
    if partners in EVAL_PARTNERS:
        return partners
    return "pop-" + re.sub(r"[^A-Za-z0-9_.-]", "_", Path(partners).resolve().name)


def evaluation_path(run_dir: str | Path, partners: str) -> Path:
    """Where :func:`evaluate_run` writes its JSON (the figure and projection sit beside it)."""
    return Path(run_dir) / f"eval_{evaluation_label(partners)}.json"


# ---------------------------------------------------------------- the run directory


def _from_dict(cls: type, data: dict[str, Any], where: str) -> Any:
    """Rebuild a (nested) frozen dataclass from its ``asdict`` form; lists become tuples, so
    the result is hashable like the original."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(
            f"{where}: unknown setting(s) {', '.join(unknown)} for {cls.__name__}; "
            f"valid: {', '.join(sorted(names))}"
        )
    kwargs = {}
    for name, value in data.items():
        hint = hints[name]
        if dataclasses.is_dataclass(hint) and isinstance(value, dict):
            kwargs[name] = _from_dict(hint, value, where)  # type: ignore[arg-type]
        else:
            kwargs[name] = tuple(value) if isinstance(value, list) else value
    return cls(**kwargs)


def load_run_config(run_dir: str | Path) -> TrainConfig:
    """The TrainConfig of a single-seed run directory (``out`` set to it), or of one seed's
    ``seed_S`` subdirectory of a multi-seed run."""
    run_dir = Path(run_dir)
    path = run_dir / "config.json"
    seed = None
    if not path.exists():
        match = re.fullmatch(r"seed_(\d+)", run_dir.name)
        if match and (run_dir.parent / "config.json").exists():
            path, seed = run_dir.parent / "config.json", int(match.group(1))
        else:
            inside = sorted(str(c.parent) for c in run_dir.glob("*/config.json"))
            hint = f"; runs inside it: {', '.join(inside)}" if inside else ""
            raise ConfigError(f"{str(run_dir)!r} holds no transam run (no config.json){hint}")
    saved = with_added_settings(json.loads(path.read_text()))
    config: TrainConfig = _from_dict(TrainConfig, saved, str(path))
    if seed is not None:
        seeds = range(config.seed, config.seed + config.num_seeds)
        if config.num_seeds == 1 or seed not in seeds:
            raise ConfigError(
                f"{str(run_dir)!r} is not a seed of the run in {str(run_dir.parent)!r} "
                f"(its seeds: {', '.join(map(str, seeds))})"
            )
        config = dataclasses.replace(config, seed=seed, num_seeds=1)
    elif config.num_seeds > 1:
        subdirs = [str(run_dir / f"seed_{config.seed + i}") for i in range(config.num_seeds)]
        raise ConfigError(
            f"{str(run_dir)!r} holds {config.num_seeds} seeds; evaluate one seed directory: "
            f"{', '.join(subdirs)}"
        )
    return dataclasses.replace(config.validate(), out=str(run_dir), progress=False)


def find_checkpoint(run_dir: str | Path, checkpoint: str | int | None = None) -> Path:
    """The newest checkpoint of ``run_dir``, or the named one (a file name such as
    ``chunk_000003.msgpack``, with or without the suffix, or a chunk number). Not verified:
    :func:`evaluate_run` reads it (and falls back past a bad newest one)."""
    from transam.train.rundir import checkpoints

    found = checkpoints(Path(run_dir))
    names = ", ".join(p.name for _, p in sorted(found.items()))
    if not found:
        raise ConfigError(f"no checkpoints in {str(Path(run_dir) / 'checkpoints')!r}")
    if checkpoint is None:
        return found[max(found)]
    name = Path(str(checkpoint)).name.removesuffix(".msgpack").removeprefix("chunk_")
    if name.isdigit() and int(name) in found:
        return found[int(name)]
    raise ConfigError(f"checkpoint {checkpoint!r} not found in {str(run_dir)!r}; have: {names}")


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


# ---------------------------------------------------------------- probe and projection


def stratified_split(labels: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) episode indices: each class shuffled, the classes laid end to end and the
    positions dealt alternately to train and test, so each class (and the whole) splits in
    half to within one episode."""
    rng = np.random.default_rng(seed)
    classes = np.unique(labels)
    order = np.concatenate([rng.permutation(np.flatnonzero(labels == c)) for c in classes])
    return np.sort(order[0::2]), np.sort(order[1::2])


def probe_accuracy(
    x_train: np.ndarray,
    y_train: np.ndarray,
    x_test: np.ndarray,
    y_test: np.ndarray,
    ridge: float = PROBE_RIDGE,
) -> float:
    """Test accuracy of a ridge-regression probe on one-hot labels (features standardised with
    the training statistics; the intercept is the class frequencies, unpenalised)."""
    x_train, x_test = np.asarray(x_train, np.float64), np.asarray(x_test, np.float64)
    mean, std = x_train.mean(0), x_train.std(0)
    std = np.where(std > 1e-8, std, 1.0)
    a, b = (x_train - mean) / std, (x_test - mean) / std
    classes = np.unique(y_train)
    onehot = (y_train[:, None] == classes[None]).astype(np.float64)
    prior = onehot.mean(0)
    target = onehot - prior
    n, d = a.shape
    if d <= n:
        w = np.linalg.solve(a.T @ a + ridge * np.eye(d), a.T @ target)
    else:  # the dual form: an n x n system
        w = a.T @ np.linalg.solve(a @ a.T + ridge * np.eye(n), target)
    pred = classes[np.argmax(b @ w + prior, -1)]
    return float((pred == y_test).mean())


def linear_probe(z: np.ndarray, live: np.ndarray, labels: np.ndarray, seed: int) -> dict[str, Any]:
    """Probe the partner index from ``z`` [T, N, D] at each step t, over the episodes running
    at t (``live`` [T, N]); ``labels`` [N]."""
    train, test = stratified_split(labels, seed)
    per_step: list[float | None] = []
    for t in range(z.shape[0]):
        tr, te = train[live[t, train] > 0], test[live[t, test] > 0]
        if len(tr) == 0 or len(te) == 0:
            per_step.append(None)
            continue
        per_step.append(probe_accuracy(z[t, tr], labels[tr], z[t, te], labels[te]))
    scored = [a for a in per_step if a is not None]
    chance = np.bincount(labels[test]).max() / len(test) if len(test) else math.nan
    return {
        "accuracy": float(np.mean(scored)) if scored else None,
        "per_step": per_step,
        "chance": float(chance),
        "train_episodes": len(train),
        "test_episodes": len(test),
        "features": f"embedding z_t (dim {z.shape[-1]})",
        "ridge": PROBE_RIDGE,
    }


def pca_2d(x: np.ndarray) -> tuple[np.ndarray, list[float]]:
    """(coordinates [N, 2], fraction of the total variance each axis explains)."""
    x = np.asarray(x, np.float64)
    centered = x - x.mean(0)
    _, s, vt = np.linalg.svd(centered, full_matrices=False)
    coords = np.zeros((len(x), 2))
    k = min(2, vt.shape[0])
    coords[:, :k] = centered @ vt[:k].T
    var = s**2
    total = var.sum()
    ratio = [float(var[i] / total) if i < k and total > 0 else 0.0 for i in range(2)]
    return coords, ratio


# ---------------------------------------------------------------- the evaluation


@functools.lru_cache(maxsize=8)
def _program(config: TrainConfig, n: int) -> Callable[..., Any]:
    """The jitted rollout of ``n`` episodes (cached: a grid evaluates many runs of one
    program in one process)."""
    from transam.train.evaluate import make_episodes
    from transam.train.loop import env_and_model

    env, model = env_and_model(config)
    return jax.jit(make_episodes(config, env, model, n, positions=True))


def _restore(
    config: TrainConfig, run_dir: Path, checkpoint: str | int | None, notes: list[str]
) -> tuple[Path, Any]:
    """(path, RunnerState) of the named checkpoint, or of the newest one that verifies (each
    newer one that does not is reported and noted). The template is only shapes: nothing is
    compiled."""
    from transam.train.a2c import init_runner
    from transam.train.loop import env_and_model
    from transam.train.rundir import (
        CheckpointError,
        checkpoints,
        newest_good_checkpoint,
        read_checkpoint,
        warn,
    )

    env, model = env_and_model(config)
    template = jax.eval_shape(lambda k: init_runner(config, env, model, k), jax.random.key(0))
    path = find_checkpoint(run_dir, checkpoint)
    if checkpoint is not None:
        try:
            return path, read_checkpoint(path, template)
        except CheckpointError as err:
            raise ConfigError(f"{err}; choose another with --checkpoint") from None

    def report(message: str) -> None:
        warn(message)
        notes.append(message)

    found = newest_good_checkpoint([run_dir], template, report=report)
    if found is None:
        names = ", ".join(p.name for _, p in sorted(checkpoints(run_dir).items()))
        raise ConfigError(f"no checkpoint of {str(run_dir)!r} verifies (have: {names})")
    chunk, (state,) = found
    return checkpoints(run_dir)[chunk], state


def _per_step_mean(values: np.ndarray, live: np.ndarray) -> list[float | None]:
    count = live.sum(1)
    return [float(v / c) if c > 0 else None for v, c in zip(values.sum(1), count, strict=True)]


def evaluate_run(
    run_dir: str | Path,
    episodes: int = 100,
    partners: EvalPartners = "train",
    checkpoint: str | int | None = None,
    seed: int = 0,
) -> dict[str, Any]:
    """Evaluate a run's checkpoint on ``episodes`` episodes with its training partners or
    held-out ones; write eval_{partners}.json/.png/_pca.npz and return the JSON's contents.
    Holds the run's lock meanwhile; without ``checkpoint``, uses the newest checkpoint that
    verifies and notes each newer one that does not."""
    from transam.train.rundir import run_lock

    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 2:
        raise ConfigError(f"episodes must be an integer >= 2, got {episodes!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"seed must be an integer >= 0, got {seed!r}")
    run_dir = Path(run_dir)
    config = load_run_config(run_dir)
    population_for(config.partners, partners)  # checks ``partners``
    top = run_dir if (run_dir / "config.json").exists() else run_dir.parent
    with run_lock(top, "transam evaluate"):
        return _evaluate_locked(run_dir, top, config, episodes, partners, checkpoint, seed)


def _evaluate_locked(
    run_dir: Path,
    top: Path,
    config: TrainConfig,
    episodes: int,
    partners: EvalPartners,
    checkpoint: str | int | None,
    seed: int,
) -> dict[str, Any]:
    from transam.partners.learned import population_digest
    from transam.train.a2c import steps_per_update
    from transam.train.loop import (
        _program_key,
        env_and_model,
        recorded_population,
        write_atomic,
        write_json,
    )

    population = population_for(config.partners, partners)
    notes: list[str] = []
    ckpt, state = _restore(config, run_dir, checkpoint, notes)

    eval_config = dataclasses.replace(config, partners=population)
    env, model = env_and_model(eval_config)
    teams = env.population.team_names
    partner_ids = balanced_partners(episodes, env.num_partners)
    run = _program(_program_key(eval_config), episodes)
    ep = jax.device_get(
        run(state.policy_params, state.model_params, jax.random.key(seed), jnp.asarray(partner_ids))
    )
    reward = np.asarray(ep.reward, np.float64)
    live = np.asarray(ep.live, np.float64)
    labels = np.asarray(ep.partner)
    returns = reward.sum(0)

    if not (top / "final.json").exists():
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
        "checkpoint": ckpt.relative_to(run_dir).as_posix(),
        "step": int(state.update) * steps_per_update(config),
        "episodes": episodes,
        "greedy": config.eval.greedy,
        "return": {"mean": float(returns.mean()), "std": float(returns.std())},
    }
    per_step: dict[str, Any] = {"cum_return": [float(v) for v in reward.cumsum(0).mean(1)]}
    for key in EVAL_METRICS:
        if key in ep.scores:
            score = np.asarray(ep.scores[key], np.float64)
            out[key] = float(score.sum() / live.sum())
            per_step[key] = _per_step_mean(score, live)
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
        write_atomic(run_dir / f"eval_{evaluation_label(partners)}_pca.npz", buf.getvalue())
    out["notes"] = notes

    path = evaluation_path(run_dir, partners)
    write_json(path, out)
    write_atomic(path.with_suffix(".png"), _figure(out, teams, labels, pca))
    return out


# ---------------------------------------------------------------- figure


def _figure(
    result: dict[str, Any],
    teams: tuple[str, ...],
    labels: np.ndarray,
    pca: tuple[np.ndarray, np.ndarray] | None,
) -> bytes:
    """The PNG: per-step curves, probe accuracy and the projection (where present)."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    per = result["per_step"]
    curves = [("cum_return", "cumulative reward")]
    curves += [(ACC_NEWEST, "action accuracy, newest position")]
    curves += [(ACC_ALL, "action accuracy, all window positions")]
    curves += [("obs_mse", "observation MSE")]
    panels = [(k, label) for k, label in curves if k in per]
    if "probe" in result:
        panels.append(("probe", "partner probe accuracy"))
    if pca is not None:
        panels.append(("pca", "embeddings at the last step (PCA)"))
    cols = min(3, len(panels))
    rows = -(-len(panels) // cols)
    fig = Figure(figsize=(max(4.6 * cols, 6.0), 3.6 * rows + 0.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    steps = np.arange(len(per["cum_return"]))
    for ax, (key, label) in zip(axes, panels, strict=False):
        if key == "pca":
            assert pca is not None
            coords = pca[0]
            cmap = matplotlib.colormaps["tab20" if len(teams) > 10 else "tab10"]
            for p in np.unique(labels):
                sel = labels == p
                ax.scatter(*coords[sel].T, s=14, color=cmap(int(p) % cmap.N), label=teams[p])
            ev = result["pca"]["explained_variance"]
            ax.set_xlabel(f"PC1 ({100 * ev[0]:.0f}% var.)")
            ax.set_ylabel(f"PC2 ({100 * ev[1]:.0f}% var.)")
            ax.legend(
                fontsize=6,
                title="partner",
                title_fontsize=7,
                loc="center left",
                bbox_to_anchor=(1.0, 0.5),
                ncol=1 + len(teams) // 16,
            )
        elif key == "probe":
            probe = result["probe"]
            vals = [np.nan if v is None else v for v in probe["per_step"]]
            ax.plot(steps, vals, label="test accuracy")
            ax.axhline(probe["chance"], color="grey", ls="--", label="chance (majority)")
            ax.set_ylim(0.0, 1.02)
            ax.set_xlabel("step t in episode")
            ax.set_ylabel("accuracy")
            ax.legend(fontsize=7)
        else:
            vals = [np.nan if v is None else v for v in per[key]]
            ax.plot(steps, vals, label=result["method"])
            ax.set_xlabel("step t in episode")
            ax.set_ylabel(label)
            ax.legend(fontsize=7)
        ax.set_title(label, fontsize=9)
    for ax in axes[len(panels) :]:
        ax.set_visible(False)
    fig.suptitle(
        f"{result['env']} / {result['method']} seed {result['seed']}, step {result['step']:,}\n"
        f"{result['partners']} partners ({result['population_name']}), "
        f"{result['episodes']} episodes",
        fontsize=10,
    )
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


# ---------------------------------------------------------------- command line


@dataclass(frozen=True)
class Evaluate:
    """Evaluate a trained run: return, agent-modeling accuracy and their per-step curves, and a
    linear probe and projection of the embeddings (writes eval_PARTNERS.json/.png)."""

    run_dir: Annotated[str, tyro.conf.Positional]
    """run directory (one seed: a multi-seed run's seed_S subdirectory)"""
    episodes: int = 100
    """evaluation episodes (run in parallel; partner i mod M for episode i)"""
    partners: EvalPartners = "train"
    """the run's training partners, held-out ones it never met, or a population directory
    (manifest.json + default.safetensors; writes eval_pop-NAME.*)"""
    checkpoint: str | None = None
    """checkpoint file name or chunk number (default: the newest)"""
    seed: int = 0
    """PRNG seed of the episodes and of the probe's train/test split"""

    def run(self) -> None:
        from rich.console import Console
        from rich.table import Table

        from transam.jaxcache import enable_compilation_cache

        enable_compilation_cache()
        res = evaluate_run(self.run_dir, self.episodes, self.partners, self.checkpoint, self.seed)
        table = Table(
            title=f"{res['env']}/{res['method']} seed {res['seed']}, {res['checkpoint']} "
            f"(step {res['step']:,}), {res['episodes']} episodes, {res['population_name']}"
        )
        table.add_column("metric")
        table.add_column("value", justify="right")
        table.add_row("return", f"{res['return']['mean']:.4g} ± {res['return']['std']:.3g}")
        for key in EVAL_METRICS:
            if key in res:
                table.add_row(key.replace("_", " "), f"{res[key]:.4g}")
        if "probe" in res:
            acc = res["probe"]["accuracy"]
            table.add_row("partner probe accuracy", "-" if acc is None else f"{acc:.3f}")
            table.add_row("probe chance", f"{res['probe']['chance']:.3f}")
        console = Console()
        console.print(table)
        for note in res["notes"]:
            console.print(f"note: {note}")
        path = evaluation_path(self.run_dir, self.partners)
        console.print(f"wrote {path}, {path.with_suffix('.png')}")
        if "pca" in res:
            console.print(f"wrote {path.with_name(path.stem + '_pca.npz')}")
