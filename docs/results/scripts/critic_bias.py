"""The end-of-episode critic bias, with and without the policy's clock.

See docs/notes/2026-11-critic-end-of-episode-bias.md.

Trains NAM on Spread against the heuristic partners with the reference A2C settings (shared
actor-critic trunk; only the clock varies) for
``--updates`` updates and prints the mean advantage (in units of the return std) of each
update's position inside the 25-step episode: the 10 environments run in lock step, so update
k of an episode always covers its steps 5k .. 5k+4. An unbiased critic gives about 0 at every
position. Run: ``python docs/results/scripts/critic_bias.py`` (about 2 minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import numpy as np

from transam.train.a2c import init_runner, make_update, steps_per_update
from transam.train.config import A2CConfig, TrainConfig
from transam.train.programs import env_and_model


def advantage_by_phase(time_feature: bool, updates: int, seed: int) -> np.ndarray:
    a2c = A2CConfig(time_feature=time_feature, critic_z=True)  # the reference's shared trunk
    config = TrainConfig(env="spread", method="nam", partners="heuristic", a2c=a2c)
    config = dataclasses.replace(config, total_steps=updates * steps_per_update(config))
    env, model = env_and_model(config)
    update = make_update(config, env, model)
    run = jax.jit(lambda rs: jax.lax.scan(lambda s, _: update(s), rs, None, length=updates))
    _, metrics = run(init_runner(config, env, model, jax.random.key(seed)))
    per_update = np.asarray(metrics["advantage_mean"])
    phases = env.spec.episode_len // config.a2c.n_steps
    last_half = per_update[updates // 2 :]  # after the critic has had time to fit
    return last_half[: len(last_half) // phases * phases].reshape(-1, phases).mean(0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--updates", type=int, default=6000)
    parser.add_argument("--seeds", type=int, default=2)
    args = parser.parse_args()
    for time_feature in (False, True):
        for seed in range(args.seeds):
            adv = advantage_by_phase(time_feature, args.updates, seed)
            cells = "  ".join(f"{a:+.3f}" for a in adv)
            print(
                f"clock={'on ' if time_feature else 'off'} seed {seed}: steps 0-4 .. 20-24: {cells}"
            )


if __name__ == "__main__":
    main()
