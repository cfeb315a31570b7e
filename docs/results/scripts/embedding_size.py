"""The size of the embedding z each agent model hands the policy, beside the observation's.

The policy reads concat(o_t, z_t). TransAM's encoder is post-norm, so z is a LayerNorm output:
|z| = sqrt(width) (11.3 at width 128) whatever the window, and at initialisation it changes
from step to step by about one unit per feature. LIAM's z is an LSTM encoder's, about 1. This
prints, per environment, the mean |o_t| and, for TransAM and LIAM at initialisation, the mean
|z_t|, the per-feature standard deviation of z over the steps and its largest entry, on one
random-play rollout against the default population (60 steps; seconds on a CPU).

    python docs/results/scripts/embedding_size.py overcooked spread tag lbf
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp

from transam import make_env, make_model
from transam.envs.core import ControlledEnv
from transam.models.base import LocalStep


def random_rollout(env_name: str, steps: int, seed: int) -> tuple[ControlledEnv, LocalStep]:
    """(env, the controlled agent's LocalSteps [steps]) under uniformly random actions."""
    env = make_env(env_name)
    key = jax.random.key(seed)
    state, obs = env.reset(key)
    rows, action, reward, first, t = [], 0, 0.0, True, 0
    for _ in range(steps):
        k_act, k_step, key = jax.random.split(key, 3)
        rows.append(
            LocalStep(
                obs=obs,
                prev_action=jnp.int32(action),
                prev_reward=jnp.float32(reward),
                t=jnp.int32(t),
                first=jnp.bool_(first),
            )
        )
        action = int(jax.random.randint(k_act, (), 0, env.spec.num_actions))
        state, ts = env.step(k_step, state, action)
        reward, first = float(ts.reward), bool(ts.done)
        t, obs = (0 if first else t + 1), ts.obs
    return env, jax.tree.map(lambda *v: jnp.stack(v), *rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("envs", nargs="+")
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(
        "| environment | obs dim | mean abs(o) | model | mean abs(z) | z std, steps | max abs z |"
    )
    print("|---|---|---|---|---|---|---|")
    for name in args.envs:
        env, xs = random_rollout(name, args.steps, args.seed)
        obs_norm = float(jnp.linalg.norm(xs.obs, axis=-1).mean())
        for method in ("transam", "liam"):
            model = make_model(method, env.spec)
            params = model.init(jax.random.key(args.seed + 1), env.spec)
            z = model.embed_rollout(params, model.init_carry(env.spec), xs)
            print(
                f"| {name} | {env.spec.obs_dim} | {obs_norm:.1f} | {method} | "
                f"{float(jnp.linalg.norm(z, axis=-1).mean()):.2f} | {float(z.std(0).mean()):.3f} | "
                f"{float(jnp.abs(z).max()):.2f} |"
            )


if __name__ == "__main__":
    main()
