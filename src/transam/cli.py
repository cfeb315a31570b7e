"""The ``transam`` command: every subcommand, one typed dataclass each (tyro) whose ``run``
method calls the library and prints what it returns. Nothing else defines a subcommand."""

from __future__ import annotations

import os
import shlex
import statistics
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import tyro
from rich.console import Console
from rich.table import Table

from transam.compose import PartnerChoice
from transam.registry import PAPER_ENVS, PAPER_METHODS, EnvName, MethodName
from transam.train.config import ConfigError, TrainConfig
from transam.train.presets import PRESET_NAMES

if TYPE_CHECKING:
    from transam.envs.population import PolicyFn

PresetName = Literal["none", "authors", "2026-11"]


console = Console()
_ARGV: list[str] = []  # this invocation's arguments (recorded by `reproduce`)


def _setup_jax() -> None:
    """CPU unless the user chose otherwise; persistent compilation cache on."""
    from transam.jaxcache import enable_compilation_cache

    enable_compilation_cache()


@dataclass
class EnvsList:
    """Print each environment's metadata (sizes, episode length, partner population)."""

    partners: PartnerChoice = "default"
    """partner population: the shipped learned one, its held-out split, the scripted one, or a
    population directory (manifest.json + default.safetensors; only the env it was made for)"""

    def run(self) -> None:
        from transam.compose import envs_for_partners, make_env

        table = Table(title="transam environments (controlled agent's view)")
        for col in ("env", "obs", "acts", "others", "other obs", "other acts", "steps", "teams"):
            table.add_column(col, no_wrap=True, justify="left" if col == "env" else "right")
        notes = []
        for name in envs_for_partners(self.partners, PAPER_ENVS):
            env = make_env(name, partners=self.partners)
            s = env.spec
            table.add_row(
                name,
                str(s.obs_dim),
                str(s.num_actions),
                str(s.num_others),
                str(s.other_obs_dim),
                str(s.other_num_actions),
                str(s.episode_len),
                str(env.num_partners),
            )
            notes.append(
                f"[bold]{name}[/bold]: {s.description}. Actions: "
                f"{', '.join(f'{i}={a}' for i, a in enumerate(s.action_names))}. "
                f"Population {env.population.name!r}: {', '.join(env.population.team_names)}."
            )
        console.print(table)
        for note in notes:
            console.print(note)


@dataclass
class EnvsBench:
    """Steps/s of each environment: random controlled actions, partner population, vmapped copies.

    Steps are controlled-agent steps summed over the copies; the median of the timed repeats is
    reported (compilation excluded).
    """

    envs: tuple[EnvName, ...] = PAPER_ENVS
    """environments to time"""
    num_envs: int = 1024
    """vmapped environment copies"""
    steps: int = 200
    """steps per timed rollout"""
    repeats: int = 5
    """timed rollouts per environment"""
    partners: PartnerChoice = "default"
    """partner population: the shipped learned one, its held-out split, the scripted one, or a
    population directory (manifest.json + default.safetensors; only the env it was made for)"""

    def run(self) -> None:
        from transam.compose import envs_for_partners, make_env
        from transam.envs.rollout import steps_per_second

        _check_positive(num_envs=self.num_envs, steps=self.steps, repeats=self.repeats)
        table = Table(
            title=f"env steps/s, {self.num_envs} copies, {self.steps} steps x "
            f"{self.repeats} repeats, {os.cpu_count()} CPU cores"
        )
        for col in ("env", "median steps/s", "min", "max"):
            table.add_column(col, justify="right")
        for name in envs_for_partners(self.partners, self.envs):
            env = make_env(name, partners=self.partners)
            rates = steps_per_second(env, self.num_envs, self.steps, self.repeats)
            table.add_row(
                name, f"{statistics.median(rates):,.0f}", f"{min(rates):,.0f}", f"{max(rates):,.0f}"
            )
        console.print(table)


ROLLOUT_AGENTS = ("random", "landmark")


@dataclass
class EnvsRollout:
    """Roll out every environment with its partner population and a random controlled agent
    (or, on Spread, the landmark rule), and print each partner team's episode returns."""

    envs: tuple[EnvName, ...] = PAPER_ENVS
    """environments to roll out"""
    episodes: int = 20
    """episodes per parallel copy (about episodes x copies / teams per team)"""
    num_envs: int = 64
    """parallel environment copies"""
    seed: int = 0
    """PRNG seed"""
    partners: PartnerChoice = "default"
    """partner population: the shipped learned one, its held-out split, the scripted one, or a
    population directory (manifest.json + default.safetensors; only the env it was made for)"""
    agent: Literal["random", "landmark"] = "random"
    """controlled agent: uniformly random, or (Spread only) transam.partners.spread's
    landmark_agent: head for the landmark whose nearest partner is farthest away"""

    def run(self) -> None:
        import jax
        import numpy as np

        from transam.compose import envs_for_partners, make_env
        from transam.envs.rollout import episode_stats, make_random_rollout

        _check_positive(episodes=self.episodes, num_envs=self.num_envs)
        envs = envs_for_partners(self.partners, self.envs)
        policy = _controlled_agent(self.agent, envs, "--envs")
        summary = Table(
            title=f"{self.agent} controlled agent: return (worst/best = team means), "
            f"{self.episodes * self.num_envs} episodes per env"
        )
        for col in ("env", "teams", "eps", "return", "std", "± s.e.", "worst", "best", "secs"):
            summary.add_column(col, justify="right", no_wrap=True)
        for name in envs:
            start = time.perf_counter()
            env = make_env(name, partners=self.partners)
            steps = self.episodes * env.spec.episode_len
            rollout = make_random_rollout(env, self.num_envs, steps, policy)
            _, ts = rollout(jax.random.key(self.seed))
            stats = episode_stats(ts)
            per_team = stats.by_partner(env.num_partners)
            table = Table(title=f"{name}: {env.population.name} population")
            for col in ("team", "episodes", "mean return", "std"):
                table.add_column(col, justify="right")
            means = []
            for team, r in zip(env.population.team_names, per_team, strict=True):
                means.append(float(r.mean()) if len(r) else float("nan"))
                table.add_row(
                    team,
                    str(len(r)),
                    _num(means[-1]),
                    _num(float(r.std()) if len(r) else float("nan")),
                )
            console.print(table)
            summary.add_row(
                name,
                str(env.num_partners),
                str(len(stats.returns)),
                _num(stats.returns.mean()),
                _num(stats.returns.std()),
                _num(stats.returns.std() / np.sqrt(max(len(stats.returns), 1))),
                _num(np.nanmin(means)),
                _num(np.nanmax(means)),
                f"{time.perf_counter() - start:.1f}",
            )
        console.print(summary)


