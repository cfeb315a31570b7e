"""Evaluation: N episodes in parallel, one per environment copy, partners drawn uniformly.

Each copy plays exactly one episode (``episode_len`` steps; steps after an early termination
are masked out). Actions are sampled from the policy by default: A2C trains a stochastic policy
and the reference code evaluates it as it acts; ``greedy=True`` takes the argmax instead.

For a model with a decoder, every step also scores ``decode(z_t, o^{-1}_t)`` against the step's
training-only :class:`PartnerRecord`: other-agent action accuracy (argmax of the logits,
averaged over agents and steps) where it predicts actions, and the MSE of the predicted joint
other-agent observation (averaged over its entries and the steps) where it reconstructs them;
a metric the model does not predict is absent. Per-step curves over the in-episode time are
returned too (``per_step/...``) for later reports.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from transam.envs.core import ControlledEnv
from transam.models.base import AgentModel
from transam.train.a2c import act, batch_carry, env_step, first_step, make_policy
from transam.train.config import TrainConfig

EvalFn = Callable[[Any, Any, jax.Array], dict[str, jax.Array]]


def make_evaluate(config: TrainConfig, env: ControlledEnv, model: AgentModel) -> EvalFn:
    """A jitted ``(policy_params, model_params, key) -> metrics`` over ``config.eval.episodes``
    episodes. Metrics: ``return`` (mean), ``return_std`` and, with a decoder,
    ``action_accuracy`` and ``obs_mse`` where the model predicts them."""
    n = config.eval.episodes
    length = env.spec.episode_len
    policy = make_policy(config, env)
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
            pc, mc, z, logits, _ = act(
                policy, model, policy_params, model_params, pc, mc, x, env_state
            )
            if greedy:
                action = jnp.argmax(logits, -1).astype(jnp.int32)
            else:
                action = jax.random.categorical(k_act, logits).astype(jnp.int32)
            env_state, ts, x = env_step(env, k_env, env_state, action)
            live = alive.astype(jnp.float32)
            rec = ts.record
            obs_pred, act_logits = jax.vmap(model.decode, in_axes=(None, 0, 0))(
                model_params, z, rec.other_obs
            )
            scores = {}
            if act_logits is not None:
                correct = jnp.argmax(act_logits, -1) == rec.other_actions
                scores["action_accuracy"] = correct.mean(-1) * live
            if obs_pred is not None:
                err = (obs_pred - rec.other_obs.reshape(n, -1)) ** 2
                scores["obs_mse"] = err.mean(-1) * live
            return (env_state, x, pc, mc, alive & ~ts.done), (ts.reward * live, live, scores)

        _, (reward, live, scores) = jax.lax.scan(body, init, jax.random.split(k_run, length))
        returns = reward.sum(0)
        per_t = jnp.maximum(live.sum(1), 1.0)
        out = {"return": returns.mean(), "return_std": returns.std()}
        for k, v in scores.items():
            out[k] = v.sum() / live.sum()
            out[f"per_step/{k}"] = v.sum(1) / per_t
        return out

    return jax.jit(evaluate)
