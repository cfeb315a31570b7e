"""Training throughput: env-steps/s of full A2C training (acting + environment + partners +
update), the FLOP rate it achieves, and this machine's matmul FLOP rate for comparison.

    python benchmarks/train_throughput.py [--envs spread tag ...] [--method nam|transam]
        [--attention window stream] [--z-pass shared separate] [--masks default flax packed]
        [--updates 100] [--repeats 5] [--seeds 4]

Each environment runs the default training configuration (``TrainConfig``) for a chunk of
``--updates`` updates, compiled ahead of time; the median of ``--repeats`` timed chunks is
reported. FLOPs are counted from the chunk's jaxpr (XLA's cost analysis counts a loop body once,
not once per iteration): matrix products exactly (2·M·N·K), every other arithmetic op as one
FLOP per output element, data movement as zero; loop bodies are multiplied by their trip counts.
The ratio compares the achieved rate to a large float32 matmul timed in the same process.

``--attention window stream`` (TransAM only) times the window model and the streaming one
(``model.attention``) side by side and prints the ratio of their env-steps/s; ``--z-pass
shared separate`` does the same for where the policy loss's z comes from (``a2c.z_pass``),
``--masks default flax packed`` for how dropout masks are drawn (``model.dropout_masks``).
Variants are compiled first, then timed in turn (one chunk each per round), and each ratio is
the median of the rounds' ratios: a neighbour that slows one round slows every variant in it.

``--seeds n`` also times n seeds vmapped in one program against the single-seed program (which
is what running the seeds one after another costs per step).
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np
import tyro
from rich.console import Console
from rich.table import Table

from transam.jaxcache import enable_compilation_cache
from transam.models import TransAMConfig
from transam.train.a2c import init_runner, make_chunk
from transam.train.config import TrainConfig
from transam.train.programs import env_and_model

FREE = {
    "broadcast_in_dim",
    "reshape",
    "transpose",
    "squeeze",
    "expand_dims",
    "slice",
    "dynamic_slice",
    "dynamic_update_slice",
    "gather",
    "scatter",
    "concatenate",
    "pad",
    "convert_element_type",
    "select_n",
    "iota",
    "copy",
    "copy_p",
    "rev",
    "stop_gradient",
    "device_put",
    "sharding_constraint",
    "split",
    "bitcast_convert_type",
    "random_wrap",
    "random_unwrap",
}


def _size(aval: Any) -> int:
    return int(np.prod(getattr(aval, "shape", ()), dtype=np.int64))


def count_flops(jaxpr: Any) -> tuple[float, float]:
    """(all FLOPs, matmul FLOPs) of one execution of ``jaxpr`` (a Jaxpr or ClosedJaxpr)."""
    jaxpr = getattr(jaxpr, "jaxpr", jaxpr)
    total = matmul = 0.0
    for eqn in jaxpr.eqns:
        name = eqn.primitive.name
        if name == "scan":
            t, m = count_flops(eqn.params["jaxpr"])
            n = eqn.params["length"]
            total, matmul = total + n * t, matmul + n * m
        elif name == "cond":
            costs = [count_flops(b) for b in eqn.params["branches"]]
            t, m = max(costs)
            total, matmul = total + t, matmul + m
        elif name == "dot_general":
            (lhs_contract, _), _ = eqn.params["dimension_numbers"]
            k = math.prod(eqn.invars[0].aval.shape[d] for d in lhs_contract)
            f = 2.0 * _size(eqn.outvars[0].aval) * k
            total, matmul = total + f, matmul + f
        else:
            subs = [
                v
                for v in eqn.params.values()
                if hasattr(v, "eqns") or hasattr(getattr(v, "jaxpr", None), "eqns")
            ]
            if subs:  # pjit, custom_jvp/vjp, remat, while (body counted once)
                for sub in subs:
                    t, m = count_flops(sub)
                    total, matmul = total + t, matmul + m
            elif name not in FREE:
                total += sum(_size(v.aval) for v in eqn.outvars)
    return total, matmul


def median_seconds(fn: Callable[[], Any], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        tic = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - tic)
    return statistics.median(times)


def matmul_gflops(n: int = 2048, repeats: int = 5) -> float:
    """float32 n×n matmul rate of this machine (compiled, median of repeats)."""
    a = jax.random.normal(jax.random.key(0), (n, n), jnp.float32)
    b = jax.random.normal(jax.random.key(1), (n, n), jnp.float32)
    f = jax.jit(jnp.matmul).lower(a, b).compile()
    jax.block_until_ready(f(a, b))
    return 2 * n**3 / median_seconds(lambda: f(a, b), repeats) / 1e9


@dataclass
class Result:
    steps_per_s: float
    gflop_per_chunk: float
    matmul_share: float
    gflops: float
    compile_s: float


@dataclass
class Prepared:
    """A compiled training chunk, warmed up, ready to time."""

    run: Callable[[], Any]
    steps: int
    flops: float
    matmul_flops: float
    compile_s: float

    def result(self, seconds: float) -> Result:
        return Result(
            self.steps / seconds,
            self.flops / 1e9,
            self.matmul_flops / max(self.flops, 1.0),
            self.flops / seconds / 1e9,
            self.compile_s,
        )


def prepare(config: TrainConfig, updates: int, seeds: int = 1) -> Prepared:
    """Compile and warm up a chunk of ``updates`` (``seeds`` vmapped seeds)."""
    env, model = env_and_model(config)
    chunk = make_chunk(config, env, model, updates)

    def init(key: jax.Array) -> Any:
        return init_runner(config, env, model, key)

    keys = jax.random.split(jax.random.key(config.seed), seeds)
    states = [jax.jit(init)(k) for k in keys]  # per seed: vmapped inits can hang XLA:CPU
    if seeds > 1:
        chunk = jax.jit(jax.vmap(chunk))
        state = jax.tree.map(lambda *a: jnp.stack(a), *states)
    else:
        state = states[0]
    tic = time.perf_counter()
    compiled = chunk.lower(state).compile()  # type: ignore[attr-defined]
    compile_s = time.perf_counter() - tic
    flops, mm = count_flops(jax.make_jaxpr(chunk)(state))
    holder = [jax.block_until_ready(compiled(state)[0])]  # warm-up

    def run() -> Any:
        holder[0] = compiled(holder[0])[0]
        return holder[0]

    steps = updates * config.a2c.num_envs * config.a2c.n_steps * seeds
    return Prepared(run, steps, flops, mm, compile_s)


def interleaved_seconds(runs: list[Callable[[], Any]], repeats: int) -> list[list[float]]:
    """Seconds of each of ``runs``, timed in turn ``repeats`` times (round r times every run
    once), so that a noisy neighbour slows all of them alike: ratios are taken per round."""
    times: list[list[float]] = [[] for _ in runs]
    for _ in range(repeats):
        for fn, out in zip(runs, times, strict=True):
            tic = time.perf_counter()
            jax.block_until_ready(fn())
            out.append(time.perf_counter() - tic)
    return times


def time_training(config: TrainConfig, updates: int, repeats: int, seeds: int = 1) -> Result:
    """Median env-steps/s (summed over envs and seeds) of a compiled chunk of ``updates``."""
    prepared = prepare(config, updates, seeds)
    return prepared.result(median_seconds(prepared.run, repeats))


@dataclass
class Args:
    """Benchmark full training throughput (default config) per environment."""

    envs: tuple[Literal["tag", "spread", "overcooked", "lbf"], ...] = (
        "tag",
        "spread",
        "overcooked",
        "lbf",
    )
    """environments"""
    method: Literal["transam", "nam"] = "nam"
    """agent-modeling method"""
    attention: tuple[Literal["window", "stream"], ...] = ("window",)
    """TransAM's attention(s) to time (``model.attention``); two: side by side, with the ratio"""
    z_pass: tuple[Literal["shared", "separate"], ...] = ("shared",)
    """the policy loss's z pass(es) to time (``a2c.z_pass``); two: side by side, with the ratio"""
    masks: tuple[Literal["default", "flax", "packed"], ...] = ("default",)
    """TransAM's dropout masks to time (``model.dropout_masks``; 'default': each attention's
    own, flax's for the window model and packed for the streaming one)"""
    updates: int = 100
    """updates per timed chunk"""
    repeats: int = 5
    """timed chunks (median reported)"""
    seeds: int = 0
    """also compare n vmapped seeds with one seed (0: skip)"""