def _controlled_agent(agent: str, envs: tuple[str, ...], flag: str) -> PolicyFn | None:
    """The controlled agent's policy of ``--agent`` (None: uniformly random), checked against
    the envs it is to play (``flag`` names the option that chose them)."""
    if agent == "random":
        return None
    if agent != "landmark":
        raise SystemExit(
            f"error: unknown --agent {agent!r}; valid choices: {', '.join(ROLLOUT_AGENTS)}"
        )
    if set(envs) != {"spread"}:
        raise SystemExit(
            f"error: --agent landmark is a Spread rule; pass {flag} spread "
            f"(got {flag} {' '.join(envs)})"
        )
    from transam.partners.spread import landmark_agent

    return landmark_agent


def _num(x: float) -> str:
    """Four significant digits: returns range from 0.01 (LBF) to hundreds (Tag, Overcooked)."""
    return f"{x:.4g}"


def _check_positive(**values: int) -> None:
    for key, value in values.items():
        if value < 1:
            raise SystemExit(f"error: --{key.replace('_', '-')} must be >= 1, got {value}")


@dataclass
class Envs:
    """Environment commands: list metadata, benchmark throughput, random-agent rollouts."""

    cmd: (
        Annotated[EnvsList, tyro.conf.subcommand("list")]
        | Annotated[EnvsBench, tyro.conf.subcommand("bench")]
        | Annotated[EnvsRollout, tyro.conf.subcommand("rollout")]
    )

    def run(self) -> None:
        self.cmd.run()


@dataclass(frozen=True)
class Train(TrainConfig):
    """Train one controlled agent with A2C and an agent model against the environment's partner
    population; writes config.json, partners.json, metrics.jsonl, checkpoints and TensorBoard
    files to --out. Steps are controlled-agent steps summed over parallel environments."""

    preset: PresetName = "none"
    """start from a named set of settings, then apply the other flags: 'authors' is the first
    author's Spread training loop as their script runs it (the defaults are the same loop with
    their action-loss bug fixed), '2026-11' our earlier defaults (transam.train.presets,
    docs/methods.md); `--preset NAME --help` shows its values as the
    defaults"""

    def run(self) -> None:
        _run_train(TrainConfig(**{f.name: getattr(self, f.name) for f in fields(TrainConfig)}))


@dataclass(frozen=True)
class Demo(TrainConfig):
    """The main job on built-in defaults: the shipped pretrained runs of --env, each beside a
    uniformly random agent on the same episodes, then a short training run (TransAM on Spread
    by default; the default settings, the authors' training loop). Prints the evaluation during
    and after training next to a uniformly random agent on the same evaluation episodes, and
    where the outputs are. Every `transam train` option applies."""

    total_steps: int = 50_000
    """controlled-agent environment steps, summed over parallel envs"""
    out: str = "runs/demo"
    """run directory"""
    force: bool = True
    """start over each time (the demo's own directory)"""
    preset: PresetName = "none"
    """start from a named set of settings (as `transam train --preset`)"""

    pretrained_episodes: int = 200
    """episodes for each shipped pretrained run of --env, shown before training (0: skip)"""

    def run(self) -> None:
        from transam.evaluation.showcase import training_summary

        config = TrainConfig(**{f.name: getattr(self, f.name) for f in fields(TrainConfig)})
        config.validate()
        if self.pretrained_episodes:
            _showcase_while_compiling(config, self.pretrained_episodes)
        if not _run_train(config):
            return
        got = training_summary(config)
        first, last = got.first, got.last
        console.print(
            f"eval return (seed {config.seed}, {config.eval.episodes} episodes, partners drawn "
            f"uniformly): {_num(first['eval/return'])} after {first['step']:,} steps -> "
            f"{_num(last['eval/return'])} after {last['step']:,}; a uniformly random agent on "
            f"the same episodes: {_num(got.random_return)}"
        )
        if got.accuracy is not None and got.memoryless is not None:
            console.print(
                f"partner-action accuracy (newest position): {got.accuracy:.3f} after "
                f"{last['step']:,} steps; the memoryless level from the agent's own view "
                f"{got.memoryless:.3f}"
            )


def _showcase_while_compiling(config: TrainConfig, episodes: int) -> None:
    """The shipped runs of ``config.env`` (:func:`_print_showcase`) while a thread compiles
    the training programs: both cores busy, and the run starts with them compiled. A compile
    error is left for the run itself to raise."""
    import contextlib
    import threading

    from transam.train.programs import compile_ahead

    def compile_quietly() -> None:
        with contextlib.suppress(Exception):  # the run compiles again and reports it
            compile_ahead(config)

    thread = threading.Thread(target=compile_quietly, daemon=True)
    if config.num_seeds == 1:
        thread.start()
    _print_showcase(config.env, episodes)
    if thread.is_alive():
        thread.join()


