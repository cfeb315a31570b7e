"""Jitted rollouts of a controlled-agent environment with a uniformly random (or any given)
controlled agent.

Used by the demo, the environment benchmark and the tests: one ``lax.scan`` over time of a
``vmap`` over environments, so no Python runs per environment step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from transam.envs.core import ControlledEnv, EnvState, Timestep
from transam.envs.population import PolicyFn

Rollout = Callable[[jax.Array], tuple[EnvState, Timestep]]


def make_random_rollout(
    env: ControlledEnv, num_envs: int, num_steps: int, agent: PolicyFn | None = None
) -> Rollout:
    """A jitted ``key -> (final states, timesteps [num_steps, num_envs])`` function.

    The controlled agent acts uniformly at random, or by ``agent(key, obs)`` on its own
    observation when given (e.g. :func:`transam.partners.spread.landmark_agent`)."""
    n_act = env.spec.num_actions

    def run(key: jax.Array) -> tuple[EnvState, Timestep]:
        key_reset, key_run = jax.random.split(key)
        states, _ = jax.vmap(env.reset)(jax.random.split(key_reset, num_envs))

        def one_step(states: EnvState, key: jax.Array) -> tuple[EnvState, Timestep]:
            key_act, key_env = jax.random.split(key)
            if agent is None:
                actions = jax.random.randint(key_act, (num_envs,), 0, n_act, dtype=jnp.int32)
            else:
                keys = jax.random.split(key_act, num_envs)
                actions = jax.vmap(agent)(keys, states.obs).astype(jnp.int32)
            return jax.vmap(env.step)(jax.random.split(key_env, num_envs), states, actions)

        return jax.lax.scan(one_step, states, jax.random.split(key_run, num_steps))

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
