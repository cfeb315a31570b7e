"""Agent models scored on the same episodes: is one model's lower accuracy the model's, or the
states its own policy visits? Each run given plays N episodes with its policy and its agent
model (no dropout, actions sampled as in every evaluation, the same partner teams and seeds
for every actor); then every run's agent model reads those episodes (its own encoder on the
actor's local data, from each episode's start; no dropout) and is scored on the partners'
actions at the newest position, overall and by step. A model gap shows on every actor's
episodes; a state gap shows only across them. Runs must play the same game and population.

    python docs/results/scripts/same_episodes.py RUN_A RUN_B [...] --episodes 500 \
        --out runs/same-episodes/a-b.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from transam.evaluation.final import balanced_partners
from transam.evaluation.weights import restore_weights
from transam.rundir import load_run_config
from transam.train.a2c import act, batch_carry, env_step, first_step, make_policy
from transam.train.programs import env_and_model


def load(run: Path) -> dict[str, Any]:
    config = load_run_config(run)
    env, model = env_and_model(config)
    w = restore_weights(config, run, None, [])
    return {"run": str(run), "config": config, "env": env, "model": model, "w": w}


def play(r: dict[str, Any], partner: np.ndarray, seed: int) -> tuple[Any, Any, jax.Array, Any]:
    """(LocalStep [T, N], PartnerRecord [T, N], live [T, N], hits [T, N]) of N episodes acted
    by run ``r``; hits: its own model's right guesses on the embeddings it acted on (a check
    of :func:`score`, which encodes the episodes again)."""
    env, model, w = r["env"], r["model"], r["w"]
    policy = make_policy(r["config"], env)
    n = len(partner)

    @jax.jit
    def episodes(key: jax.Array) -> tuple[Any, Any, jax.Array, jax.Array]:
        k_reset, k_run = jax.random.split(key)
        state, obs = jax.vmap(env.reset)(jax.random.split(k_reset, n), jnp.asarray(partner))
        init = (
            state,
            first_step(obs),
            policy.init_carry((n,)),
            batch_carry(model.init_carry(env.spec), n),
            jnp.ones((n,), bool),
        )

        def body(carry: tuple[Any, ...], key: jax.Array) -> tuple[tuple[Any, ...], Any]:
            state, x, pc, mc, alive = carry
            k_act, k_env = jax.random.split(key)
            pc, mc, z, logits, _ = act(
                policy, model, w.policy_params, w.model_params, pc, mc, x, state
            )
            action = jax.random.categorical(k_act, logits).astype(jnp.int32)
            state, ts, x_next = env_step(env, k_env, state, action)
            rec = ts.record
            _, guess = jax.vmap(model.decode, in_axes=(None, 0, 0))(
                w.model_params, z, rec.other_obs
            )
            hits = jnp.mean(jnp.argmax(guess, -1) == rec.other_actions, -1)
            return (state, x_next, pc, mc, alive & ~ts.done), (x, rec, alive, hits)

        keys = jax.random.split(k_run, env.spec.episode_len)
        return jax.lax.scan(body, init, keys)[1]

    return episodes(jax.random.key(seed))


def by_step(hits: Any, live: Any) -> np.ndarray:
    """Mean of ``hits`` [T, N] over the live episodes at each step: [T]."""
    w = np.asarray(live, np.float64)
    return (np.asarray(hits) * w).sum(1) / np.maximum(w.sum(1), 1.0)


def score(r: dict[str, Any], xs: Any, rec: Any, live: jax.Array) -> np.ndarray:
    """Accuracy [T] of run ``r``'s agent model on the episodes (xs, rec time-major [T, N])."""
    model, params = r["model"], r["w"].model_params

    def one(x: Any, y: Any) -> jax.Array:  # one episode, [T, ...]
        z = model.embed_rollout(params, model.init_carry(r["env"].spec), x)
        _, logits = jax.vmap(model.decode, in_axes=(None, 0, 0))(params, z, y.other_obs)
        return jnp.mean(jnp.argmax(logits, -1) == y.other_actions, -1)  # [T]

    swap = lambda v: jnp.swapaxes(v, 0, 1)  # [T, N] <-> [N, T]
    hits = jax.jit(jax.vmap(one))(jax.tree.map(swap, xs), jax.tree.map(swap, rec))
    return by_step(swap(hits), live)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="run seed directories")
    ap.add_argument("--episodes", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    runs = [load(run) for run in args.runs]
    games = {(r["config"].env, str(r["config"].partners)) for r in runs}
    if len(games) != 1:
        raise SystemExit(f"the runs play different games or populations: {sorted(games)}")
    partner = balanced_partners(args.episodes, runs[0]["env"].num_partners).astype(np.int32)
    out: dict[str, Any] = {"episodes": args.episodes, "seed": args.seed, "actors": {}}
    for actor in runs:
        xs, rec, live, hits = play(actor, partner, args.seed)
        steps = np.asarray(live, np.float64).sum(1)
        by_model = {}
        for r in runs:
            acc = score(r, xs, rec, live)
            if r is actor and not np.allclose(acc, by_step(hits, live), atol=2e-3):
                raise SystemExit(f"{r['run']}: encoding the episodes again gave other guesses")
            overall = float((acc * steps).sum() / steps.sum())
            by_model[r["run"]] = {"accuracy": overall, "by_step": acc.round(4).tolist()}
            print(f"actor {actor['run']}: model {r['run']}: {overall:.4f}", flush=True)
        out["actors"][actor["run"]] = by_model
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
