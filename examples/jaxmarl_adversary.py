"""Train TransAM on a JaxMARL game transam does not ship: MPE ``simple_adversary_v3``.

Three agents, two landmarks, one of them the goal. The controlled agent is the good agent
``agent_1``; its partners are the adversary ``adversary_0`` (which does not know the goal) and
the other good agent ``agent_0``, played by one of four hand-written teams below. The good
agents' reward is the adversary's distance to the goal minus the closest good agent's, so what
``agent_1`` should do depends on who it plays with: cover the goal itself when its teammate
wanders off, or lure a shadowing adversary away while its teammate covers the goal.

Everything happens from this file through the Python API: the game is the package's JaxMARL
adapter (:mod:`transam.envs.jaxmarl`) registered with :func:`transam.register_env`, then
:func:`transam.train` and :func:`transam.evaluate_run`.

    python examples/jaxmarl_adversary.py --steps 200000
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import jax
import jax.numpy as jnp
from jaxmarl.environments.mpe.simple_adversary import SimpleAdversaryMPE

import transam
from transam.envs import jaxmarl
from transam.envs.core import MPE_ACTION_NAMES, ControlledEnv
from transam.envs.population import Member, Population, Team
from transam.jaxcache import enable_compilation_cache
from transam.models import TransAMConfig
from transam.train.config import A2CConfig, EvalConfig

NAME = "jaxmarl-adversary"
CONTROLLED = "agent_1"  # partners, in slot order: adversary_0, agent_0


@dataclass(frozen=True)
class Config:
    """The game's options (training uses the defaults)."""

    max_steps: int = 25  # transitions per episode


def make_env(config: Config, population: Population) -> ControlledEnv:
    """simple_adversary seen from agent_1 (the shape :func:`transam.register_env` expects)."""
    env = SimpleAdversaryMPE(max_steps=config.max_steps)
    return jaxmarl.make_env(env, CONTROLLED, population, name=NAME, action_names=MPE_ACTION_NAMES)


# --------------------------------------------------------------------- heuristic partners
# Observations (JaxMARL): adversary [landmark 0, landmark 1, agent_0, agent_1] relative to
# itself (8); good agent [goal, landmark 0, landmark 1, adversary_0, agent_1] (10), 2-D each.


def toward(delta: jax.Array) -> jax.Array:
    """The MPE action (0 no-op, 1 -x, 2 +x, 3 -y, 4 +y) along the larger axis of ``delta``."""
    x, y = delta[0], delta[1]
    along_x = jnp.where(x > 0, 2, 1)
    along_y = jnp.where(y > 0, 4, 3)
    move = jnp.where(jnp.abs(x) > jnp.abs(y), along_x, along_y)
    return jnp.where(jnp.linalg.norm(delta) < 0.05, 0, move).astype(jnp.int32)


def adversary_nearest_landmark(key: jax.Array, obs: jax.Array) -> jax.Array:
    del key
    l0, l1 = obs[0:2], obs[2:4]
    return toward(jnp.where(jnp.linalg.norm(l0) < jnp.linalg.norm(l1), l0, l1))


def adversary_shadow(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Follow the controlled agent (agent_1)."""
    del key
    return toward(obs[6:8])


def adversary_follow_teammate(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Follow agent_0."""
    del key
    return toward(obs[4:6])


def teammate_goal(key: jax.Array, obs: jax.Array) -> jax.Array:
    del key
    return toward(obs[0:2])


def teammate_decoy(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Go to the landmark that is not the goal."""
    del key
    goal, l0, l1 = obs[0:2], obs[2:4], obs[4:6]
    return toward(jnp.where(jnp.linalg.norm(l0 - goal) > jnp.linalg.norm(l1 - goal), l0, l1))


def teammate_still(key: jax.Array, obs: jax.Array) -> jax.Array:
    del key, obs
    return jnp.zeros((), jnp.int32)


def population(config: Config) -> Population:
    """Four teams (adversary_0, agent_0) that call for different play from agent_1."""
    del config
    members = [
        Member("nearest-landmark", adversary_nearest_landmark),
        Member("shadow", adversary_shadow),
        Member("follow-teammate", adversary_follow_teammate),
        Member("goal", teammate_goal),
        Member("decoy", teammate_decoy),
        Member("still", teammate_still),
    ]
    teams = [
        Team("covered", ("nearest-landmark", "goal")),
        Team("decoyed", ("follow-teammate", "decoy")),
        Team("alone", ("shadow", "still")),
        Team("lure", ("shadow", "goal")),
    ]
    return Population("adversary-heuristic", members, teams)


def register() -> None:
    """Register the game from user code (``replace``: ``main`` may run more than once).
    ``partner_actions``: a population directory's learned members have 5 actions, so
    ``partners=DIR`` works too."""
    game = SimpleNamespace(Config=Config, make_env=make_env)
    transam.register_env(
        name=NAME,
        title="simple_adversary (JaxMARL)",
        game=game,
        episode_len=Config().max_steps,
        populations={"default": population},
        partner_actions=5,
        replace=True,
    )


def main(argv: Sequence[str] | None = None, model: TransAMConfig | None = None) -> dict[str, Any]:
    """Train, evaluate and print the evaluation table; returns evaluate_run's result.
    ``model``: the transformer's settings (default: the paper's; the test passes a tiny one)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200_000, help="training steps")
    parser.add_argument("--method", default="transam", help="agent-modeling method")
    parser.add_argument("--num-envs", type=int, default=16, help="parallel environments")
    parser.add_argument("--episodes", type=int, default=100, help="evaluation episodes")
    parser.add_argument("--out", default="", help="run directory (default: a temporary one)")
    args = parser.parse_args(argv)

    enable_compilation_cache()  # as the CLI: later runs skip most of the compile time
    register()
    config = transam.TrainConfig(
        env=NAME,  # type: ignore[arg-type]  # a registered name; the Literal lists the paper's
        method=args.method,
        total_steps=args.steps,
        out=args.out or tempfile.mkdtemp(prefix=f"{NAME}-"),
        progress=False,
        model=model or TransAMConfig(),
        a2c=A2CConfig(num_envs=args.num_envs),
        eval=EvalConfig(every_episodes=max(1, args.steps // 25 // 10), episodes=args.episodes),
    )
    result = transam.train(config)
    found = transam.evaluate_run(result.run_dir, episodes=args.episodes)

    print(f"{NAME} / {found['method']}: step {found['step']:,}, {found['episodes']} episodes")
    rows = [("return", f"{found['return']['mean']:.3f} ± {found['return']['std']:.3f}")]
    rows += [(f"  vs {team}", f"{r:.3f}") for team, r in found["per_partner_return"].items()]
    for key in ("action_accuracy_newest", "obs_mse"):
        if key in found:
            rows.append((key.replace("_", " "), f"{found[key]:.3f}"))
    if "probe" in found and found["probe"]["accuracy"] is not None:
        rows.append(("partner probe accuracy", f"{found['probe']['accuracy']:.3f}"))
        rows.append(("probe chance", f"{found['probe']['chance']:.3f}"))
    width = max(len(name) for name, _ in rows)
    for name, value in rows:
        print(f"{name:<{width}}  {value:>15}")
    print(f"run directory: {result.run_dir}")
    return found


if __name__ == "__main__":
    main()