def _print_showcase(env: str, episodes: int) -> None:
    """The shipped pretrained runs of ``env`` against the references (see
    transam.evaluation.showcase); nothing when none is shipped."""
    from transam.evaluation.final import output_dir
    from transam.evaluation.showcase import accuracy_by_step, showcase, standard_error
    from transam.evaluation.weights import pretrained_dir, read_card
    from transam.models.base import ACC_NEWEST

    shown = showcase(env, episodes)
    if shown is None:
        return
    table = Table(
        title=f"{env}: shipped pretrained runs against the default partners, {episodes} episodes",
        caption="vs random: return minus the random agent's on the same episodes (same "
        "partners and starts), ± its standard error; accuracy: of the partners' actions, "
        "predicted at the newest position from the agent's own trajectory; memoryless: an MLP "
        "trained to predict them from the agent's current observation alone, or from its "
        "current and previous ones (2 steps: the partners' velocities readable), or its last "
        "five (window: what TransAM's window holds), pooled over teams (the population's "
        "recorded levels); a model above them has learned whom it "
        "plays with",
    )
    for col in ("agent", "steps", "return", "± s.e.", "vs random", "accuracy"):
        table.add_column(col, justify="right" if col != "agent" else "left")
    for name, res in shown.runs.items():
        acc = f"{res[ACC_NEWEST]:.3f}" if ACC_NEWEST in res else "-"
        r, g = res["return"], shown.gain[name]
        se = _num(standard_error(r, episodes))
        vs = f"{g['mean']:+.2f} ± {g['se']:.2f}"
        table.add_row(name, f"{res['step']:,}", _num(r["mean"]), se, vs, acc)
    rnd = shown.random
    table.add_row("random agent", "-", _num(rnd["mean"]), _num(rnd["se"]), "0", "-")
    if shown.landmark:
        lm = shown.landmark
        table.add_row("landmark rule", "-", _num(lm["mean"]), _num(lm["se"]), "-", "-")
    if shown.levels:
        own = shown.levels["memoryless_own_accuracy"]
        table.add_row("memoryless (own view)", "-", "-", "-", "-", f"{own:.3f}")
        own2 = shown.levels.get("memoryless_own2_accuracy")
        if own2 is not None:
            table.add_row("memoryless, 2 steps", "-", "-", "-", "-", f"{own2:.3f}")
        window = shown.levels.get("memoryless_window_accuracy")
        if window is not None:
            table.add_row("memoryless, window", "-", "-", "-", "-", f"{window:.3f}")
        table.add_row("ceiling", "-", "-", "-", "-", f"{shown.levels['action_ceiling']:.3f}")
    console.print(table)
    for name in shown.runs:  # how each was trained: budgets and settings differ
        summary = read_card(pretrained_dir(name)).get("summary")
        if summary:
            console.print(f"[bold]{name}[/bold]: {summary}")
    levels = shown.levels or {}
    by_step = {
        "memoryless": levels.get("memoryless_own_accuracy_by_step") or [],
        "2 steps": levels.get("memoryless_own2_accuracy_by_step") or [],
        "window": levels.get("memoryless_window_accuracy_by_step") or [],
    }
    for name, res in shown.runs.items():
        curve = accuracy_by_step(res)
        if curve:
            steps = Table(
                title=f"{name}: partner-action accuracy by step of the episode",
                caption="memoryless: the population's recorded level at that step from the "
                "agent's current observation (2 steps: and its previous one; window: its last "
                "five, TransAM's window), random "
                "controlled agent; early steps are easier to predict without history",
            )
            steps.add_column("t")
            for t, _ in curve:
                steps.add_column(str(t), justify="right")
            steps.add_row("accuracy", *(f"{a:.2f}" for _, a in curve))
            for label, level in by_step.items():
                if level:
                    at = [level[t] if t < len(level) else None for t, _ in curve]
                    steps.add_row(label, *("-" if v is None else f"{v:.2f}" for v in at))
            console.print(steps)
        console.print(f"figure: {output_dir(name) / 'eval_train.png'}")


