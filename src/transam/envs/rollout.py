"""Jitted rollouts of a controlled-agent environment with a uniformly random controlled agent
(or a given fixed policy of the controlled agent's observation).

Used by the demo, the environment benchmark and the tests: one ``lax.scan`` over time of a
``vmap`` over environments, so no Python runs per environment step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from transam.envs.core import ControlledEnv, EnvError, EnvState, Timestep
from transam.envs.starts import Starts

Rollout = Callable[[jax.Array], tuple[EnvState, Timestep]]


def make_random_rollout(
    env: ControlledEnv,
    num_envs: int,
    num_steps: int,
    policy: Callable[[jax.Array, jax.Array], jax.Array] | None = None,
    starts: Starts | None = None,
) -> Rollout:
    """A jitted ``key -> (final states, timesteps [num_steps, num_envs])`` function; the
    controlled agent plays uniformly at random, or ``policy(key, obs) -> action`` when given.
    With ``starts`` (``num_envs`` of them) the first episodes begin there."""
    n_act = env.spec.num_actions
    if starts is not None and starts.episodes != num_envs:
        raise EnvError(f"{starts.episodes} starts for {num_envs} environment copies")

    def run(key: jax.Array) -> tuple[EnvState, Timestep]:
        key_reset, key_run = jax.random.split(key)
        if starts is None:
            states, obs = jax.vmap(env.reset)(jax.random.split(key_reset, num_envs))
        else:
            states, obs = jax.vmap(env.reset_to)(starts.game, jnp.asarray(starts.team))

        def one_step(
            carry: tuple[EnvState, jax.Array], key: jax.Array
        ) -> tuple[tuple[EnvState, jax.Array], Timestep]:
            states, obs = carry
            key_act, key_env = jax.random.split(key)
            if policy is None:
                actions = jax.random.randint(key_act, (num_envs,), 0, n_act, dtype=jnp.int32)
            else:
                actions = jax.vmap(policy)(jax.random.split(key_act, num_envs), obs)
            states, ts = jax.vmap(env.step)(jax.random.split(key_env, num_envs), states, actions)
            return (states, ts.obs), ts

        (states, _), ts = jax.lax.scan(
            one_step, (states, obs), jax.random.split(key_run, num_steps)
        )
        return states, ts

    return jax.jit(run)


@dataclass(frozen=True)
class EpisodeStats:
    """Returns of the episodes completed in a rollout, with each episode's partner index."""

    returns: np.ndarray  # [episodes] float
    partners: np.ndarray  # [episodes] int

    def by_partner(self, num_partners: int) -> list[np.ndarray]:
        return [self.returns[self.partners == m] for m in range(num_partners)]


def episode_stats(timesteps: Timestep) -> EpisodeStats:
    """Per-episode returns from timesteps [T, N]; episodes unfinished at the end are dropped."""
    reward = np.asarray(timesteps.reward)
    done = np.asarray(timesteps.done)
    partner = np.asarray(timesteps.record.partner)
    # Return of episode k in column n = cumulative reward at its end minus that at its start.
    cum = np.cumsum(reward, axis=0, dtype=np.float64)
    returns, partners = [], []
    for n in range(reward.shape[1]):
        ends = np.flatnonzero(done[:, n])
        before = np.concatenate([[0.0], cum[ends, n]])[:-1]
        returns.append(cum[ends, n] - before)
        partners.append(partner[ends, n])
    return EpisodeStats(np.concatenate(returns), np.concatenate(partners))


def steps_per_second(
    env: ControlledEnv, num_envs: int, num_steps: int, repeats: int
) -> list[float]:
    """Environment steps/s (summed over the vmapped copies) of each timed repeat, after a
    compile-and-warm-up run; random controlled actions, the env's partner population."""
    import time

    rollout = make_random_rollout(env, num_envs, num_steps)
    jax.block_until_ready(rollout(jax.random.key(0)))
    rates = []
    for i in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(rollout(jax.random.key(i + 1)))
        rates.append(num_envs * num_steps / (time.perf_counter() - start))
    return rates
