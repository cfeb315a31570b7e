"""The Python loop around the jitted chunks: run directory, logging, evaluation, checkpoints.

Run directory (``--out``)::

    config.json            the run's settings (written once, atomically)
    partners.json          which partner population it trains against (the choice or the
                           population directory's absolute path, and its digest)
    final.json             written last: the run is finished (its final evaluation per seed)
    metrics.jsonl          one JSON object per chunk (= per evaluation point)
    tb/                    TensorBoard event files (same scalars, plus steps/s)
    checkpoints/           chunk_NNNNNN.msgpack: the whole runner state and its SHA-256
                           (last two kept; one that fails verification becomes *.corrupt)
    .lock                  held (flock) by the one process training or evaluating the run

With ``--num-seeds n > 1`` the per-seed files (metrics.jsonl, tb/, checkpoints/) sit in
``seed_S/`` subdirectories and config.json / final.json at the top. Both seed modes write the
same layout, so a run can be resumed in either mode.

Determinism: every number in metrics.jsonl is computed inside jit from the runner state and
keys derived from the seed, so the same seed gives the same file, and a resumed run (restored
from the msgpack checkpoint, which includes RNG keys, optimiser states and the return
normaliser) gives the same file as an uninterrupted one. Wall-clock numbers (steps/s) go only to
TensorBoard and the console for that reason. On resume, metrics lines past the checkpoint are
dropped and recomputed.

Integrity (:mod:`transam.train.rundir`): a resume starts from the newest checkpoint that
verifies (each failing one is named on stderr); a second process on the same ``--out`` is
refused; the first SIGINT/SIGTERM checkpoints at the end of the running chunk and raises
:class:`~transam.train.rundir.RunInterrupted`. The jitted chunk flags any non-finite loss,
gradient norm or parameter (:func:`transam.train.a2c.nonfinite_check`); the loop then raises
:class:`NonFiniteError` before writing anything of that chunk, so the run keeps its last good
checkpoint and never gets a final.json. Vmapped seeds share one program, so a seed that
diverges stops its whole group (every diverged seed is named); its other seeds resume from
the same checkpoint with ``--seed-mode sequential`` after the diverged seed is dealt with.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from transam.compose import make_env, partner_choices, resolve_partners
from transam.envs.core import ControlledEnv
from transam.models import make_model
from transam.models.base import ACC_NEWEST, AgentModel
from transam.train.a2c import (
    HEALTH_KEYS,
    NONFINITE_QUANTITIES,
    RunnerState,
    anneal_updates,
    init_runner,
    make_chunk,
    steps_per_update,
    total_updates,
)
from transam.train.config import ConfigError, TrainConfig, with_added_settings
from transam.train.evaluate import make_evaluate
from transam.train.rundir import (
    LOCK_FILE,
    RunInterrupted,
    StopRequest,
    checkpoints,
    newest_good_checkpoint,
    prune_checkpoints,
    run_lock,
    save_checkpoint,
    stop_on_signals,
    wait_ready,
    write_atomic,
    write_json,
)

POPULATION_FILE = "partners.json"
OWN_ENTRIES = ("config.json", POPULATION_FILE, "final.json", "metrics.jsonl", "tb", "checkpoints")


@dataclass(frozen=True)
class Plan:
    """How a run splits into jitted chunks (one chunk per evaluation interval)."""

    steps_per_update: int
    total_updates: int
    updates_per_chunk: int

    @property
    def chunks(self) -> list[int]:
        """Updates in each chunk (the last may be shorter)."""
        full, rest = divmod(self.total_updates, self.updates_per_chunk)
        return [self.updates_per_chunk] * full + ([rest] if rest else [])

    @property
    def total_steps(self) -> int:
        return self.total_updates * self.steps_per_update


def make_plan(config: TrainConfig, episode_len: int) -> Plan:
    """Chunks of whole collections (``a2c.rollouts_per_collect`` updates each)."""
    per_update = steps_per_update(config)
    per = config.a2c.rollouts_per_collect
    every = round(config.eval.every_episodes * episode_len / (per_update * per)) * per
    return Plan(per_update, total_updates(config), max(per, every))


@dataclass
class RunResult:
    """Where a run wrote its outputs and its final evaluation (one dict per seed)."""

    run_dir: Path
    seeds: list[int]
    final: list[dict[str, Any]]
    finished: bool


# ---------------------------------------------------------------- building blocks (cached)


@functools.lru_cache(maxsize=8)
def env_and_model(config: TrainConfig) -> tuple[ControlledEnv, AgentModel]:
    e = make_env(config.env, partners=config.partners)
    return e, make_model(config.method, e.spec, config.model, config.baseline)


def anneal_by_run(config: TrainConfig) -> bool:
    """Whether the learning-rate schedule depends on the run length."""
    return config.a2c.anneal_lr and not config.a2c.anneal_steps


def _program_key(config: TrainConfig) -> TrainConfig:
    """The part of the config a compiled program depends on (not the seed or the paths; the
    run length only through the learning-rate schedule)."""
    return dataclasses.replace(
        config,
        total_steps=config.total_steps if anneal_by_run(config) else 1,
        seed=0,
        num_seeds=1,
        seed_mode="vmap",
        out="",
        resume=False,
        force=False,
        progress=False,
        checkpoint_every=1,
    )


@dataclass(frozen=True)
class Programs:
    init: Callable[[jax.Array], RunnerState]  # one seed
    chunks: dict[int, Callable[[RunnerState], tuple[RunnerState, dict[str, jax.Array]]]]
    evaluate: Callable[[Any, Any, jax.Array], dict[str, jax.Array]]


@functools.lru_cache(maxsize=8)
def programs(config: TrainConfig, sizes: tuple[int, ...], vmapped: bool) -> Programs:
    """Jitted init (one seed), chunk (one per chunk size) and evaluation functions, the latter
    vmapped over a leading seed axis when ``vmapped``. Cached so repeated runs in one process
    compile once."""
    env, model = env_and_model(config)

    def init(key: jax.Array) -> RunnerState:
        return init_runner(config, env, model, key)

    evaluate = make_evaluate(config, env, model)
    chunks = {u: make_chunk(config, env, model, u) for u in sizes}
    if vmapped:  # init stays per seed: vmapped orthogonal inits (batched QR) hang XLA:CPU
        evaluate = jax.vmap(evaluate)
        chunks = {u: jax.vmap(f) for u, f in chunks.items()}
    return Programs(
        init=jax.jit(init),
        chunks={u: jax.jit(f) for u, f in chunks.items()},
        evaluate=jax.jit(evaluate),
    )


def run_programs(config: TrainConfig, vmapped: bool = False) -> Programs:
    """The compiled programs a run of ``config`` uses (shared with :func:`train`'s cache)."""
    env, _ = env_and_model(config)
    chunks = make_plan(config, env.spec.episode_len).chunks
    return programs(_program_key(config), tuple(sorted(set(chunks))), vmapped)


# ---------------------------------------------------------------- files


def read_metrics(path: Path) -> list[dict[str, Any]]:
    """The records of a metrics.jsonl (a torn last line from a kill is skipped)."""
    if not path.exists():
        return []
    records = []
    for line in path.read_text().splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records


class RunDirError(ConfigError):
    """The run directory holds something that the requested action would overwrite."""


class NonFiniteError(RuntimeError):
    """A loss, gradient norm or parameter went non-finite; the run stopped before writing
    anything of that chunk (its last good checkpoint stays the newest)."""


def prepare_run_dir(config: TrainConfig) -> str:
    """Decide what to do with ``--out`` before writing anything: 'fresh', 'resume' or
    'finished'. Raises :class:`RunDirError` when it would overwrite a run without --force."""
    out = Path(config.run_dir)
    if out.exists() and not out.is_dir():
        raise RunDirError(f"--out {str(out)!r} exists and is not a directory")
    entries = {p.name for p in out.iterdir()} - {LOCK_FILE} if out.exists() else set()
    if not entries and config.resume and not config.force:
        raise RunDirError(
            f"--resume: no run in --out {str(out)!r} to continue; drop --resume to start one"
        )
    if not entries:
        return "fresh"
    if "config.json" not in entries:
        raise RunDirError(
            f"--out {str(out)!r} is not empty and holds no transam run; choose another directory"
        )
    finished = "final.json" in entries
    if config.force:
        return "fresh"
    if not config.resume:
        what = "a finished run" if finished else "an unfinished run"
        hint = "" if finished else " --resume to continue it, or"
        raise RunDirError(
            f"--out {str(out)!r} holds {what}; pass{hint} --force to delete it and start over"
        )
    saved = with_added_settings(json.loads((out / "config.json").read_text()))
    wanted = json.loads(json.dumps(config.identity()))
    if saved != wanted:
        diff = sorted(_diff(saved, wanted))
        raise RunDirError(
            f"--resume: settings differ from the run in {str(out)!r}: {', '.join(diff)} "
            "(resume with the same settings, or --force to start over)"
        )
    if not finished:
        _check_population(out, config)
    return "finished" if finished else "resume"


def population_record(config: TrainConfig) -> dict[str, Any]:
    """What partners.json says: the environment, the partner choice and the population's
    digest (None for the scripted population)."""
    from transam.partners.learned import population_digest

    digest = population_digest(config.env, config.partners)
    return {"env": config.env, "partners": config.partners, "digest": digest}


def recorded_population(out: Path) -> dict[str, Any] | None:
    """The run's partners.json, or None for a run written before that file existed (nothing
    says which population it used)."""
    path = out / POPULATION_FILE
    return json.loads(path.read_text()) if path.exists() else None


def _check_population(out: Path, config: TrainConfig) -> None:
    """Refuse to resume against a different shipped population than the run started with."""
    recorded = recorded_population(out)
    if recorded is None:
        return
    was, now = recorded["digest"], population_record(config)["digest"]
    shipped = config.partners in partner_choices(config.env)
    how = "the transam version it started with" if shipped else "the directory as it was"
    if was != now:
        raise RunDirError(
            f"--resume: the {config.env} partner population {config.partners!r} "
            f"changed since the run in {str(out)!r} started (run: {was}, now: {now}); finish "
            f"it with {how}, or --force to start over"
        )


def _diff(a: Any, b: Any, prefix: str = "") -> Iterator[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            yield from _diff(a.get(k), b.get(k), f"{prefix}{k}.")
    elif a != b:
        name = prefix.rstrip(".")
        yield f"{name} (run: {a!r}, now: {b!r}; the run's flag: {_flag(name, a)})"


def _flag(name: str, value: Any) -> str:
    """The command-line flag that sets setting ``name`` (e.g. 'a2c.time_feature') to ``value``."""
    group, _, leaf = name.rpartition(".")
    if value is False:
        leaf = f"no_{leaf}"  # tyro's negated boolean flag
    flag = "--" + ".".join(filter(None, (group, leaf))).replace("_", "-")
    return flag if isinstance(value, bool) else f"{flag} {value}"


def _clean(out: Path) -> None:
    """Delete what a previous run wrote (and nothing else) in ``out``."""
    for p in out.iterdir():
        if p.name in OWN_ENTRIES or (p.is_dir() and p.name.startswith("seed_")):
            shutil.rmtree(p) if p.is_dir() else p.unlink()


# ---------------------------------------------------------------- logging


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
    for k in ("return", "return_std", ACC_NEWEST, "obs_mse"):
        if k in evaluation:  # a method without a decoder has no accuracy / MSE: absent, not 0
            rec[f"eval/{k}"] = _clean_float(evaluation[k])
    return rec


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
def _progress(enabled: bool, total: int, description: str) -> Iterator[Callable[..., None]]:
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


def _fmt(values: list[Any]) -> str:
    vals = [v for v in values if v is not None]
    return f"{np.mean(vals):.4g}" if vals else "-"


# ---------------------------------------------------------------- the run


def seed_dirs(config: TrainConfig) -> list[Path]:
    out = Path(config.run_dir)
    seeds = [config.seed + i for i in range(config.num_seeds)]
    return [out] if config.num_seeds == 1 else [out / f"seed_{s}" for s in seeds]


def train(config: TrainConfig, stop_after_chunks: int | None = None) -> RunResult:
    """Run (or resume) training as ``config`` says. ``stop_after_chunks`` stops early, as a kill
    would, after that many chunks of this invocation (for tests)."""
    config.validate()
    # A population directory is recorded (config.json, partners.json) as an absolute path.
    config = dataclasses.replace(config, partners=resolve_partners(config.partners))
    env_and_model(config)  # bad env/model: fail before writing
    action = prepare_run_dir(config)
    out = Path(config.run_dir)
    seeds = [config.seed + i for i in range(config.num_seeds)]
    if action == "finished":
        final = json.loads((out / "final.json").read_text())
        return RunResult(out, seeds, final["seeds"], finished=True)
    with run_lock(out, "transam train" + (" --resume" if config.resume else "")):
        action = prepare_run_dir(config)  # again: now no other process writes here
        if action == "finished":
            final = json.loads((out / "final.json").read_text())
            return RunResult(out, seeds, final["seeds"], finished=True)
        with stop_on_signals() as stop:
            return _train_locked(config, action, stop, stop_after_chunks)


def _train_locked(
    config: TrainConfig, action: str, stop: StopRequest, stop_after_chunks: int | None
) -> RunResult:
    out = Path(config.run_dir)
    seeds = [config.seed + i for i in range(config.num_seeds)]
    dirs = seed_dirs(config)
    if out.exists() and config.force:
        _clean(out)
    if action == "fresh" or not (out / "config.json").exists():
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "config.json", config.identity())
        write_json(out / POPULATION_FILE, population_record(config))
    for d in dirs:
        d.mkdir(parents=True, exist_ok=True)

    env, _ = env_and_model(config)
    plan = make_plan(config, env.spec.episode_len)
    groups = [list(range(len(seeds)))]
    if config.seed_mode == "sequential" and len(seeds) > 1:
        groups = [[i] for i in range(len(seeds))]
    budget = [stop_after_chunks]
    finals: list[dict[str, Any]] = [{} for _ in seeds]
    done = True
    for group in groups:
        if stop.signum:  # arrived during the last chunk of the previous group
            raise RunInterrupted(
                stop.signum,
                f"stopped by {stop.name} before seed {seeds[group[0]]} started; "
                f"resume with --resume --out {out} (same settings)",
            )
        finished = _run_group(
            config, plan, [seeds[i] for i in group], [dirs[i] for i in group], budget, stop
        )
        done &= finished is not None
        if finished is not None:
            for i, rec in zip(group, finished, strict=True):
                finals[i] = rec
        else:
            break
    if done:
        write_json(out / "final.json", {"seeds": finals})
    return RunResult(out, seeds, finals, finished=done)


def uniform_policy_eval(config: TrainConfig, seed: int, chunk: int) -> dict[str, float]:
    """What a uniformly random controlled agent scores on the evaluation episodes of chunk
    ``chunk`` (0-based) of seed ``seed``: the run's own "random" reference (actor zeroed, so
    all logits are equal; same partners, same starts)."""
    progs = run_programs(config)
    init_key, eval_key = jax.random.split(jax.random.key(seed))
    state = progs.init(init_key)
    params = jax.tree.map(jnp.zeros_like, state.policy_params)
    out = progs.evaluate(params, state.model_params, jax.random.fold_in(eval_key, chunk))
    return {k: float(v) for k, v in out.items() if not k.startswith("per_step/")}


def _run_group(
    config: TrainConfig,
    plan: Plan,
    seeds: list[int],
    dirs: list[Path],
    budget: list[int | None],
    stop: StopRequest,
) -> list[dict[str, Any]] | None:
    """Train seeds together (vmapped when several); the final records, or None when stopped
    by ``budget``. Raises :class:`NonFiniteError` or, on a stop request, checkpoints and
    raises :class:`RunInterrupted`."""
    chunks = plan.chunks
    vmapped = len(seeds) > 1
    progs = run_programs(config, vmapped)

    def stack(trees: list[Any]) -> Any:
        return jax.tree.map(lambda *a: jnp.stack(a), *trees) if vmapped else trees[0]

    def unstack(tree: Any) -> list[Any]:
        if not vmapped:
            return [tree]
        return [jax.tree.map(lambda a, i=i: a[i], tree) for i in range(len(seeds))]

    init_keys, eval_keys = zip(*(jax.random.split(jax.random.key(s)) for s in seeds), strict=True)
    state = stack([progs.init(k) for k in init_keys])

    # Resume from the newest chunk checkpointed, and verified, for every seed of the group.
    start = 0
    if any(checkpoints(d) for d in dirs):
        template = unstack(jax.device_get(state))[0]
        found = newest_good_checkpoint(dirs, template, quarantine=True)
        if found is not None:
            start, states = found[0] + 1, found[1]
            state = stack(states)
    for d in dirs:
        kept = [r for r in read_metrics(d / "metrics.jsonl") if r.get("chunk", -1) < start]
        write_atomic(d / "metrics.jsonl", "".join(json.dumps(r) + "\n" for r in kept).encode())
    if start >= len(chunks):
        return [read_metrics(d / "metrics.jsonl")[-1] for d in dirs]

    done_steps = sum(chunks[:start]) * plan.steps_per_update
    writers = [TBWriter(d / "tb", done_steps + 1 if start else None) for d in dirs]
    logs = [open(d / "metrics.jsonl", "a") for d in dirs]  # noqa: SIM115 (closed below)
    desc = f"{config.env}/{config.method} seed {','.join(map(str, seeds))}"
    last: list[dict[str, Any]] = []
    try:
        with _progress(config.progress, plan.total_steps * len(seeds), desc) as advance:
            advance(done_steps * len(seeds))
            for c in range(start, len(chunks)):
                if budget[0] is not None:
                    if budget[0] <= 0:
                        return None
                    budget[0] -= 1
                tic = time.perf_counter()
                state, train_metrics = progs.chunks[chunks[c]](state)
                wait_ready((state, train_metrics))
                health = jax.device_get({k: train_metrics.pop(k) for k in HEALTH_KEYS})
                seconds = time.perf_counter() - tic
                diverged = _nonfinite_message(health, seeds, c, plan, dirs)
                if diverged:
                    raise NonFiniteError(diverged)
                ek = stack([jax.random.fold_in(k, c) for k in eval_keys])
                ev = progs.evaluate(state.policy_params, state.model_params, ek)
                wait_ready(ev)
                counts = jax.device_get((state.update, state.episodes, train_metrics, ev))
                steps = chunks[c] * plan.steps_per_update
                last = []
                for i, (upd, eps, tm, em) in enumerate(
                    zip(*(unstack(x) for x in counts), strict=True)
                ):
                    rec = make_record(c, seeds[i], int(upd), int(eps), tm, em, plan, config)
                    logs[i].write(json.dumps(rec) + "\n")
                    logs[i].flush()
                    writers[i].write(rec, {"perf/steps_per_s": steps / seconds})
                    last.append(rec)
                interrupted = stop.signum is not None and c + 1 < len(chunks)
                every = (c + 1) % config.checkpoint_every == 0 or c + 1 == len(chunks)
                if every or interrupted:
                    for d, s in zip(dirs, unstack(jax.device_get(state)), strict=True):
                        saved = save_checkpoint(d, c, s)
                    for d in dirs:
                        prune_checkpoints(d)
                if interrupted:
                    raise RunInterrupted(
                        stop.signum or 0,
                        f"stopped by {stop.name} after chunk {c} of {len(chunks)} "
                        f"(step {int(last[0]['step']):,}); checkpoint {saved} saved. Resume "
                        f"with the same settings and --resume --out {Path(config.run_dir)}",
                    )
                advance(
                    steps * len(seeds),
                    sps=f"{steps * len(seeds) / seconds:,.0f}",
                    ret=_fmt([r["train/return"] for r in last]),
                    acc=_fmt([r.get(f"train/{ACC_NEWEST}") for r in last]),
                )
    finally:
        for f in logs:
            f.close()
        for w in writers:
            w.close()
    return last


def _nonfinite_message(
    health: dict[str, Any], seeds: list[int], chunk: int, plan: Plan, dirs: list[Path]
) -> str | None:
    """What went non-finite in this chunk, for which seeds (None when nothing did)."""
    flags = np.asarray(health["nonfinite"]).reshape(len(seeds), -1)
    updates = np.asarray(health["nonfinite_update"]).reshape(len(seeds))
    parts = []
    for seed, f, u in zip(seeds, flags, updates, strict=True):
        if f.any():
            names = ", ".join(q for q, b in zip(NONFINITE_QUANTITIES, f, strict=True) if b)
            parts.append(
                f"seed {seed}: non-finite {names} at update {int(u):,} "
                f"(step {int(u) * plan.steps_per_update:,})"
            )
    if not parts:
        return None
    kept = [str(p[max(p)]) for p in map(checkpoints, dirs) if p]
    last = f"its last good checkpoint: {', '.join(kept)}" if kept else "no checkpoint yet"
    return (
        f"training diverged in chunk {chunk}: {'; '.join(parts)}. The run stopped without "
        f"writing anything of that chunk ({last}). The same settings diverge again on resume "
        "(runs are deterministic): change the setting that caused it (e.g. a lower "
        "--a2c.lr) and start over with --force"
    )


def policy_lr(config: TrainConfig, update: int) -> float:
    """The policy learning rate used by update number ``update`` (0-based), as the optimiser's
    linear schedule computes it (for logging)."""
    a = config.a2c
    if not a.anneal_lr:
        return a.lr
    n = anneal_updates(config)
    return a.lr * (1.0 - min(max(update, 0), n) / n)