@dataclass(frozen=True)
class Reproduce:
    """Run the reproduction grid (env x method x seed) of a budget into --out, skipping finished
    runs and resuming interrupted ones, evaluate every run on its training and held-out partners,
    then build the report (figures, report.md, results.json) in --out/report/."""

    budget: Literal["smoke", "small", "medium", "paper"] = "small"
    """steps x seeds per run: smoke 1k x 2 (every artefact, nothing learned; a test runs it),
    small 30k x 2, medium 1M x 3, paper 10M x 5 (docs/reproducing.md)"""
    out: str = "runs/reproduce"
    """grid directory (one budget per directory)"""
    envs: tuple[EnvName, ...] = PAPER_ENVS
    """environments"""
    methods: tuple[MethodName, ...] = PAPER_METHODS
    """methods"""
    seeds: tuple[int, ...] = ()
    """seeds (default: 0 .. the budget's seed count - 1)"""
    jobs: int = 2
    """local backend: runs at a time, one process each (one training program does not keep two
    CPU cores busy)"""
    vmap_seeds: bool = False
    """local backend: train each (env, method)'s seeds as one vmapped program, one task per
    method (for a GPU, where one run's program is latency-bound; on CPU NAM gains, TransAM
    hardly); each run directory is written as if trained alone"""
    backend: Literal["local", "ray"] = "local"
    """local processes, or tasks on a Ray cluster (pip install 'transam[ray]')"""
    address: str = "auto"
    """Ray: the cluster to join ('auto', HOST:PORT, or 'local' to start one here)"""
    cpus_per_run: float = 1.0
    """Ray: CPUs reserved per run"""
    gpus_per_run: float = 0.0
    """Ray: GPUs reserved per run (fractions share a GPU)"""
    max_retries: int = 3
    """Ray: retries of a run whose worker or node died (it resumes from its checkpoint)"""
    partners: str = "default"
    """the partner population every run trains against: default, heldout, or a population
    directory (manifest.json + default.safetensors; its one env only), e.g. the authors' own
    Spread population from `transam partners import-authors`"""
    total_steps: int | None = None
    """steps of each run (default: the budget's); a new grid only, recorded in it (e.g. an
    environment that needs more than the budget's steps to learn)"""
    evals: int | None = None
    """evaluations during each run (default: the budget's); a new grid only"""
    eval_episodes: int | None = None
    """episodes per evaluation during training (default: the budget's); a new grid only"""
    final_episodes: int | None = None
    """episodes of each run's final evaluations (default: the budget's); recorded in the
    grid, and runs evaluated with another count are evaluated again"""
    set: tuple[str, ...] = ()
    """settings every run of the grid changes from the defaults, GROUP.NAME=VALUE with GROUP
    a2c, model or baseline (e.g. --set a2c.z_scale=0.088 model.dropout=0): a deviation
    measured as a whole grid; a new grid only, recorded in it (docs/reproducing.md)"""

    def run(self) -> None:
        from transam.compose import make_env, resolve_partners
        from transam.reproduce import grid
        from transam.reproduce.report.build import build_report
        from transam.train.presets import parse_settings

        _check_positive(jobs=self.jobs)
        budget = grid.BUDGETS[self.budget]
        seeds = self.seeds or tuple(range(budget.seeds))
        specs = grid.grid_specs(self.envs, self.methods, seeds)
        partners = resolve_partners(self.partners)
        if partners != "default":
            for env in self.envs:  # a population that does not fit an env fails before writing
                make_env(env, partners=partners)
        out = Path(self.out)
        address = None if self.address == "local" else self.address
        if self.backend == "ray" and self.vmap_seeds:
            raise ConfigError("--vmap-seeds runs with --backend local only (ray: one run a task)")
        if self.backend == "ray":  # a missing Ray or a bad address fails before writing
            from transam.reproduce.grid_ray import connect

            connect(address)
        overrides = {
            "total_steps": self.total_steps,
            "evals": self.evals,
            "eval_episodes": self.eval_episodes,
            "final_episodes": self.final_episodes,
        }
        settings = parse_settings(self.set)
        opened = grid.open_grid(
            out, self.budget, specs, ["transam", *_ARGV], partners, overrides, settings
        )
        budget = grid.grid_budget(opened)
        console.print(
            f"{len(specs)} runs ({len(self.envs)} envs x {len(self.methods)} methods x "
            f"{len(seeds)} seeds), budget {self.budget!r} "
            f"({budget.total_steps:,} steps each), partners {partners!r}, into {out}/ via "
            f"{self.backend}, settings {grid.show_settings(opened.get('settings', {}))}"
        )
        if self.backend == "ray":
            from transam.reproduce.grid_ray import run_ray

            failures = run_ray(
                out,
                specs,
                budget,
                address=address,
                cpus_per_run=self.cpus_per_run,
                gpus_per_run=self.gpus_per_run,
                max_retries=self.max_retries,
            )
        else:
            failures = grid.run_local(out, specs, budget, self.jobs, self.vmap_seeds)
        grid.close_grid(out, failures)
        report = build_report(out)
        for f in failures:
            console.print(f"[red]failed[/red] {f}")
        console.print(f"report: {report}")
        if failures:
            raise SystemExit(1)


EvalPartners = Annotated[str, tyro.conf.arg(metavar="{train,heldout}|DIR")]
"""``train``, ``heldout`` or a population directory (checked by
:func:`transam.evaluation.final.population_for`)."""


@dataclass(frozen=True)
class Evaluate:
    """Evaluate a trained run: return, agent-modeling accuracy and their per-step curves, and a
    linear probe and projection of the embeddings (writes eval_PARTNERS.json/.png)."""

    run_dir: Annotated[str, tyro.conf.Positional]
    """run directory (one seed: a multi-seed run's seed_S subdirectory), a pretrained run's
    directory, or the name of a shipped pretrained run (`transam pretrained` lists them)"""
    episodes: int = 100
    """evaluation episodes (run in parallel; partner i mod M for episode i)"""
    partners: EvalPartners = "train"
    """the run's training partners, held-out ones it never met, or a population directory
    (manifest.json + default.safetensors; writes eval_pop-NAME.*)"""
    checkpoint: str | None = None
    """checkpoint file name or chunk number (default: the newest)"""
    seed: int = 0
    """PRNG seed of the episodes and of the probe's train/test split"""
    out: str | None = None
    """where to write the outputs (default: the run directory; runs/pretrained/NAME for a
    shipped pretrained run)"""
    starts: str | None = None
    """instead, play the episodes of a starts file (given start positions and partner teams of
    the run's population, e.g. another codebase's evaluation episodes; MPE games; format in
    transam.envs.starts) and write eval_starts-STEM.json (--episodes and --partners unused)"""
    no_dropout: bool = False
    """act without the agent model's dropout (the run acted with it, as the authors'
    evaluation does): reads what the model knows rather than what its noisy acting sees;
    writes eval_PARTNERS-nodropout.* beside the run's own evaluation"""

    def run(self) -> None:
        from transam.evaluation.final import EVAL_METRICS, evaluate_run, output_dir
        from transam.jaxcache import enable_compilation_cache
        from transam.rundir import evaluation_path, projection_path

        enable_compilation_cache()
        if self.starts is not None:
            self._run_starts(self.starts)
            return
        dest = output_dir(self.run_dir, self.out)
        dropout = not self.no_dropout
        res = evaluate_run(
            self.run_dir,
            self.episodes,
            self.partners,
            self.checkpoint,
            self.seed,
            self.out,
            dropout,
        )
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
        console.print(table)
        for note in res["notes"]:
            console.print(f"note: {note}")
        path = evaluation_path(dest, self.partners, dropout)
        console.print(f"wrote {path}, {path.with_suffix('.png')}")
        if "pca" in res:
            console.print(f"wrote {projection_path(dest, self.partners, dropout)}")

    def _run_starts(self, starts: str) -> None:
        from transam.evaluation.final import EVAL_METRICS, evaluate_starts, output_dir
        from transam.rundir import starts_evaluation_path

        if self.partners != "train":
            raise SystemExit(
                f"error: --starts plays the run's own partners (its team indices); got "
                f"--partners {self.partners}"
            )
        dropout = not self.no_dropout
        res = evaluate_starts(self.run_dir, starts, self.checkpoint, self.seed, self.out, dropout)
        table = Table(
            title=f"{res['env']}/{res['method']} seed {res['seed']}, {res['checkpoint']} "
            f"(step {res['step']:,}), the {res['episodes']} episodes of {starts}"
        )
        table.add_column("episodes")
        table.add_column("return", justify="right")
        r = res["return"]
        table.add_row("all", f"{r['mean']:.4g} ± {r['se']:.2g} (s.e.)")
        if len(res["per_group"]) > 1:
            for g, mean in res["per_group"].items():
                table.add_row(f"group {g}", f"{mean:.4g}")
        for key in EVAL_METRICS:
            if key in res:
                table.add_row(key.replace("_", " "), f"{res[key]:.4g}")
        console.print(table)
        for note in res["notes"]:
            console.print(f"note: {note}")
        dest = output_dir(self.run_dir, self.out)
        console.print(f"wrote {starts_evaluation_path(dest, starts, dropout)}")


