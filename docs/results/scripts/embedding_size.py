"""The size of the embedding z each agent model hands the policy, beside the observation's.

The policy reads concat(o_t, z_t). TransAM's encoder is post-norm, so z is a LayerNorm output:
|z| = sqrt(width) (11.3 at width 128) whatever the window, and at initialisation it changes
from step to step by about one unit per feature. LIAM's z is an LSTM encoder's, about 1. This
prints, per environment, the mean |o_t| and, for each model of --methods (TransAM and LIAM
unless told) at initialisation, the mean |z_t|, the per-feature standard deviation of z over
an episode's steps and its largest entry, on one random-play episode per partner team of the
default population (seconds on a CPU).

    python docs/results/scripts/embedding_size.py overcooked spread tag lbf \
        [--methods carl cail pel]
"""

from __future__ import annotations

import argparse
import functools

import jax
import jax.numpy as jnp
from supervised_model import collect  # whole random-play episodes as LocalSteps, jitted

from transam import make_env, make_model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("envs", nargs="+")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--methods", nargs="+", default=["transam", "liam"])
    args = parser.parse_args()
    print(
        "| environment | obs dim | mean abs(o) | model | mean abs(z) | z std, steps | max abs z |"
    )
    print("|---|---|---|---|---|---|---|")
    for name in args.envs:
        env = make_env(name)
        xs, _ = collect(env, 1, args.seed)  # [teams, episode_len]
        obs_norm = float(jnp.linalg.norm(xs.obs, axis=-1).mean())
        for method in args.methods:
            model = make_model(method, env.spec)
            params = model.init(jax.random.key(args.seed + 1), env.spec)
            embed = functools.partial(model.embed_rollout, params, model.init_carry(env.spec))
            z = jax.jit(jax.vmap(embed))(xs)
            print(
                f"| {name} | {env.spec.obs_dim} | {obs_norm:.1f} | {method} | "
                f"{float(jnp.linalg.norm(z, axis=-1).mean()):.2f} | "
                f"{float(z.std(1).mean()):.3f} | {float(jnp.abs(z).max()):.2f} |"
            )


if __name__ == "__main__":
    main()
