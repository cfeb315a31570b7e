"""Hand-written controlled agents on Spread against one or more partner populations: uniformly
random, always "no move", head for the nearest landmark, and the landmark rule. Prints each
one's mean return ± its standard error (see
docs/notes/2026-12-slow-policy-learning-default-population.md).

    python docs/results/scripts/simple_agents.py default runs/authors-pop
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from transam.compose import make_env
from transam.envs.rollout import episode_stats, make_random_rollout
from transam.partners.spread import landmark_agent, landmark_offsets, move_toward


def nearest_landmark(key: jax.Array, obs: jax.Array) -> jax.Array:
    del key
    offsets = landmark_offsets(obs)
    return move_toward(offsets[jnp.argmin(jnp.linalg.norm(offsets, axis=-1))])


def no_move(key: jax.Array, obs: jax.Array) -> jax.Array:
    del key, obs
    return jnp.int32(0)


AGENTS = {
    "random": None,
    "no move": no_move,
    "nearest landmark": nearest_landmark,
    "landmark rule": landmark_agent,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("populations", nargs="+", help="'default', 'heldout' or a directory")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    for pop in args.populations:
        env = make_env("spread", partners=pop)
        for name, policy in AGENTS.items():
            rollout = make_random_rollout(env, args.episodes, env.spec.episode_len, policy)
            r = episode_stats(rollout(jax.random.key(args.seed))[1]).returns
            print(f"{pop:20s} {name:18s} {r.mean():7.2f} ± {r.std() / np.sqrt(len(r)):.2f}")


if __name__ == "__main__":
    main()