@dataclass
class Export:
    """Write a pretrained run (the policy's and the agent model's parameters, the settings and
    the partner population's digest; a few MB) from one seed of a trained run, so that
    `transam evaluate DIR` plays it without the run directory."""

    run_dir: Annotated[str, tyro.conf.Positional]
    """run directory (one seed: a multi-seed run's seed_S subdirectory)"""
    out: str
    """the pretrained run's directory (replaced if it already holds one)"""
    checkpoint: str | None = None
    """checkpoint file name or chunk number (default: the newest that verifies)"""
    summary: str = ""
    """one line for card.json and `transam pretrained`: how it was trained, what it shows"""

    def run(self) -> None:
        from transam.evaluation.weights import export_run

        card = export_run(self.run_dir, self.out, self.checkpoint, self.summary)
        console.print(
            f"wrote {self.out}: {card['env']}/{card['method']} seed {card['seed']}, "
            f"{card['checkpoint']} (step {card['step']:,})"
        )


@dataclass
class Pretrained:
    """List the shipped pretrained runs (`transam evaluate NAME` plays one)."""

    def run(self) -> None:
        from transam.evaluation.weights import PRETRAINED_DIR, pretrained_names, read_card

        table = Table(title=f"pretrained runs in {PRETRAINED_DIR}")
        for col in ("name", "env", "method", "seed", "step", "summary"):
            table.add_column(col)
        for name in pretrained_names():
            card = read_card(PRETRAINED_DIR / name)
            row = [card.get(k, "") for k in ("env", "method", "seed", "step")]
            table.add_row(name, *map(str, row), str(card.get("summary", "")))
        console.print(table)


@dataclass
class Report:
    """Aggregate a grid directory (the --out of `transam reproduce`) into OUT/report/: tables with
    95% bootstrap CIs over seeds, the paper's figures, and its claims with computed verdicts."""

    out: tyro.conf.Positional[Path]
    """the grid directory (holds grid.json and runs/)"""

    def run(self) -> None:
        import json

        from transam.models.base import ACC_NEWEST
        from transam.reproduce.report.build import build_report

        path = build_report(self.out)
        results = json.loads((path.parent / "results.json").read_text())
        runs = results["runs"]
        table = Table(title=f"final return, mean [95% CI] ({results['grid']['budget']} budget)")
        for col in ("env", "method", "seeds", "return", "action acc. (newest)"):
            table.add_column(col, justify="left" if col in ("env", "method") else "right")
        for env, cells in results["cells"].items():
            for method, cell in cells.items():
                ret, acc = cell["metrics"].get("return"), cell["metrics"].get(ACC_NEWEST)
                table.add_row(
                    env,
                    method,
                    str(len(cell["seeds"])),
                    f"{ret['mean']:.2f} [{ret['lo']:.2f}, {ret['hi']:.2f}]" if ret else "-",
                    f"{100 * acc['mean']:.1f}%" if acc else "-",
                )
        console.print(table)
        verdicts: dict[str, list[str]] = {}
        for claim in results["claims"]:
            verdicts.setdefault(claim["verdict"], []).append(claim["key"])
        for verdict, keys in verdicts.items():
            console.print(f"claims {verdict}: {', '.join(keys)}")
        console.print(
            f"runs: {len(runs['finished'])} finished, {len(runs['unfinished'])} unfinished, "
            f"{len(runs['missing'])} missing (of {runs['expected']} in grid.json)"
        )
        console.print(f"report: {path}")
        console.print(
            f"results: {path.parent / 'results.json'}; figures: {path.parent / 'figures'}"
        )


def _partner_split(heldout: bool) -> str:
    return "heldout" if heldout else "default"


