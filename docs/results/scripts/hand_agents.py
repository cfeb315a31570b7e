"""Hand-written controlled agents against partner populations, one set per game: uniformly
random play and simple rules on the controlled agent's own observation. Prints each one's mean
episode return ± its standard error (std / sqrt(episodes)), one episode per parallel copy.

    python docs/results/scripts/hand_agents.py --envs spread tag lbf overcooked
    python docs/results/scripts/hand_agents.py default runs/authors-pop       # Spread, as before

The agents (issue 36, learnability):

* Spread (agent 2): always "no move", head for the nearest landmark, the landmark rule
  (docs/notes/2026-12-slow-policy-learning-default-population.md; also
  docs/results/scripts/simple_agents.py, which this replaces with the same numbers).
* Tag (the prey): always "no move"; ``flee``: away from the nearest visible predator, else
  toward the centre (transam.partners.tag.flee_prey, the stand-in the held-out predators
  trained against); ``flee in bounds``: the same, but first back toward the centre whenever
  the prey is (about to be) near the -10 boundary (transam.partners.tag.flee_in_bounds).
  Tag's return is printed as the game and `transam evaluate` report it (with the -10 boundary
  penalty), and in brackets without it (LIAM's evaluation rule, ``strip_boundary_penalty``).
* LBF (agent 0): lbforaging's heuristics as the controlled agent (transam.partners.lbf):
  H1 (nearest food), H2 (food nearest the players' centroid), H3 (nearest food it can load
  alone, level <= its own).
* Overcooked (agent_0): the scripted cooks of transam.partners.overcooked played as the
  controlled cook (each with a 5% random action): full cook (the whole cycle alone), onion
  carrier, dish carrier.

"random" is uniform over the game's actions (what `transam envs rollout` plays). Every agent
plays the same episodes (same key: same starts, same partner teams) of a population.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from transam.compose import make_env
from transam.envs.rollout import make_random_rollout
from transam.partners import lbf as lbf_partners
from transam.partners import overcooked as oc_partners
from transam.partners import tag as tag_partners
from transam.partners.spread import landmark_agent, landmark_offsets, move_toward

Policy = Callable[[jax.Array, jax.Array], jax.Array] | None


def nearest_landmark(key: jax.Array, obs: jax.Array) -> jax.Array:
    del key
    offsets = landmark_offsets(obs)
    return move_toward(offsets[jnp.argmin(jnp.linalg.norm(offsets, axis=-1))])


def no_move(key: jax.Array, obs: jax.Array) -> jax.Array:
    del key, obs
    return jnp.int32(0)


def lbf_agents() -> dict[str, Policy]:
    from transam.envs.lbf import Config

    config = Config()  # the learned populations play the default game only
    return {
        "random": None,
        "H1 nearest food": lbf_partners.heuristic(False, None, config),
        "H2 centroid food": lbf_partners.heuristic(True, None, config),
        "H3 loadable food": lbf_partners.heuristic(False, "own", config),
    }


AGENTS: dict[str, Callable[[], dict[str, Policy]]] = {
    "spread": lambda: {
        "random": None,
        "no move": no_move,
        "nearest landmark": nearest_landmark,
        "landmark rule": landmark_agent,
    },
    "tag": lambda: {
        "random": None,
        "no move": no_move,
        "flee": tag_partners.flee_prey,
        "flee in bounds": tag_partners.flee_in_bounds,
        "stay in bounds": tag_partners.stay_in_bounds,
    },
    "lbf": lbf_agents,
    "overcooked": lambda: {
        "random": None,
        "full cook": oc_partners.scripted(oc_partners.full_cook_task),
        "onion carrier": oc_partners.scripted(oc_partners.onion_carrier_task),
        "dish carrier": oc_partners.scripted(oc_partners.dish_carrier_task),
    },
}


def first_episode_returns(reward: np.ndarray, done: np.ndarray) -> np.ndarray:
    """The return of each column's first episode ([T, N] rewards and done flags; T is the
    episode limit, so every first episode ends inside). Later episodes are dropped: in a game
    with early ends (LBF) they would favour short episodes."""
    if not done.any(axis=0).all():
        raise ValueError("a column's first episode did not end inside the rollout")
    end = np.argmax(done, axis=0)
    upto = np.arange(reward.shape[0])[:, None] <= end[None, :]
    return np.sum(np.where(upto, reward, 0.0), axis=0, dtype=np.float64)


def play(env_name: str, population: str, episodes: int, seed: int) -> list[tuple[str, str]]:
    """(agent, formatted return ± s.e.) rows for one env and population."""
    env = make_env(env_name, partners=population)
    digits = 4 if env_name == "lbf" else 2
    rows = []
    for name, policy in AGENTS[env_name]().items():
        rollout = make_random_rollout(env, episodes, env.spec.episode_len, policy)
        ts = rollout(jax.random.key(seed))[1]
        reward, done = np.asarray(ts.reward), np.asarray(ts.done)
        r = first_episode_returns(reward, done)
        text = f"{r.mean():7.{digits}f} ± {r.std() / np.sqrt(len(r)):.{digits}f}"
        if env_name == "tag":
            from transam.envs.tag import strip_boundary_penalty

            s = first_episode_returns(np.asarray(strip_boundary_penalty(ts.reward)), done)
            text += f"  (no boundary penalty {s.mean():6.2f} ± {s.std() / np.sqrt(len(s)):.2f})"
        rows.append((name, text))
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "positional", nargs="*", help="Spread populations (the old simple_agents.py form)"
    )
    parser.add_argument("--envs", nargs="+", default=None, choices=sorted(AGENTS))
    parser.add_argument(
        "--populations",
        nargs="+",
        default=["default", "heldout"],
        help="'default', 'heldout' or a population directory (for one env)",
    )
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument(
        "--overcooked-episodes",
        type=int,
        default=None,
        help="Overcooked's count (default: --episodes)",
    )
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args(argv)
    if args.positional:  # simple_agents.py's form and output: Spread only
        for pop in args.positional:
            for name, text in play("spread", pop, args.episodes, args.seed):
                print(f"{pop:20s} {name:18s} {text}")
        return
    print(f"mean episode return ± standard error; seed {args.seed}; {os.cpu_count()} cpus")
    for env_name in args.envs or ["spread", "tag", "lbf", "overcooked"]:
        n = args.episodes
        if env_name == "overcooked" and args.overcooked_episodes:
            n = args.overcooked_episodes
        for pop in args.populations:
            for name, text in play(env_name, pop, n, args.seed):
                print(f"{env_name:11s} {pop:10s} {n:5d} eps  {name:18s} {text}", flush=True)


if __name__ == "__main__":
    main()
