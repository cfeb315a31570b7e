"""The size of the embedding z each agent model hands the policy, beside the observation's.

The policy reads concat(o_t, z_t). TransAM's encoder is post-norm, so z is a LayerNorm output:
|z| = sqrt(width) (11.3 at width 128) whatever the window, and at initialisation it changes
from step to step by about one unit per feature. LIAM's z is an LSTM encoder's, about 1. This
prints, per environment, the mean |o_t| and, for each model of --methods (TransAM and LIAM
unless told) at initialisation, the mean |z_t|, the per-feature standard deviation of z over
an episode's steps and its largest entry, on one random-play episode per partner team of the
default population (seconds on a CPU). With --runs, the same for trained models: each run
directory's newest checkpoint, on random-play episodes of its own environment and partners.

    python docs/results/scripts/embedding_size.py overcooked spread tag lbf \
        [--methods carl cail pel]
    python docs/results/scripts/embedding_size.py --runs \
        runs/grid-overcooked/runs/overcooked/*/seed_0
"""

from __future__ import annotations

import argparse
import functools
from pathlib import Path

import jax
import jax.numpy as jnp
from supervised_model import collect  # whole random-play episodes as LocalSteps, jitted

from transam import make_env, make_model
from transam.envs.core import ControlledEnv
from transam.evaluation.weights import restore_weights
from transam.models.base import AgentModel, LocalStep, Params
from transam.rundir import load_run_config
from transam.train.config import ConfigError
from transam.train.programs import env_and_model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("envs", nargs="*")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--methods", nargs="+", default=["transam", "liam"])
    parser.add_argument("--runs", nargs="+", default=[], help="trained run directories")
    args = parser.parse_args()
    if not args.envs and not args.runs:
        parser.error("name environments (e.g. overcooked spread) or --runs RUN_DIR ...")
    print(
        "| environment | obs dim | mean abs(o) | model | mean abs(z) | z std, steps | max abs z |"
    )
    print("|---|---|---|---|---|---|---|")
    for name in args.envs:
        env = make_env(name)
        xs, _ = collect(env, 1, args.seed)  # [teams, episode_len]
        for method in args.methods:
            model = make_model(method, env.spec)
            params = model.init(jax.random.key(args.seed + 1), env.spec)
            _row(name, env, xs, method, model, params)
    for run in args.runs:
        try:
            config = load_run_config(run)
            env, model = env_and_model(config)
            weights = restore_weights(config, Path(run), None, [])
        except ConfigError as err:  # no run there, or no checkpoint that verifies
            parser.error(str(err))
        xs, _ = collect(env, 1, args.seed)
        _row(
            config.env,
            env,
            xs,
            f"{config.method}, {run} at {weights.step:,}",
            model,
            weights.model_params,
        )


def _row(
    name: str, env: ControlledEnv, xs: LocalStep, label: str, model: AgentModel, params: Params
) -> None:
    embed = functools.partial(model.embed_rollout, params, model.init_carry(env.spec))
    z = jax.jit(jax.vmap(embed))(xs)
    print(
        f"| {name} | {env.spec.obs_dim} | {float(jnp.linalg.norm(xs.obs, axis=-1).mean()):.1f} | "
        f"{label} | {float(jnp.linalg.norm(z, axis=-1).mean()):.2f} | "
        f"{float(z.std(1).mean()):.3f} | {float(jnp.abs(z).max()):.2f} |"
    )


if __name__ == "__main__":
    main()
