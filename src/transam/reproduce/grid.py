"""The reproduction grid: every (environment, method, seed) run of a budget, each an ordinary
``transam train`` run directory, followed by its final evaluations.

Layout of ``--out`` (the same whichever backend ran the runs)::

    grid.json                          the grid: budget, its settings, runs, invocations
    runs/ENV/METHOD/seed_S/            one training run (config.json, metrics.jsonl, ...),
        eval_train.json, eval_heldout.json   ... plus `transam evaluate` outputs
    log/ENV_METHOD_seed_S.jsonl        one line per launch of that run (pid, host, start chunk)
    report/                            `transam report` output

:func:`run_one` is idempotent and is the whole unit of work a backend schedules: it skips a
finished run, resumes an interrupted one from its last checkpoint, and evaluates what has not
been evaluated. A backend therefore only has to call it (again, after a failure) for every run.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import platform
import signal
import socket
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from transam import registry
from transam.train.config import ConfigError, EvalConfig, TrainConfig
from transam.train.presets import apply_settings

BudgetName = Literal["smoke", "small", "medium", "paper"]


@dataclass(frozen=True)
class Budget:
    """How long each run trains and how it is evaluated."""

    total_steps: int
    """controlled-agent steps per run, summed over parallel envs"""
    seeds: int
    """seeds per (env, method) when --seeds is not given"""
    evals: int
    """evaluation points during training (evenly spaced; also the checkpoint interval)"""
    eval_episodes: int
    """episodes per evaluation during training"""
    final_episodes: int
    """episodes of the final `transam evaluate` (training and held-out partners)"""


BUDGETS: dict[str, Budget] = {
    # Minutes: a test runs it end to end (every artefact, no learning expected).
    # (26 final episodes: two per partner team of Spread, the probe's minimum.)
    "smoke": Budget(total_steps=1_000, seeds=2, evals=2, eval_episodes=8, final_episodes=26),
    # What fits about an hour on a 2-core CPU for all 4 envs x 10 methods (docs/results/).
    "small": Budget(total_steps=30_000, seeds=2, evals=6, eval_episodes=16, final_episodes=100),
    # One environment x 10 methods x 3 seeds in about a working day on a 2-core CPU
    # (--envs spread): the 15 transformer runs dominate at about 1,000 env-steps/s each
    # (docs/performance.md), 4-5 h; the 15 recurrent ones add well under an hour.
    "medium": Budget(
        total_steps=1_000_000, seeds=3, evals=40, eval_episodes=100, final_episodes=500
    ),
    # The paper: 10M steps, 5 seeds.
    "paper": Budget(
        total_steps=10_000_000, seeds=5, evals=100, eval_episodes=100, final_episodes=100
    ),
}


@dataclass(frozen=True)
class RunSpec:
    """One cell of the grid."""

    env: str
    method: str
    seed: int

    @property
    def rel(self) -> str:
        """The run directory, relative to the grid's --out."""
        return f"runs/{self.env}/{self.method}/seed_{self.seed}"

    @property
    def name(self) -> str:
        return f"{self.env}_{self.method}_seed_{self.seed}"


