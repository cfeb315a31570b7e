"""A run's agent model trained offline, by supervised passes over random-play episodes, and
scored on held-out episodes: does the model reach what its window holds
(window_levels.py) when data and passes are not the limit? The model, its loss (dropout
on), optimiser and learning rate are the run's; batches are whole episodes from the start.
Also scores the run's own trained model on the same held-out episodes. Accuracy is at the
newest window position, without dropout, overall and by step; one JSON line per evaluation.

    python docs/results/scripts/supervised_model.py runs/parity/defaults/seed_0 \
        --out runs/supervised/s256 --episodes 256 --batch 32 --updates 600 --every 150
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from transam.evaluation.weights import restore_weights
from transam.models.base import LocalStep
from transam.rundir import load_run_config
from transam.train.a2c import batch_carry, make_optimizers
from transam.train.programs import env_and_model


def collect(env: Any, eps_per_team: int, seed: int) -> tuple[LocalStep, Any]:
    """(LocalStep, PartnerRecord) [E, T, ...] of whole episodes, random controlled agent."""
    spec = env.spec
    team = jnp.repeat(jnp.arange(env.num_partners, dtype=jnp.int32), eps_per_team)

    def episode(key: jax.Array, partner: jax.Array) -> Any:
        k0, k1 = jax.random.split(key)
        state, obs = env.reset(k0, partner)

        def body(c: tuple, k: jax.Array) -> tuple:
            state, obs, pa, pr, t = c
            ka, ks = jax.random.split(k)
            a = jax.random.randint(ka, (), 0, spec.num_actions, dtype=jnp.int32)
            x = LocalStep(obs=obs, prev_action=pa, prev_reward=pr, t=t, first=t == 0)
            state, ts = env.step(ks, state, a)
            return (state, ts.obs, a, ts.reward, t + 1), (x, ts.record)

        zero_i, zero_f = jnp.zeros((), jnp.int32), jnp.zeros((), jnp.float32)
        init = (state, obs, zero_i, zero_f, zero_i)
        return jax.lax.scan(body, init, jax.random.split(k1, spec.episode_len))[1]

    keys = jax.random.split(jax.random.key(seed), team.shape[0])
    return jax.jit(jax.vmap(episode))(keys, team)  # type: ignore[no-any-return]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="a run's seed directory (its model and settings)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--episodes", type=int, default=256, help="training episodes per team")
    ap.add_argument("--test-episodes", type=int, default=64, help="held-out episodes per team")
    ap.add_argument("--batch", type=int, default=32, help="episodes per update")
    ap.add_argument("--updates", type=int, default=600)
    ap.add_argument("--every", type=int, default=150, help="updates between evaluations")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    config = load_run_config(args.run)
    env, model = env_and_model(config)
    spec = env.spec
    train_x, train_y = collect(env, args.episodes, 1)
    test_x, test_y = collect(env, args.test_episodes, 2)
    num_train = train_x.obs.shape[0]

    tx = make_optimizers(config)[1]  # the agent model's, as the trainer builds it

    def loss(p: Any, xs: Any, ys: Any, key: jax.Array) -> Any:
        return model.loss(p, batch_carry(model.init_carry(spec), xs.obs.shape[1]), xs, ys, key)

    @jax.jit
    def update(p: Any, o: Any, key: jax.Array, xs: Any, ys: Any) -> tuple[Any, Any, jax.Array]:
        kb, kd = jax.random.split(key)
        idx = jax.random.choice(kb, num_train, (args.batch,), replace=False)
        pick = lambda v: jnp.swapaxes(v[idx], 0, 1)
        (value, _), g = jax.value_and_grad(loss, has_aux=True)(
            p, jax.tree.map(pick, xs), jax.tree.map(pick, ys), kd
        )
        u, o = tx.update(g, o, p)
        return optax.apply_updates(p, u), o, value

    @jax.jit
    def score(p: Any, xs: Any, ys: Any) -> jax.Array:
        def one(x: Any, y: Any) -> jax.Array:
            _, logits = model.decode(p, model.embed_rollout(p, model.init_carry(spec), x))
            return jnp.mean(jnp.argmax(logits, -1) == y.other_actions, -1)  # [T]

        return jnp.mean(jax.vmap(one)(xs, ys), 0)

    def report(tag: str, p: Any, extra: dict[str, Any]) -> None:
        by = np.asarray(score(p, test_x, test_y))
        rec = {"tag": tag, "accuracy": float(by.mean()), "by_step": by.round(4).tolist(), **extra}
        with (args.out / "log.jsonl").open("a") as f:
            f.write(json.dumps(rec) + "\n")
        print(tag, f"{rec['accuracy']:.4f}", extra, flush=True)

    w = restore_weights(config, args.run, None, [])
    report("rl_checkpoint", w.model_params, {"step": w.step})
    p = model.init(jax.random.key(0), spec)
    o = tx.init(p)
    key = jax.random.key(3)
    t0 = time.time()
    for u in range(1, args.updates + 1):
        key, k = jax.random.split(key)
        p, o, value = update(p, o, k, train_x, train_y)
        if u % args.every == 0:
            windows = u * args.batch * spec.episode_len
            extra = {"updates": u, "windows": windows, "loss": float(value)}
            report("supervised", p, {**extra, "seconds": round(time.time() - t0)})


if __name__ == "__main__":
    main()