@dataclass
class PartnersTrain:
    """Regenerate ENV's learned population from scratch (deterministic) into the package data."""

    env: tyro.conf.Positional[EnvName]
    heldout: bool = False  # train the held-out population instead of the default one
    steps: int | None = None  # smoke runs: every family gets this budget, 4 envs, 8-step rollouts
    out: Path | None = None  # write here instead of the package data (use with --steps)

    def run(self) -> None:
        from transam.partners import learned
        from transam.partners.recipes import recipe

        if self.steps is not None and self.out is None:
            raise SystemExit(
                "error: --steps changes the recipe's budget; pass --out DIR too, so the shipped "
                f"{self.env} population is not overwritten by a smoke run"
            )
        try:
            r = recipe(self.env, self.heldout)
        except ValueError as err:
            raise SystemExit(f"error: {err}") from None
        if self.steps is not None:
            r = r.scaled(self.steps)
        t0 = time.time()
        tensors, entry = learned.train_recipe(r, log=console.print)
        path = learned.save(self.env, r.split, tensors, entry, root=self.out)
        digest = learned.digest(self.env, r.split, root=self.out)
        console.print(
            f"trained {len(entry['members'])} members in {time.time() - t0:.1f}s -> {path} "
            f"(digest {digest})"
        )


@dataclass
class PartnersShow:
    """Print ENV's manifest with each member's measured return against its stand-in."""

    env: tyro.conf.Positional[EnvName]
    heldout: bool = False
    episodes: int = 128  # episodes per measured number

    def run(self) -> None:
        from transam.partners import learned

        if self.episodes < 1:
            raise SystemExit(f"error: --episodes must be at least 1, got {self.episodes}")
        split = _partner_split(self.heldout)
        entry = learned.load_manifest(self.env)[split]
        members = learned.learned_members(self.env, split)
        measured = learned.measure_members(self.env, entry["members"], members, self.episodes)
        # Tag: also how often each team of three reaches the prey, and random predators' rate.
        touches = (
            learned.measure_members(
                self.env, entry["members"], members, self.episodes, "touches", True
            )
            if self.env == "tag"
            else {}
        )
        digest = learned.digest(self.env, split)
        table = Table(title=f"{self.env} {split} learned partners (digest {digest})")
        rows = [
            {
                "member": m["name"],
                "kind": m["kind"],
                "recipe": m["recipe"],
                "act": m.get("act", "sample"),
                # Imported members (LIAM's) have no training metadata: "-", column dropped.
                "seed": str(m.get("seed", "-")),
                "shaping": m.get("shaping", "-"),
                "gamma": f"{m['gamma']:g}" if "gamma" in m else "-",
                "steps": f"{m['steps']:,}" if "steps" in m else "-",
                "self-play": f"{m['self_play_return']:.3f}" if "self_play_return" in m else "-",
                "vs": learned.stand_in_of(m),
                "measured": f"{measured[m['name']]:.3f}",
                **({"touches": f"{touches[m['name']]:.2f}"} if touches else {}),
            }
            for m in entry["members"]
        ]
        cols = [c for c in rows[0] if any(r[c] != "-" for r in rows)]
        for c in cols:
            table.add_column(c, justify="left" if c in ("member", "recipe", "vs") else "right")
        for r in rows:
            table.add_row(*(r[c] for c in cols))
        console.print(table)
        if "source" in entry:
            src = entry["source"]
            licence = learned.data_dir(self.env) / src["license_file"]
            console.print(
                f"imported from {src['repository']}@{src['commit'][:8]} ({src['license']}, "
                f"{src['copyright']}; licence in {licence})"
            )
        if "random_return" in entry:
            console.print(f"random play: {entry['random_return']}")
        if touches:
            rnd = {k.split("/")[1]: round(v, 2) for k, v in touches.items() if "/" in k}
            console.print(
                f"touches: steps per episode with a predator within the capture distance of "
                f"the prey; random predators: {rnd}"
            )
        if entry["teams"]:
            console.print("teams: " + ", ".join(t["name"] for t in entry["teams"]))
        console.print(
            "self-play: the member's training run (manifest); measured: every learner slot "
            f"played by this member, against the stand-in in column vs ({self.episodes} "
            "episodes)"
        )