def grid_specs(envs: Sequence[str], methods: Sequence[str], seeds: Sequence[int]) -> list[RunSpec]:
    """The runs of a grid in a fixed order (env, method, seed), after checking the names."""
    for what, values, valid in (
        ("env", envs, registry.env_names()),
        ("method", methods, registry.method_names()),
    ):
        for v in values:
            if v not in valid:
                raise ConfigError(f"unknown {what} {v!r}; valid choices: {', '.join(valid)}")
    if not envs or not methods or not seeds:
        raise ConfigError("the grid is empty: give at least one env, method and seed")
    if any(s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise ConfigError(f"seeds must be distinct integers >= 0, got {list(seeds)}")
    return [RunSpec(e, m, s) for e in envs for m in methods for s in seeds]


def run_config(
    spec: RunSpec,
    budget: Budget,
    out: str | Path,
    partners: str = "default",
    settings: dict[str, Any] | None = None,
) -> TrainConfig:
    """The training configuration of one grid run: the default settings with the grid's own
    (``transam reproduce --set``), plus the budget, against the grid's partner population."""

    # the registry's episode length: a grid is planned without building environments
    episode_len = registry.env_entry(spec.env).episode_len
    every = max(1, round(budget.total_steps / (budget.evals * episode_len)))
    config = TrainConfig(
        env=spec.env,  # type: ignore[arg-type]
        method=spec.method,  # type: ignore[arg-type]
        partners=partners,
        total_steps=budget.total_steps,
        seed=spec.seed,
        out=str(Path(out) / spec.rel),
        progress=False,
        eval=EvalConfig(every_episodes=every, episodes=budget.eval_episodes),
    )
    return apply_settings(config, settings or {}).validate()


def _log(out: Path, spec: RunSpec, event: dict[str, Any]) -> None:
    """Append one launch event (a line is small: appends are atomic enough on a local or NFS
    filesystem, and a torn line is skipped by readers)."""
    path = out / "log" / f"{spec.name}.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as f:
        f.write(json.dumps(event) + "\n")


def read_launches(out: str | Path, spec: RunSpec) -> list[dict[str, Any]]:
    """The launch events of one run (see :func:`run_one`)."""
    from transam.rundir import read_metrics

    return read_metrics(Path(out) / "log" / f"{spec.name}.jsonl")


def run_one(out: str | Path, spec: RunSpec, budget: Budget) -> dict[str, Any]:
    """Train (or resume, or skip) one grid run, then evaluate it on the training and held-out
    partners where not done yet at the budget's final episode count. Safe to call again after
    any failure; returns a summary."""
    return run_together(out, [spec], budget)[0]


def run_together(out: str | Path, specs: list[RunSpec], budget: Budget) -> list[dict[str, Any]]:
    """:func:`run_one` for runs of one (env, method) whose seeds train as one vmapped program
    (``--vmap-seeds``; :func:`transam.train.loop.train_together`: each run directory as if
    trained alone, its launch event naming the seeds it trained with). Returns the summaries."""
    from transam.evaluation.final import evaluate_run
    from transam.rundir import EVAL_PARTNERS, checkpoints, evaluation_path
    from transam.train.loop import train, train_together

    out = Path(out)
    partners, settings = grid_partners(out), grid_settings(out)
    configs = [run_config(spec, budget, out, partners, settings) for spec in specs]
    tic = time.time()
    todo = [
        (s, c)
        for s, c in zip(specs, configs, strict=True)
        if not (Path(c.run_dir) / "final.json").exists()
    ]
    resumed = []
    for spec, config in todo:
        run_dir = Path(config.run_dir)
        started = (run_dir / "config.json").exists()
        resumed.append(dataclasses.replace(config, resume=started))
        event: dict[str, Any] = {
            "event": "train",
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "start_chunk": max(checkpoints(run_dir), default=-1) + 1 if started else 0,
            "resume": started,
            "time": tic,
        }
        if len(todo) > 1:
            event["vmapped_with"] = [s.seed for s, _ in todo]
        _log(out, spec, event)
    results = train_together(resumed) if len(resumed) > 1 else [train(c) for c in resumed]
    for (spec, _), result in zip(todo, results, strict=True):
        if not result.finished:  # pragma: no cover (only a stop_after_chunks test stops early)
            raise RuntimeError(f"{spec.name}: training stopped before the end")
    summaries = []
    for spec, config in zip(specs, configs, strict=True):
        run_dir = Path(config.run_dir)
        evaluated = []
        for partners in EVAL_PARTNERS:
            path = evaluation_path(run_dir, partners)
            if (
                not path.exists()
                or json.loads(path.read_text())["episodes"] != budget.final_episodes
            ):
                evaluate_run(run_dir, episodes=budget.final_episodes, partners=partners)
                evaluated.append(partners)
        trained = any(spec == s for s, _ in todo)
        if trained or evaluated:
            _log(out, spec, {"event": "done", "pid": os.getpid(), "seconds": time.time() - tic})
        summaries.append({"run": spec.rel, "trained": trained, "evaluated": evaluated})
    return summaries


ARCHIVE_SKIP = ("checkpoints", "tb", "*.png", "*.lock", "*.tmp")
"""What :func:`archive_grid` leaves out of a run: what training and the figures need, not the
report."""


def archive_grid(out: str | Path, dest: str | Path, carry: bool = False) -> list[str]:
    """Copy grid.json, log/ and every finished run (trained, and evaluated on each of
    EVAL_PARTNERS) of the grid in ``out`` into ``dest`` without checkpoints, TensorBoard files
    and figures: what the report reads, about 60 KB a run, so that a study that takes
    several sessions outlives a machine that does not keep runs/. Copied back, :func:`run_one`
    skips those runs. Unfinished runs are left out (without their checkpoints they could
    neither resume nor be evaluated), unless ``carry``: then each unfinished run that has a
    checkpoint is copied with its newest one only, so that, copied back, it resumes there (a
    run longer than a machine lasts; a TransAM checkpoint is about 8 MB). A run that finished
    since loses the checkpoint an earlier carry left in ``dest``. Returns the runs copied
    (relative paths; carried ones end in " (carried)")."""
    import shutil

    from transam.rundir import EVAL_PARTNERS, checkpoints, evaluation_path

    out, dest = Path(out), Path(dest)
    if not (out / "grid.json").exists():
        raise ConfigError(f"{str(out)!r} holds no grid.json: pass a `transam reproduce --out`")
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copy2(out / "grid.json", dest / "grid.json")
    if (out / "log").is_dir():
        shutil.copytree(out / "log", dest / "log", dirs_exist_ok=True)
    skip = shutil.ignore_patterns(*ARCHIVE_SKIP)
    copied = []
    for config in sorted(out.glob("runs/*/*/seed_*/config.json")):
        run = config.parent
        rel = run.relative_to(out)
        finished = (run / "final.json").exists() and all(
            evaluation_path(run, p).exists() for p in EVAL_PARTNERS
        )
        saved = checkpoints(run)
        if finished:
            shutil.copytree(run, dest / rel, ignore=skip, dirs_exist_ok=True)
            shutil.rmtree(dest / rel / "checkpoints", ignore_errors=True)
            copied.append(str(rel))
        elif carry and saved:
            shutil.rmtree(dest / rel, ignore_errors=True)  # no stale evaluation or checkpoint
            shutil.copytree(run, dest / rel, ignore=skip)
            (dest / rel / "checkpoints").mkdir()
            newest = saved[max(saved)]
            shutil.copy2(newest, dest / rel / "checkpoints" / newest.name)
            copied.append(f"{rel} (carried)")
    return copied


# ---------------------------------------------------------------- the grid file


# The instruction sets XLA's CPU code generation chooses kernels by: two machines with the
# same kernel label but different sets can give runs that differ in the last bits.
_ISA_FLAGS = ("avx2", "fma", "avx512f", "avx512_bf16", "avx512_fp16", "avx_vnni", "amx_tile")


def cpu_description(cpuinfo: str) -> dict[str, Any]:
    """The CPU of a ``/proc/cpuinfo`` text: model name, family/model/stepping, ISA flags.

    A hypervisor often masks the model name ("Intel(R) Xeon(R) Processor"); the numbers
    and the flags still tell machines apart.
    """
    first: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        if not line.strip():
            if first:
                break  # the first processor's block is enough
            continue
        key, _, value = line.partition(":")
        first[key.strip()] = value.strip()
    if not first:
        return {}
    flags = set(first.get("flags", "").split())
    ident = "/".join(first.get(k, "?") for k in ("cpu family", "model", "stepping"))
    return {
        "cpu": f"{first.get('model name', '?')} (family/model/stepping {ident})",
        "cpu_isa": [f for f in _ISA_FLAGS if f in flags],
    }


def machine() -> dict[str, Any]:
    """What ran the grid (for the report's compute line)."""
    import jax

    try:
        cpu = cpu_description(Path("/proc/cpuinfo").read_text())
    except OSError:  # not Linux
        cpu = {"cpu": platform.processor() or "?"}
    return {
        "host": socket.gethostname(),
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        **cpu,
        "jax_backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
    }


def _recorded(out: str | Path, key: str, default: Any) -> Any:
    """grid.json's entry ``key``; ``default`` for a grid without the entry or without grid.json."""
    path = Path(out) / "grid.json"
    return json.loads(path.read_text()).get(key, default) if path.exists() else default


def grid_partners(out: str | Path) -> str:
    """The partner population a grid trains against (grid.json's ``partners``; "default" for a
    grid without the entry or without grid.json)."""
    return str(_recorded(out, "partners", "default"))


def grid_settings(out: str | Path) -> dict[str, Any]:
    """The settings every run of a grid changes from the defaults (grid.json's ``settings``,
    from ``transam reproduce --set``; none for a grid without the entry)."""
    return dict(_recorded(out, "settings", {}))


TRAINING_SETTINGS = ("total_steps", "evals", "eval_episodes")
"""The budget settings a new grid may change and an existing one keeps (its runs share them)."""
OVERRIDABLE = (*TRAINING_SETTINGS, "final_episodes")
"""The budget settings a grid may change (``transam reproduce --total-steps`` etc.; recorded
in grid.json, see :func:`grid_budget`)."""


def open_grid(
    out: Path,
    budget_name: str,
    specs: list[RunSpec],
    argv: list[str],
    partners: str = "default",
    overrides: dict[str, int | None] | None = None,
    settings: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Create or extend ``grid.json``; a grid directory keeps one budget, one partner
    population (``partners``: a shipped choice, or a population directory as an absolute
    path) and one set of ``settings`` (``group.name`` -> value, from ``transam reproduce
    --set``: fixed when the grid is created; an invocation without them keeps the grid's).
    ``overrides`` (None values ignored) replace budget settings of :data:`OVERRIDABLE`
    and stay recorded for later invocations: ``final_episodes`` at any time (runs evaluated at
    another count are evaluated again), the training settings only for a new grid (its runs
    must share them)."""
    if budget_name not in BUDGETS:
        raise ConfigError(f"unknown budget {budget_name!r}; valid choices: {', '.join(BUDGETS)}")
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    for key, value in given.items():
        if key not in OVERRIDABLE:
            raise ConfigError(f"unknown budget override {key!r}; valid: {', '.join(OVERRIDABLE)}")
        if value < 1:
            raise ConfigError(f"{key} must be >= 1, got {value!r}")
    from transam.rundir import write_json

    path = out / "grid.json"
    if path.exists():
        grid = json.loads(path.read_text())
        if grid.get("budget") != budget_name:
            raise ConfigError(
                f"--out {str(out)!r} holds a {grid.get('budget')!r} grid; use another --out for "
                f"budget {budget_name!r}"
            )
        if grid.get("partners", "default") != partners:
            raise ConfigError(
                f"--out {str(out)!r} holds a grid against partners "
                f"{grid.get('partners', 'default')!r}; use another --out for partners {partners!r}"
            )
        had_settings = grid.get("settings", {})
        if settings and settings != had_settings:
            raise ConfigError(
                f"--out {str(out)!r} holds a grid with settings {show_settings(had_settings)}; use "
                f"another --out for settings {show_settings(settings)}"
            )
        for key in TRAINING_SETTINGS:
            had = grid["budget_settings"][key]
            if given.get(key, had) != had:
                raise ConfigError(
                    f"--out {str(out)!r} holds a grid with {key} {had:,}; use another --out for "
                    f"{key} {given[key]:,}"
                )
    elif out.exists() and any(out.iterdir()):
        raise ConfigError(f"--out {str(out)!r} is not empty and holds no grid; choose another")
    else:
        grid = {
            "budget": budget_name,
            "budget_settings": dataclasses.asdict(BUDGETS[budget_name]),
            "partners": partners,
            "settings": dict(settings or {}),
            "runs": [],
            "invocations": [],
        }
    grid["budget_settings"].update(given)
    known = {r for r in grid["runs"]}
    grid["runs"] += [s.rel for s in specs if s.rel not in known]
    grid["invocations"].append(
        {"argv": argv, "started": time.time(), "ended": None, "machine": machine()}
    )
    out.mkdir(parents=True, exist_ok=True)
    write_json(path, grid)
    return grid


def show_settings(settings: dict[str, Any]) -> str:
    """``a2c.z_scale=0.088 model.dropout=0.0``: settings as ``--set`` takes them."""
    return " ".join(f"{k}={json.dumps(v)}" for k, v in settings.items()) or "(the defaults)"


def grid_budget(grid: dict[str, Any]) -> Budget:
    """The budget a grid runs: its named budget with the settings of :data:`OVERRIDABLE` that
    grid.json records (an override given once holds for the grid's later invocations)."""
    recorded = grid.get("budget_settings", {})
    kept = {k: recorded[k] for k in OVERRIDABLE if k in recorded}
    return dataclasses.replace(BUDGETS[grid["budget"]], **kept)


def close_grid(out: Path, failures: list[str]) -> None:
    """Stamp the end time (and failures) of this invocation into grid.json."""
    from transam.rundir import write_json

    path = out / "grid.json"
    grid = json.loads(path.read_text())
    inv = grid["invocations"][-1]
    inv["ended"] = time.time()
    inv["wall_s"] = inv["ended"] - inv["started"]
    inv["failures"] = failures
    write_json(path, grid)


def spec_from_rel(rel: str) -> RunSpec:
    """Inverse of :attr:`RunSpec.rel`; ValueError for anything that is not
    ``runs/ENV/METHOD/seed_S``."""
    parts = rel.strip("/").split("/")
    if len(parts) != 4 or parts[0] != "runs" or not parts[3].startswith("seed_"):
        raise ValueError(f"not a grid run path (runs/ENV/METHOD/seed_S): {rel!r}")
    return RunSpec(parts[1], parts[2], int(parts[3].removeprefix("seed_")))


# ---------------------------------------------------------------- backends

Backend = Callable[[Path, list[RunSpec], Budget], list[str]]


def _run_group(
    out: str, specs: list[RunSpec], budget: Budget, vmap_seeds: bool = False
) -> list[str]:
    """Run the seeds of one (env, method) one after another in this process, so the seeds after
    the first reuse its compiled programs, or with ``vmap_seeds`` as one vmapped program (a
    failure then fails them all); returns the failures."""
    if vmap_seeds:
        try:
            run_together(out, specs, budget)
        except Exception as err:
            return [f"{spec.rel}: {type(err).__name__}: {err}" for spec in specs]
        return []
    failures = []
    for spec in specs:
        try:
            run_one(out, spec, budget)
        except Exception as err:  # one bad run must not stop the grid
            failures.append(f"{spec.rel}: {type(err).__name__}: {err}")
    return failures


def _run_group_in_subprocess(
    out: str, specs: list[RunSpec], budget: Budget, vmap_seeds: bool = False
) -> list[str]:
    from transam.jaxcache import enable_compilation_cache

    enable_compilation_cache()
    return _run_group(out, specs, budget, vmap_seeds)


_worker_stopped: int | None = None
"""In a worker process of :func:`run_local`: the signal that interrupted one of its runs."""


def _worker_init() -> None:
    """A worker in a process group of its own: a terminal's Ctrl-C (sent to the foreground
    group) reaches it only as the parent forwards it, once, not twice (the second signal
    would stop its run at once instead of at the chunk's end). POSIX only."""
    if hasattr(os, "setpgrp"):
        os.setpgrp()


def _in_worker(fn: Callable[..., list[str]], *args: Any) -> list[str]:
    """Run a task in a worker, unless a signal already interrupted one of this worker's runs
    (a task the pool had queued before the stop must not start a run)."""
    from transam.train.stop import RunInterrupted

    global _worker_stopped
    if _worker_stopped is not None:
        raise RunInterrupted(_worker_stopped, "not started: the grid is stopping")
    try:
        return fn(*args)
    except RunInterrupted as err:
        _worker_stopped = err.signum
        raise


class _GridStop:
    """The parent's side of stopping :func:`run_local`'s worker processes on SIGINT/SIGTERM:
    the first signal cancels the tasks not yet started and is forwarded to every worker (each
    run in flight checkpoints at its chunk's end and stops); a second is forwarded too (the
    workers stop at once). A run interrupted in a worker stops the grid the same way."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self.futures: list[Any] = []

    def note(self, signum: int) -> None:
        if self.signum is None:
            self.signum = signum
        for fut in self.futures:
            fut.cancel()  # only those not yet handed to a worker

    def _forward(self, signum: int, frame: Any) -> None:
        import multiprocessing as mp

        self.note(signum)
        for child in mp.active_children():
            with contextlib.suppress(ProcessLookupError):
                os.kill(child.pid, signum)  # type: ignore[arg-type]

    def forwarding(self) -> contextlib.AbstractContextManager[None]:
        """Forward SIGINT/SIGTERM for the duration (main thread only)."""
        from transam.train.stop import handling_stop_signals

        return handling_stop_signals(self._forward)


def run_local(
    out: Path, specs: list[RunSpec], budget: Budget, jobs: int = 1, vmap_seeds: bool = False
) -> list[str]:
    """Run the grid on this machine. With ``jobs`` > 1, that many runs train at a time in
    separate processes (one XLA:CPU training program does not keep two cores busy), handed
    out one run at a time, so no process idles while runs remain (handing out a method's seeds
    as one task left a core idle through the last method's later seeds). Every method's first
    seed goes first, then every second seed, and so on: by the time a method's later seed
    starts, its programs are in the persistent compilation cache, whichever process compiled
    them. With ``vmap_seeds`` each (env, method)'s seeds are one task, one vmapped program
    (on a GPU, where one run's program is latency-bound). On a GPU the processes share it:
    each allocates GPU memory as it needs it (JAX's default, taking 75% of the GPU's memory at
    start, would leave the second process too little) unless XLA_PYTHON_CLIENT_PREALLOCATE is
    set. SIGINT or SIGTERM stops the grid as it stops one run: each run in flight checkpoints
    at its chunk's end, none starts after, and :class:`~transam.train.stop.RunInterrupted` is
    raised (rerunning the command resumes). Returns the failed runs, in grid order."""
    groups: dict[tuple[str, str], list[RunSpec]] = {}
    for spec in specs:
        groups.setdefault((spec.env, spec.method), []).append(spec)
    if jobs <= 1:
        return [
            f for group in groups.values() for f in _run_group(str(out), group, budget, vmap_seeds)
        ]
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    from transam.train.stop import RunInterrupted

    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")  # the workers inherit it

    rank = {spec: i for group in groups.values() for i, spec in enumerate(group)}
    order = sorted(specs, key=lambda spec: rank[spec])  # stable: grid order within a rank
    tasks = list(groups.values()) if vmap_seeds else [[spec] for spec in order]
    failed: dict[RunSpec, list[str]] = {}
    stop = _GridStop()
    context = mp.get_context("spawn")
    with (
        stop.forwarding(),
        ProcessPoolExecutor(jobs, mp_context=context, initializer=_worker_init) as pool,
    ):
        stop.futures = [
            pool.submit(_in_worker, _run_group_in_subprocess, str(out), task, budget, vmap_seeds)
            for task in tasks
        ]
        for fut, task in zip(stop.futures, tasks, strict=True):
            if fut.cancelled():
                continue
            try:
                found = fut.result()
            except KeyboardInterrupt as err:  # RunInterrupted in the worker: the grid stops
                stop.note(getattr(err, "signum", signal.SIGINT))
                continue
            except Exception as err:  # a worker process died: rerun the command to resume
                if stop.signum is not None:  # cancelled, or its worker ended by a second signal
                    continue  # stopped, not failed
                found = [f"{spec.rel}: {type(err).__name__}: {err}" for spec in task]
            for spec in task:
                failed[spec] = [f for f in found if f.startswith(f"{spec.rel}:")]
    if stop.signum is not None:
        raise RunInterrupted(
            stop.signum,
            f"{signal.Signals(stop.signum).name}: the grid stopped; every run in flight kept "
            "its last checkpoint",
        )
    return [f for spec in specs for f in failed.get(spec, [])]
