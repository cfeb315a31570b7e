"""Where a training collection's time goes: each part of the default A2C update timed as its
own compiled program, against the whole collection and the matmul rate of the same shapes.

    python benchmarks/profile_training.py [--env spread] [--method transam]
        [--attention window] [--repeats 5] [--reps 20]

A collection is what one scan iteration of a training chunk runs: ``rollouts_per_collect`` (C)
rollouts with their bootstraps (acting + environment + partners), then C updates. The parts:

* ``collect``: the C rollouts and bootstraps (the acting path), split into the agent model's
  ``step`` on the batch of envs, the policy's step, and the environment step (partners
  included), each timed alone over the same number of calls;
* ``learn``: the C updates, split into the policy's z pass (``embed_rollout``; only with
  ``a2c.z_pass="separate"``, else the policy reads the loss pass's z), the agent-model loss
  forward + backward, the A2C loss forward + backward, and the two Adam steps.

Where the encoder has dropout on (the default), the acting step and the loss are timed again
without it: the random bits of the dropout masks are integer work that counts no FLOPs.

Each part is scanned ``--reps`` times inside one program (so dispatch is not timed) and the
median of ``--repeats`` timings is reported per collection. The parts do not add up exactly to
the whole (XLA fuses across their borders). FLOPs come from the jaxpr
(``train_throughput.count_flops``). A second table gives the rate of float32 matmuls of the
model's own shapes (rows = tokens in one call: envs x tokens per window when acting, rollout
windows x tokens in the update; width -> 3 x width for q, k, v and width -> feed-forward and
back), timed as a chain in one program: the ceiling for a part made of such products.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import jax
import jax.numpy as jnp
import tyro
from rich.console import Console
from rich.table import Table
from train_throughput import count_flops, matmul_gflops, median_seconds

from transam.jaxcache import enable_compilation_cache
from transam.models import TransAMConfig
from transam.train import a2c
from transam.train.config import TrainConfig
from transam.train.programs import env_and_model


@dataclass
class Args:
    """Profile one collection of the default training configuration."""

    env: Literal["tag", "spread", "overcooked", "lbf"] = "spread"
    method: Literal["transam", "nam", "liam"] = "transam"
    attention: Literal["window", "stream"] = "window"
    repeats: int = 5
    """timings per part (median reported)"""
    reps: int = 20
    """collections (or calls) per timed program"""


def timed(fn: Callable[..., Any], *args: Any, repeats: int) -> tuple[float, float]:
    """(median seconds of one call of the compiled ``fn(*args)``, its FLOPs)."""
    compiled = jax.jit(fn).lower(*args).compile()
    flops, _ = count_flops(jax.make_jaxpr(fn)(*args))
    jax.block_until_ready(compiled(*args))  # warm-up
    return median_seconds(lambda: compiled(*args), repeats), flops


def repeat(fn: Callable[[Any], Any], reps: int) -> Callable[[Any], Any]:
    """``fn(x)`` ``reps`` times in one scan (outputs summed so that nothing is dead code). Each
    call's floating-point inputs are offset by a negligible multiple of the running sum, so XLA
    cannot hoist the call out of the loop."""

    def run(x: Any) -> Any:
        def body(acc: jax.Array, _: None) -> tuple[jax.Array, None]:
            eps = acc * 1e-30

            def nudge(v: Any) -> Any:
                if jnp.issubdtype(v.dtype, jnp.floating):
                    return v + eps.astype(v.dtype)
                return v

            out = fn(jax.tree.map(nudge, x))
            leaves = [jnp.sum(v.astype(jnp.float32)) for v in jax.tree.leaves(out)]
            return acc + sum(leaves), None

        return jax.lax.scan(body, jnp.zeros(()), None, length=reps)[0]

    return run


def shape_rate(m: int, k: int, n: int, reps: int = 200, repeats: int = 5) -> float:
    """GFLOP/s of the float32 products [m, k] @ [k, n] @ [n, k], chained ``reps`` times."""
    a = jax.random.normal(jax.random.key(0), (m, k), jnp.float32)
    b = jax.random.normal(jax.random.key(1), (k, n), jnp.float32) / n
    c = jax.random.normal(jax.random.key(2), (n, k), jnp.float32) / k

    def chain(x: jax.Array) -> jax.Array:
        return jax.lax.scan(lambda h, _: (h + 1e-3 * ((h @ b) @ c), None), x, None, length=reps)[0]

    sec, _ = timed(chain, a, repeats=repeats)
    return 4 * m * k * n * reps / sec / 1e9


def main(args: Args) -> None:
    enable_compilation_cache()
    model_cfg = dataclasses.replace(TransAMConfig(), attention=args.attention)
    config = TrainConfig(env=args.env, method=args.method, model=model_cfg)
    env, model_ = env_and_model(config)
    model: Any = model_  # the TransAM family's methods take dropout keys
    a = config.a2c
    per = a.rollouts_per_collect
    n = args.reps
    rs = jax.jit(lambda k: a2c.init_runner(config, env, model, k))(jax.random.key(0))
    update = a2c.make_update(config, env, model)
    collect = a2c.make_collect(config, env, model)
    policy = a2c.make_policy(config, env)
    keys = jax.random.split(jax.random.key(1), per)
    _, collected = jax.jit(collect)(rs, keys)
    steps = per * a.n_steps * a.num_envs

    rows: list[tuple[str, float, float]] = []

    def add(name: str, fn: Callable[[Any], Any], x: Any, calls: int) -> float:
        """Time ``fn`` called ``calls`` times per collection (scanned n times that many)."""
        sec, flops = timed(repeat(fn, n * calls), x, repeats=args.repeats)
        rows.append((name, sec / n, flops / n))
        return sec / n

    # Whole collection: n updates-of-a-collection in one scan, as a chunk runs them.
    def whole(s: a2c.RunnerState) -> a2c.RunnerState:
        return jax.lax.scan(lambda c, _: (update(c)[0], None), s, None, length=n)[0]

    sec, flops = timed(whole, rs, repeats=args.repeats)
    total = sec / n
    rows.append(("collection (C rollouts + C updates)", total, flops / n))

    add("collect: C rollouts + bootstraps", lambda s: collect(s, keys)[1].traj.z, rs, 1)
    x, carry = rs.x, rs.model_carry
    drop = config.acting_dropout
    calls = per * (a.n_steps + 1)

    def model_step(inp: tuple[Any, Any], dropout: bool = drop) -> Any:
        key = jax.random.key(2) if dropout else None
        return a2c.model_step(model, rs.model_params, inp[0], inp[1], None, key)[1]

    add("  agent model step (acting)", model_step, (carry, x), calls)
    if drop:
        add("    the same without dropout", lambda inp: model_step(inp, False), (carry, x), calls)
    z0 = jnp.zeros((a.num_envs, model.embed_dim))
    add(
        "  policy step (acting)",
        lambda inp: policy.step(rs.policy_params, rs.policy_carry, inp, z0)[1],
        x,
        calls,
    )
    actions = jnp.zeros((a.num_envs,), jnp.int32)
    add(
        "  env + partners step",
        lambda s: a2c.env_step(env, jax.random.key(3), s, actions)[2].obs,
        rs.env_state,
        per * a.n_steps,
    )

    col = jax.tree.map(lambda v: v[0], collected)
    traj = col.traj
    key = jax.random.key(4)
    rows.append(("learn: C updates (collection - collect)", total - rows[1][1], 0.0))
    learn_row = len(rows) - 1
    zkeys = jax.random.split(key, a.num_envs)

    def embed(p: Any) -> jax.Array:
        if drop:
            f = jax.vmap(model.embed_rollout, in_axes=(None, 0, 1, 0), out_axes=1)
            return f(p, traj.model_carry0, traj.x, zkeys)
        return jax.vmap(model.embed_rollout, in_axes=(None, 0, 1), out_axes=1)(
            p, traj.model_carry0, traj.x
        )

    def loss_z(p: Any) -> Any:
        return model.loss_and_embed(p, traj.model_carry0, traj.x, traj.record, key)[2]

    # The trainer makes a pass of its own unless the loss's pass gives z (z_pass="shared").
    if a.z_pass == "separate" or jax.eval_shape(loss_z, rs.model_params) is None:
        add("  policy's z pass (forward)", embed, rs.model_params, per)

    def model_grad(p: Any, k: jax.Array | None = key) -> Any:
        return jax.grad(lambda q: model.loss(q, traj.model_carry0, traj.x, traj.record, k)[0])(p)

    add("  agent-model loss forward + backward", model_grad, rs.model_params, per)
    if drop:
        add("    the same without dropout", lambda p: model_grad(p, None), rs.model_params, per)

    def policy_grad(p: Any) -> Any:
        def f(q: Any) -> jax.Array:
            t = a2c.a2c_losses(policy, q, traj, traj.z, col.advantages, col.targets, a.advantage)
            return t["policy_loss"] + t["value_loss"] - t["entropy"]

        return jax.grad(f)(p)

    add("  A2C loss forward + backward", policy_grad, rs.policy_params, per)
    policy_tx, model_tx = a2c.make_optimizers(config)
    g_model = model_grad(rs.model_params)
    g_policy = policy_grad(rs.policy_params)

    def adam(inp: tuple[Any, Any]) -> Any:
        u1, _ = policy_tx.update(inp[0], rs.policy_opt, rs.policy_params)
        u2, _ = model_tx.update(inp[1], rs.model_opt, rs.model_params)
        return u1, u2

    add("  two Adam steps", adam, (g_policy, g_model), per)

    name, sec, _ = rows[learn_row]
    rows[learn_row] = (name, sec, rows[0][2] - rows[1][2])
    peak = matmul_gflops()
    console = Console()
    table = Table(
        title=f"one collection ({steps} env-steps) of {args.method} ({args.attention}) on "
        f"{args.env}, default config; {jax.devices()[0].platform}, matmul {peak:.0f} GFLOP/s"
    )
    for colname in ("part", "ms / collection", "share", "GFLOP", "GFLOP/s"):
        table.add_column(colname, justify="right" if colname != "part" else "left")
    for name, sec, flops in rows:
        table.add_row(
            name,
            f"{sec * 1e3:.1f}",
            f"{sec / total:.0%}",
            f"{flops / 1e9:.3f}",
            f"{flops / sec / 1e9:.1f}",
        )
    console.print(table)
    shapes = Table(title="float32 matmul chains of the model's shapes (rows x width x inner)")
    for colname in ("where", "shape", "GFLOP/s", "of the 2048^2 rate"):
        shapes.add_column(colname, justify="right" if colname != "where" else "left")
    w, ff = config.model.width, config.model.ff_width
    per_window = 3 * config.model.context
    tokens = {
        "acting (one step, all envs)": a.num_envs
        * (per_window if args.attention == "window" else 3),
        "update (one rollout's windows)": a.num_envs * a.n_steps * per_window,
    }
    if args.attention == "stream":
        tokens["update (one rollout's windows)"] = a.num_envs * a.n_steps * 3
    for where, m in tokens.items():
        for inner in (3 * w, ff):
            rate = shape_rate(m, w, inner)
            shapes.add_row(where, f"{m} x {w} x {inner}", f"{rate:.0f}", f"{rate / peak:.0%}")
    console.print(shapes)
    console.print(
        f"whole collection: {steps / total:,.0f} env-steps/s, "
        f"{rows[0][2] / total / 1e9:.1f} GFLOP/s = {rows[0][2] / total / 1e9 / peak:.0%} of the "
        "matmul rate"
    )


if __name__ == "__main__":
    main(tyro.cli(Args))