@dataclass
class PartnersDiversity:
    """Cross-play matrix (LBF, Overcooked), partner-index classifier accuracy vs chance, and the
    partners' action-accuracy levels: the ceiling E[max_a pi(a|o)] and the memoryless,
    team-agnostic level (an MLP from a partner's own observation, pooled over teams)."""

    env: tyro.conf.Positional[EnvName]
    heldout: bool = False
    heuristic: bool = False  # the scripted population (partners="heuristic") instead
    population: str | None = None
    """a population directory instead (e.g. written by import-authors); no cross-play"""
    agent: Literal["random", "landmark"] = "random"
    """the controlled agent while measuring the accuracy levels: uniformly random, or (Spread)
    the landmark rule, to see how much the levels depend on the states it visits"""
    window: int = 10  # steps per classifier sample
    record: bool = False
    """store the results in the shipped manifest (docs/partners.md quotes it), or in the
    --population directory's (`transam report` reads a grid's levels there)"""
    levels_episodes: int | None = None
    """episodes per team for the accuracy levels (default: LevelsConfig's 25,600 steps' worth,
    1,024 on Spread). The levels are fits of an MLP, so lower bounds: less data (and fewer
    --levels-steps) lower them"""
    levels_steps: int | None = None
    """training steps of the levels' MLPs, batch 256 (default: LevelsConfig's 20,000)"""

    def run(self) -> None:
        from rich.markup import escape

        from transam.compose import make_env
        from transam.partners import diversity, learned

        other = "--heuristic" if self.heuristic else "--population" if self.population else None
        if self.heuristic and (self.heldout or self.record or self.population):
            raise SystemExit(
                "error: --heuristic measures the scripted population, which has no manifest: "
                "it takes none of --heldout, --record, --population"
            )
        if self.population and self.heldout:
            raise SystemExit(
                "error: --population measures that directory's one population: no --heldout"
            )
        if self.levels_steps is not None:
            _check_positive(levels_steps=self.levels_steps)
        if self.levels_episodes is not None and self.levels_episodes < 2:
            raise SystemExit(
                "error: --levels-episodes must be >= 2 (every 4th episode of a team is held "
                f"out to test), got {self.levels_episodes}"
            )
        agent = _controlled_agent(self.agent, (self.env,), "ENV")
        if agent is not None and self.record:
            raise SystemExit(
                "error: the recorded levels are random play's: --agent landmark takes no --record"
            )
        shipped = None if other else _partner_split(self.heldout)
        if self.heuristic:
            split, env = "heuristic", make_env(self.env, partners="heuristic")
        elif self.population is not None:
            split, env = self.population, make_env(self.env, partners=self.population)
        else:
            split = _partner_split(self.heldout)
            env = make_env(self.env, population=learned.population(self.env, split))
        if not 1 <= self.window <= env.spec.episode_len:
            raise SystemExit(
                f"error: --window must be between 1 and {self.env}'s episode length "
                f"{env.spec.episode_len} (a window stays inside one episode), got {self.window}"
            )
        lv_cfg = diversity.levels_config(self.levels_episodes, self.levels_steps)
        found = diversity.measure(env, shipped, self.window, lv_cfg, agent)
        if found.cross_play is not None:
            table = Table(title=f"{self.env} cross-play (row: partner, column: stand-in slot)")
            table.add_column("partner", no_wrap=True)
            for j in range(len(found.members)):
                table.add_column(str(j), justify="right")
            for i, (n, row) in enumerate(zip(found.members, found.cross_play, strict=True)):
                table.add_row(f"{i} {n}", *(f"{x:.2f}" for x in row))
            console.print(table)
        acc = found.accuracy
        console.print(
            f"{self.env} {split}: partner-index top-1 accuracy from the others' obs+actions "
            f"{acc['others']:.3f}, from the controlled agent's local trajectory "
            f"{acc['local']:.3f}, "
            f"chance {acc['chance']:.3f} ({acc['teams']} teams, window {self.window})"
        )
        levels = found.levels
        table = Table(title=f"{self.env} {split}: partners' action-accuracy levels")
        table.add_column("level")
        table.add_column("value", justify="right")
        table.add_column("what")
        table.add_row(
            "ceiling", f"{levels['ceiling']:.3f}", escape("E[max_a pi(a|o)] under their own obs")
        )
        table.add_row(
            "memoryless",
            f"{levels['memoryless']:.3f}",
            "MLP: partner's own obs + slot -> action, pooled over teams (held out)",
        )
        table.add_row(
            "memoryless (own view)",
            f"{levels['memoryless_own']:.3f}",
            "the same from the controlled agent's current obs (an agent model without history)",
        )
        table.add_row(
            "memoryless (own view, 2 steps)",
            f"{levels['memoryless_own2']:.3f}",
            "the same from its current and previous obs (the partners' velocities readable)",
        )
        table.add_row(
            f"memoryless (own view, {lv_cfg.window} steps)",
            f"{levels['memoryless_window']:.3f}",
            "the same from its last obs in the agent model's window",
        )
        table.add_row("majority", f"{levels['majority']:.3f}", "each slot's most frequent action")
        console.print(table)
        for key, what in (
            ("own", "own view"),
            ("own2", "own view, 2 steps"),
            ("window", f"own view, {lv_cfg.window} steps"),
        ):
            console.print(
                f"memoryless ({what}) by step of the episode: "
                + " ".join(
                    "-" if v is None else f"{v:.2f}" for v in levels[f"memoryless_{key}_by_step"]
                )
            )
        sampled = set(levels["sampled"])
        console.print(
            "member ceilings: "
            + ", ".join(
                f"{n} {v:.3f}" + ("*" if n in sampled else "") for n, v in levels["members"].items()
            )
            + f" (* measured by sampling act {lv_cfg.samples}x per obs; others from their "
            f"probabilities); {levels['episodes_per_team']} episodes per team, {levels['steps']:,} "
            f"partner steps, {self.agent} controlled agent"
        )
        if self.record:
            root = Path(self.population) if self.population else None
            console.print(f"recorded in {diversity.record(self.env, self.heldout, found, root)}")


@dataclass
class PartnersImportLiam:
    """Convert LIAM's six pretrained Tag predators (.npz exports of its .pt files, with its
    LICENSE) into Tag's default population in the package data."""

    env: tyro.conf.Positional[Literal["tag"]]
    src: tyro.conf.Positional[Path]  # folder of params_{ia2c,maddpg}_agent_{0,1,2}.npz + LICENSE
    out: Path | None = None  # write here instead of the package data

    def run(self) -> None:
        from transam.partners import learned
        from transam.partners.liam import import_liam

        try:
            path = import_liam(self.src, root=self.out)
        except (FileNotFoundError, ValueError) as err:
            raise SystemExit(f"error: {err}") from None
        digest = learned.digest(self.env, "default", root=self.out)
        console.print(f"imported LIAM's predators -> {path} (digest {digest})")


@dataclass
class PartnersImportAuthors:
    """Import the TransAM authors' Spread population from YOUR checkout of their repository
    (conor-wallace/agent-transformer) into a population directory --out DIR, for
    `--partners DIR` / make_env("spread", partners=DIR). Their repository has no licence: the
    directory is for your own use, never to be redistributed (nothing of theirs ships with
    transam)."""

    env: tyro.conf.Positional[Literal["spread"]]
    path: tyro.conf.Positional[Path]
    """their repository's root (weights under pretrained_opponents/pretrained_parameters/spread/)
    or a folder holding params_{ippo,mappo}_agent_{0..3}.pt directly"""
    out: Path
    """population directory to write (manifest.json + default.safetensors), outside the
    transam package"""

    def run(self) -> None:
        from transam.partners import authors, learned

        if self.out.exists() and not self.out.is_dir():
            raise SystemExit(f"error: --out {self.out} exists and is not a directory")
        if (
            self.out.is_dir()
            and any(self.out.iterdir())
            and not (self.out / "manifest.json").exists()
        ):
            raise SystemExit(
                f"error: --out {self.out} is a non-empty folder that holds no population "
                "(manifest.json); choose an empty or new folder"
            )
        try:
            path = authors.import_spread(self.path, self.out)
        except (FileNotFoundError, ValueError) as err:
            raise SystemExit(f"error: {err}") from None
        pop = learned.directory_population("spread", self.out)
        console.print(
            f"wrote {path} and {self.out / 'default.safetensors'}: {len(authors.LEARNED)} "
            f"learned actors (argmax) + {len(authors.MEMBER_LIST[:5])} heuristics, "
            f"{len(pop.teams)} teams (digest {learned.directory_digest(self.out)})"
        )
        console.print(
            f"use: transam train --partners {self.out} (or make_env('spread', "
            f"partners='{self.out}')); licence: {authors.LICENCE}"
        )