def config(
    env: str, method: str, attention: str, z_pass: str = "shared", masks: str = "default"
) -> TrainConfig:
    """The default training configuration with the given attention, z pass and masks."""
    dropout_masks = None if masks == "default" else masks
    model = replace(TransAMConfig(), attention=attention, dropout_masks=dropout_masks)  # type: ignore[arg-type]
    a2c = replace(TrainConfig().a2c, z_pass=z_pass)  # type: ignore[arg-type]
    return TrainConfig(env=env, method=method, model=model, a2c=a2c)  # type: ignore[arg-type]


def main(args: Args) -> None:
    settings = (args.attention, args.z_pass, args.masks)
    if args.method != "transam" and settings != (("window",), ("shared",), ("default",)):
        raise SystemExit("--attention, --z-pass and --masks apply to --method transam")
    variants = [f"{a}/{z}/{m}" for a in args.attention for z in args.z_pass for m in args.masks]
    enable_compilation_cache()
    console = Console(width=160)  # wide tables stay readable in a log
    peak = matmul_gflops()
    table = Table(
        title=f"full A2C training, method {args.method}, default config, {args.updates} updates "
        f"x {args.repeats} repeats (variants timed in turn), {jax.devices()[0].platform}"
    )
    cols = ("env", "attention/z pass/masks", "steps/s", "GFLOP/chunk", "matmul share", "GFLOP/s")
    for col in (*cols, "matmul GFLOP/s"):
        table.add_column(col, justify="right")
    table.add_column("ratio", justify="right")
    rates: dict[tuple[str, str], float] = {}
    ratios: dict[tuple[str, str], float] = {}
    for name in args.envs:
        prepared = [
            prepare(config(name, args.method, *v.split("/")), args.updates) for v in variants
        ]
        times = interleaved_seconds([p.run for p in prepared], args.repeats)
        for variant, p, t in zip(variants, prepared, times, strict=True):
            r = p.result(statistics.median(t))
            rates[name, variant] = r.steps_per_s
            # Paired: each round's ratio against the first variant, then their median.
            ratios[name, variant] = statistics.median(
                a / b for a, b in zip(times[0], t, strict=True)
            )
            table.add_row(
                name,
                variant if args.method == "transam" else "-",
                f"{r.steps_per_s:,.0f}",
                f"{r.gflop_per_chunk:.3g}",
                f"{r.matmul_share:.0%}",
                f"{r.gflops:.3g}",
                f"{peak:.3g}",
                f"{r.gflops / peak:.2%}",
            )
    console.print(table)
    if len(variants) > 1:
        first, *others = variants
        side = Table(
            title=f"env-steps/s by attention/z pass/masks (ratio against {first}: median of "
            "the rounds' ratios)"
        )
        side.add_column("env", justify="right")
        for variant in variants:
            side.add_column(f"{variant} steps/s", justify="right")
        for variant in others:
            side.add_column(f"{variant} / {first}", justify="right")
        for name in args.envs:
            side.add_row(
                name,
                *(f"{rates[name, v]:,.0f}" for v in variants),
                *(f"{ratios[name, v]:.2f}x" for v in others),
            )
        console.print(side)
    if args.seeds > 1:
        seeds = Table(title=f"{args.seeds} seeds: one vmapped program vs one seed at a time")
        for col in ("env", "vmap steps/s", "sequential steps/s", "vmap speed-up"):
            seeds.add_column(col, justify="right")
        for name in args.envs:
            cfg = config(name, args.method, args.attention[0], args.z_pass[0], args.masks[0])
            one = time_training(cfg, args.updates, args.repeats)
            many = time_training(cfg, args.updates, args.repeats, seeds=args.seeds)
            seeds.add_row(
                name,
                f"{many.steps_per_s:,.0f}",
                f"{one.steps_per_s:,.0f}",
                f"{many.steps_per_s / one.steps_per_s:.2f}x",
            )
        console.print(seeds)


if __name__ == "__main__":
    main(tyro.cli(Args))
