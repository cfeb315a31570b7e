"""Evaluation: N episodes in parallel, one per environment copy, partners drawn uniformly.

Each copy plays exactly one episode (``episode_len`` steps; steps after an early termination
are masked out). Actions are sampled from the policy by default: A2C trains a stochastic policy
and the reference code evaluates it as it acts; ``greedy=True`` takes the argmax instead.

For a model with a reconstruction head (``decode`` not None), every step also scores
``decode(z_t)`` against the step's training-only :class:`PartnerRecord`: other-agent action
accuracy (argmax of the logits, averaged over agents and steps) and the MSE of the predicted
joint other-agent observation (averaged over its entries and the steps). Per-step curves over
the in-episode time are returned too (``per_step/...``) for later reports.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

import jax
import jax.numpy as jnp

from transam.envs.core import ControlledEnv
from transam.models.base import AgentModel
from transam.train.a2c import act, batch_carry, env_step, first_step, make_policy
from transam.train.config import TrainConfig

EvalFn = Callable[[Any, Any, jax.Array], dict[str, jax.Array]]


def has_decoder(model: AgentModel, env: ControlledEnv) -> bool:
    """Whether the model has a reconstruction head (checked abstractly, no computation)."""
    key = jax.random.key(0)
    params = jax.eval_shape(lambda: model.init(key, env.spec))
    z = jax.ShapeDtypeStruct((model.embed_dim,), jnp.float32)
    found = []

    def probe(p: Any, z: jax.Array) -> int:
        found.append(model.decode(p, z) is not None)
        return 0

    jax.eval_shape(probe, params, z)
    return found[0]


def make_evaluate(config: TrainConfig, env: ControlledEnv, model: AgentModel) -> EvalFn:
    """A jitted ``(policy_params, model_params, key) -> metrics`` over ``config.eval.episodes``
    episodes. Metrics: ``return`` (mean), ``return_std`` and, with a decoder,
    ``action_accuracy`` and ``obs_mse`` (NaN without one)."""
    n = config.eval.episodes
    length = env.spec.episode_len
    policy = make_policy(config, env)
    decoder = has_decoder(model, env)
    greedy = config.eval.greedy

    def evaluate(policy_params: Any, model_params: Any, key: jax.Array) -> dict[str, jax.Array]:
        k_reset, k_run = jax.random.split(key)
        env_state, obs = jax.vmap(env.reset)(jax.random.split(k_reset, n))
        init = (
            env_state,
            first_step(obs),
            policy.init_carry((n,)),
            batch_carry(model.init_carry(env.spec), n),
            jnp.ones((n,), bool),
        )

        def body(carry: tuple[Any, ...], key: jax.Array) -> tuple[tuple[Any, ...], Any]:
            env_state, x, pc, mc, alive = carry
            k_act, k_env = jax.random.split(key)
            pc, mc, z, logits, _ = act(policy, model, policy_params, model_params, pc, mc, x)
            if greedy:
                action = jnp.argmax(logits, -1).astype(jnp.int32)
            else:
                action = jax.random.categorical(k_act, logits).astype(jnp.int32)
            env_state, ts, x = env_step(env, k_env, env_state, action)
            live = alive.astype(jnp.float32)
            if decoder:
                decoded = jax.vmap(model.decode, in_axes=(None, 0))(model_params, z)
                obs_pred, act_logits = cast(tuple[jax.Array, jax.Array], decoded)
                target = ts.record.other_obs.reshape(n, -1)
                mse = ((obs_pred - target) ** 2).mean(-1)
                acc = (jnp.argmax(act_logits, -1) == ts.record.other_actions).mean(-1)
            else:
                mse = acc = jnp.full((n,), jnp.nan)
            out = (ts.reward * live, live, acc * live, mse * live)
            return (env_state, x, pc, mc, alive & ~ts.done), out

        _, (reward, live, acc, mse) = jax.lax.scan(body, init, jax.random.split(k_run, length))
        returns = reward.sum(0)
        steps = live.sum()
        per_t = jnp.maximum(live.sum(1), 1.0)
        return {
            "return": returns.mean(),
            "return_std": returns.std(),
            "action_accuracy": acc.sum() / steps,
            "obs_mse": mse.sum() / steps,
            "per_step/action_accuracy": acc.sum(1) / per_t,
            "per_step/obs_mse": mse.sum(1) / per_t,
        }

    return jax.jit(evaluate)
