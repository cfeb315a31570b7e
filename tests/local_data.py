"""Shared test data: the smoke grid every grid test uses (conftest builds it), and what the
trainer's execution path sees, from a uniformly random agent."""

from __future__ import annotations

from functools import partial
from typing import Any

import jax

from transam.envs.core import ControlledEnv, PartnerRecord
from transam.models.base import LocalStep, PartnerView
from transam.train import a2c

SMOKE_ENVS, SMOKE_METHODS, SMOKE_SEEDS = ["spread"], ["nam", "liam"], [0, 1]
SMOKE_ARGS = [
    *("--envs", *SMOKE_ENVS),
    *("--methods", *SMOKE_METHODS),
    *("--seeds", *map(str, SMOKE_SEEDS)),
]
"""The `transam reproduce` arguments of the smoke grid (with --budget smoke)."""


@partial(jax.jit, static_argnums=(0, 2, 3))
def random_rollout(
    env: ControlledEnv, key: jax.Array, num_envs: int, num_steps: int, partners: Any = None
) -> tuple[LocalStep, PartnerView, PartnerRecord]:
    """``num_envs`` environments (first episodes' partners ``partners`` [num_envs], or drawn),
    ``num_steps`` random steps, built as the trainer builds them (``a2c.env_step``):
    (LocalSteps, the Oracle's partner views, training-only records), time-major [T, N]."""
    k_reset, k_run = jax.random.split(key)
    reset_keys = jax.random.split(k_reset, num_envs)
    if partners is None:
        state, obs = jax.vmap(env.reset)(reset_keys)
    else:
        state, obs = jax.vmap(env.reset)(reset_keys, partners)

    def body(carry: Any, key: jax.Array) -> Any:
        state, x = carry
        k_act, k_env = jax.random.split(key)
        action = jax.random.randint(k_act, (num_envs,), 0, env.spec.num_actions)
        view = PartnerView(state.other_obs, state.other_prev_actions)
        state, ts, x_next = a2c.env_step(env, k_env, state, action)
        return (state, x_next), (x, view, ts.record)

    init = (state, a2c.first_step(obs))
    return jax.lax.scan(body, init, jax.random.split(k_run, num_steps))[1]