@dataclass
class Partners:
    """Learned partner populations: train, show, diversity, import-liam, import-authors."""

    cmd: (
        Annotated[PartnersTrain, tyro.conf.subcommand("train")]
        | Annotated[PartnersImportLiam, tyro.conf.subcommand("import-liam")]
        | Annotated[PartnersShow, tyro.conf.subcommand("show")]
        | Annotated[PartnersDiversity, tyro.conf.subcommand("diversity")]
        | Annotated[PartnersImportAuthors, tyro.conf.subcommand("import-authors")]
    )

    def run(self) -> None:
        self.cmd.run()


def _run_train(config: TrainConfig) -> bool:
    """Train and print the final evaluation table; True when the run finished."""
    from transam.rundir import WriteError
    from transam.train.loop import NonFiniteError, train
    from transam.train.stop import RunInterrupted

    try:
        result = train(config)
    except (ConfigError, NonFiniteError, WriteError) as err:
        raise SystemExit(f"error: {err}") from None
    except RunInterrupted as err:
        again = [*_ARGV, *([] if "--resume" in _ARGV else ["--resume"])]
        if _ARGV[:1] == ["demo"] and "--no-force" not in _ARGV:
            again.append("--no-force")  # the demo starts over by default
        console.print(f"{err}\nresume with: {shlex.join(['transam', *again])}")
        raise SystemExit(128 + err.signum) from None
    if not result.finished:
        console.print(f"stopped early; resume with --resume --out {result.run_dir}")
        return False
    table = Table(title=f"final evaluation: {config.env} / {config.method}")
    for col in ("seed", "step", "eval return", "std", "action acc (newest)", "obs mse"):
        table.add_column(col, justify="right")
    for seed, rec in zip(result.seeds, result.final, strict=True):
        table.add_row(
            str(seed),
            f"{rec.get('step', 0):,}",
            *(_opt(rec.get(f"eval/{k}")) for k in ("return", "return_std")),
            *(_opt(rec.get(f"eval/{k}")) for k in ("action_accuracy_newest", "obs_mse")),
        )
    console.print(table)
    console.print(
        f"outputs in {result.run_dir}/: config.json, partners.json, final.json, metrics.jsonl, "
        "checkpoints/, tb/ (per seed in seed_S/ when --num-seeds > 1)"
    )
    return True


def _opt(x: float | None) -> str:
    return "-" if x is None else _num(x)


def _preset_in(argv: list[str]) -> str:
    """The value of ``--preset`` in ``argv`` ('none' without one, or with a value tyro will
    reject itself)."""
    for i, arg in enumerate(argv):
        value = argv[i + 1] if arg == "--preset" and i + 1 < len(argv) else None
        if arg.startswith("--preset="):
            value = arg.partition("=")[2]
        if value is not None:
            return value if value in PRESET_NAMES else "none"
    return "none"


def _with_preset(cls: type[Train] | type[Demo], preset: str) -> Train | Demo:
    """A ``cls`` whose settings are the preset's (the defaults tyro then parses flags over)."""
    from transam.train.presets import apply

    base = apply(cls(), preset)
    values = {f.name: getattr(base, f.name) for f in fields(TrainConfig)}
    return cls(**values, preset=preset)  # type: ignore[arg-type]


def command(preset: str = "none") -> Any:
    """The ``transam`` command union; with a ``preset``, train's and demo's defaults are its."""
    return (
        Annotated[Demo, tyro.conf.subcommand("demo", default=_with_preset(Demo, preset))]
        | Annotated[Envs, tyro.conf.subcommand("envs")]
        | Annotated[Train, tyro.conf.subcommand("train", default=_with_preset(Train, preset))]
        | Annotated[Evaluate, tyro.conf.subcommand("evaluate")]
        | Annotated[Export, tyro.conf.subcommand("export")]
        | Annotated[Pretrained, tyro.conf.subcommand("pretrained")]
        | Annotated[Reproduce, tyro.conf.subcommand("reproduce")]
        | Annotated[Report, tyro.conf.subcommand("report")]
        | Annotated[Partners, tyro.conf.subcommand("partners")]
    )


Command = command()


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``transam`` console script."""
    _ARGV[:] = sys.argv[1:] if argv is None else argv
    cmd = tyro.cli(
        command(_preset_in(_ARGV)),
        prog="transam",
        args=_ARGV,
        config=(tyro.conf.OmitSubcommandPrefixes,),
        description="TransAM: transformer-based agent modeling for multi-agent RL (JAX).",
    )
    _setup_jax()
    from transam.envs import EnvError
    from transam.rundir import WriteError
    from transam.train.stop import RunInterrupted

    try:
        cmd.run()
    except (EnvError, ConfigError, WriteError) as err:
        raise SystemExit(f"error: {err}") from None
    except RunInterrupted as err:  # a grid stopped by a signal: rerunning it resumes
        console.print(f"{err}\nrerun the same command to continue")
        raise SystemExit(128 + err.signum) from None


if __name__ == "__main__":
    main()
