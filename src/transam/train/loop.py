"""The training loop: the Python loop around the jitted chunks of a run (evaluation, metrics,
checkpoints, progress), in the run directory that :mod:`transam.rundir` lays out.

Determinism: every number in metrics.jsonl is computed inside jit from the runner state and
keys derived from the seed, so the same seed gives the same file, and a resumed run (restored
from the msgpack checkpoint, which includes RNG keys, optimiser states and the return
normaliser) gives the same file as an uninterrupted one. Wall-clock numbers (steps/s) go only to
TensorBoard and the console for that reason. On resume, metrics lines past the checkpoint are
dropped and recomputed.

Integrity (:mod:`transam.rundir`, :mod:`transam.train.stop`): a resume starts from the newest
checkpoint that verifies (each failing one is named on stderr); a second process on the same
``--out`` is refused; the first SIGINT/SIGTERM checkpoints at the end of the running chunk and
raises :class:`~transam.train.stop.RunInterrupted`. The jitted chunk flags any non-finite loss,
gradient norm or parameter (:func:`transam.train.a2c.nonfinite_check`); the loop then raises
:class:`NonFiniteError` before writing anything of that chunk, so the run keeps its last good
checkpoint and never gets a final.json. Vmapped seeds share one program, so a seed that
diverges stops its whole group (every diverged seed is named); its other seeds resume from
the same checkpoint with ``--seed-mode sequential`` after the diverged seed is dealt with.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from transam.compose import resolve_partners
from transam.models.base import ACC_NEWEST
from transam.rundir import (
    RunDirError,
    checkpoints,
    clean_run_dir,
    extend_run_dir,
    newest_good_checkpoint,
    prepare_run_dir,
    prune_checkpoints,
    read_final,
    read_metrics,
    run_lock,
    save_checkpoint,
    seed_dirs,
    start_run_dir,
    truncate_metrics,
    write_final,
)
from transam.train.a2c import HEALTH_KEYS, NONFINITE_QUANTITIES
from transam.train.config import ConfigError, TrainConfig
from transam.train.logs import TBWriter, make_record, mean_text, progress
from transam.train.programs import Plan, env_and_model, make_plan, run_programs
from transam.train.stop import RunInterrupted, StopRequest, stop_on_signals, wait_ready


@dataclass
class RunResult:
    """Where a run wrote its outputs and its final evaluation (one dict per seed)."""

    run_dir: Path
    seeds: list[int]
    final: list[dict[str, Any]]
    finished: bool


class NonFiniteError(RuntimeError):
    """A loss, gradient norm or parameter went non-finite; the run stopped before writing
    anything of that chunk (its last good checkpoint stays the newest)."""


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
        return RunResult(out, seeds, read_final(out), finished=True)
    with run_lock(out, "transam train" + (" --resume" if config.resume else "")):
        action = prepare_run_dir(config)  # again: now no other process writes here
        if action == "finished":
            return RunResult(out, seeds, read_final(out), finished=True)
        with stop_on_signals() as stop:
            return _train_locked(config, action, stop, stop_after_chunks)


def train_together(
    configs: list[TrainConfig], stop_after_chunks: int | None = None
) -> list[RunResult]:
    """Train one-seed runs that differ only in their seed and ``--out`` as one vmapped program
    (``transam reproduce --vmap-seeds``: a method's seeds), each run directory written as
    :func:`train` writes it alone (config.json, metrics, checkpoints, final.json), so the grid,
    ``--resume`` and the report see ordinary runs. Each resumes from its own checkpoints; runs
    at different chunks train as one group per starting chunk, the furthest first."""
    configs = [
        dataclasses.replace(c.validate(), partners=resolve_partners(c.partners)) for c in configs
    ]
    shared = {dataclasses.replace(c, seed=0, out="", resume=False, force=False) for c in configs}
    if len(shared) > 1 or any(c.num_seeds != 1 for c in configs):
        raise ConfigError("runs trained together must be one seed each and differ only in seed/out")
    env, _ = env_and_model(configs[0])
    plan = make_plan(configs[0], env.spec.episode_len)
    results: list[RunResult | None] = [None] * len(configs)
    with contextlib.ExitStack() as stack:
        todo = []
        for i, config in enumerate(configs):
            out = Path(config.run_dir)
            if prepare_run_dir(config) != "finished":
                stack.enter_context(run_lock(out, "transam reproduce --vmap-seeds"))
            action = prepare_run_dir(config)  # again: now no other process writes here
            if action == "finished":
                results[i] = RunResult(out, [config.seed], read_final(out), finished=True)
            else:
                _open_run_dir(config, action, env.spec.episode_len)
                todo.append(i)
        stop = stack.enter_context(stop_on_signals())
        start = {i: max(checkpoints(Path(configs[i].run_dir)), default=-1) for i in todo}
        budget = [stop_after_chunks]
        for chunk in sorted(set(start.values()), reverse=True):
            group = [i for i in todo if start[i] == chunk]
            if stop.signum:  # arrived during the last chunk of the previous group
                raise RunInterrupted(
                    stop.signum,
                    f"stopped by {stop.name} before seeds "
                    f"{', '.join(str(configs[i].seed) for i in group)} started; run the same "
                    "command again to resume",
                )
            dirs = [Path(configs[i].run_dir) for i in group]
            finals = _run_group(
                configs[group[0]], plan, [configs[i].seed for i in group], dirs, budget, stop
            )
            if finals is None:
                break
            for i, d, rec in zip(group, dirs, finals, strict=True):
                write_final(d, [rec])
                results[i] = RunResult(d, [configs[i].seed], [rec], finished=True)
    return [
        r or RunResult(Path(c.run_dir), [c.seed], [], finished=False)
        for r, c in zip(results, configs, strict=True)
    ]


def _open_run_dir(config: TrainConfig, action: str, episode_len: int) -> None:
    """Make a locked ``--out`` ready to train in as ``action`` (of prepare_run_dir) says."""
    out = Path(config.run_dir)
    if out.exists() and config.force:
        clean_run_dir(out)
    if action == "extend":
        _check_extension(config, episode_len)
        extend_run_dir(config)
    if action == "fresh" or not (out / "config.json").exists():
        start_run_dir(config)
    for d in seed_dirs(config):
        d.mkdir(parents=True, exist_ok=True)


def _train_locked(
    config: TrainConfig, action: str, stop: StopRequest, stop_after_chunks: int | None
) -> RunResult:
    out = Path(config.run_dir)
    seeds = [config.seed + i for i in range(config.num_seeds)]
    dirs = seed_dirs(config)
    env, _ = env_and_model(config)
    plan = make_plan(config, env.spec.episode_len)
    _open_run_dir(config, action, env.spec.episode_len)

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
        write_final(out, finals)
    return RunResult(out, seeds, finals, finished=done)


def _check_extension(config: TrainConfig, episode_len: int) -> None:
    """Refuse to continue a run whose last chunk its old length cut short: the longer run's
    chunks (its evaluation points) would not line up with those already done."""
    out = Path(config.run_dir)
    before = json.loads((out / "config.json").read_text())["total_steps"]
    old = make_plan(dataclasses.replace(config, total_steps=before), episode_len)
    if old.total_updates % old.updates_per_chunk:
        chunk = old.updates_per_chunk * old.steps_per_update
        raise RunDirError(
            f"--resume --total-steps {config.total_steps}: the run in {str(out)!r} ends with a "
            f"short chunk ({before} steps is not a multiple of its {chunk}-step evaluation "
            "interval), so a continued run would not be the run set for the larger length "
            "from the start; start over with --force"
        )


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
        truncate_metrics(d, start)
    if start >= len(chunks):
        return [read_metrics(d / "metrics.jsonl")[-1] for d in dirs]

    done_steps = sum(chunks[:start]) * plan.steps_per_update
    writers = [TBWriter(d / "tb", done_steps + 1 if start else None) for d in dirs]
    logs = [open(d / "metrics.jsonl", "a") for d in dirs]  # noqa: SIM115 (closed below)
    desc = f"{config.env}/{config.method} seed {','.join(map(str, seeds))}"
    last: list[dict[str, Any]] = []
    try:
        with progress(config.progress, plan.total_steps * len(seeds), desc) as advance:
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
                        prune_checkpoints(d, config.keep_checkpoints)
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
                    ret=mean_text([r["train/return"] for r in last]),
                    acc=mean_text([r.get(f"train/{ACC_NEWEST}") for r in last]),
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
