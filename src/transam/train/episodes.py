"""Evaluation episodes: the rollout of N episodes in parallel, one per environment copy, that
both the evaluation during training (:func:`make_evaluate`, every chunk) and the final
evaluation of a run (:mod:`transam.evaluation`, ``transam evaluate``) play.

Each copy plays exactly one episode (``episode_len`` steps; steps after an early termination
are masked out). Actions are sampled from the policy by default: A2C trains a stochastic policy
and the reference code evaluates it as it acts; ``greedy=True`` takes the argmax instead.
With ``a2c.act_dropout`` the agent model keeps its dropout on here too, as the reference
evaluates. Partners are drawn uniformly during training (as the training episodes draw
them); the final evaluation passes one partner index per
episode instead.

For a model with a decoder, every step also scores ``decode(z_t, o^{-1}_t)`` against the step's
training-only :class:`PartnerRecord`: other-agent action accuracy (argmax of the logits,
averaged over agents and steps) where it predicts actions, and the MSE of the predicted joint
other-agent observation (averaged over its entries and the steps) where it reconstructs them;
a metric the model does not predict is absent. The accuracy is ``action_accuracy_newest``: the
decoder on the z the policy acted on, i.e. the newest window position (the authors' evaluation
metric); ``obs_mse`` likewise. With ``positions=True`` (the final evaluation only: it encodes
each window a second time) a model that decodes every window position (TransAM, -fuse, -im)
also gets ``action_accuracy_all_positions`` / ``obs_mse_all_positions``: per step, the mean
over the valid positions of the window ending there (each against its own step's partners),
then averaged over steps like the others (each window weighs the same). Every step also
scores the policy's entropy (:data:`POLICY_ENTROPY`). Per-step curves over the in-episode time
are returned too (``per_step/...``) for later reports.

:func:`make_episodes` is the one rollout both use: it returns the per-step arrays (reward, live
mask, scores, embeddings z, partner ids), and :func:`make_evaluate` reduces them to the
training-time summary inside jit, where XLA drops the outputs the summary does not use (z).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from transam.envs.core import ControlledEnv
from transam.models.base import ACC_ALL, ACC_NEWEST, MSE_ALL, AgentModel
from transam.models.transam import TransAM
from transam.train.a2c import (
    act,
    batch_carry,
    env_step,
    first_step,
    make_policy,
    policy_entropy,
)
from transam.train.config import TrainConfig

POLICY_ENTROPY = "policy_entropy"
"""The per-step score of the policy's own entropy (nats; every method has it): where in the
episode the policy is decided and where it is near uniform."""

OBS_NORM, Z_NORM = "obs_norm", "z_norm"
"""The per-step sizes of the policy's two inputs, concat(o_t, z_scale * z_t): |o_t| and
|z_scale * z_t| (Euclidean; NAM's z is its previous action, one-hot). An embedding far
larger than the observation drowns it in the policy's first layer (TransAM's LayerNorm z is
sqrt(width) = 11.3; CARL's contrastive z grows as it trains): docs/results/overcooked."""
INPUT_SIZES = (OBS_NORM, Z_NORM)

EvalFn = Callable[[Any, Any, jax.Array], dict[str, jax.Array]]


@struct.dataclass
class Episodes:
    """Per-step arrays of N evaluation episodes, time-major ([T, N, ...])."""

    reward: jax.Array  # [T, N] controlled-agent reward, 0 after the episode ended
    live: jax.Array  # [T, N] float: 1 while the episode runs (step t belongs to it)
    z: jax.Array  # [T, N, embed_dim] the embedding the policy acted on at t
    partner: jax.Array  # [N] int32 partner index of each episode
    scores: dict[str, jax.Array]  # [T, N] per-step metrics where predicted, 0 when dead
    action: jax.Array  # [T, N] int32 the controlled agent's action (meaningless when dead)


EpisodesFn = Callable[..., Episodes]
"""``(policy_params, model_params, key, partner=None, start=None) -> Episodes``."""


def make_episodes(
    config: TrainConfig, env: ControlledEnv, model: AgentModel, n: int, positions: bool = False
) -> EpisodesFn:
    """``(policy_params, model_params, key, partner, start) -> Episodes`` of ``n`` episodes
    (pure; not jitted). ``partner`` ([n] int32) fixes each episode's partner; None draws them
    uniformly. ``start`` (the game's state, leading axis n; with ``partner``) starts the episodes
    there instead of at fresh resets (:mod:`transam.envs.starts`).
    ``positions`` adds the all-positions metrics where the model has them (module docstring)."""
    length = env.spec.episode_len
    policy = make_policy(config, env)
    greedy = config.eval.greedy
    window = model if positions and isinstance(model, TransAM) and model.decodes_positions else None
    k = window.config.context if window is not None else 1
    spec = env.spec
    dropout = config.acting_dropout
    z_scale = config.a2c.z_scale

    def episodes(
        policy_params: Any,
        model_params: Any,
        key: jax.Array,
        partner: jax.Array | None = None,
        start: Any = None,
    ) -> Episodes:
        k_reset, k_run = jax.random.split(key)
        reset_keys = jax.random.split(k_reset, n)
        if start is not None:
            if partner is None:
                raise ValueError("episodes from given starts need their partners too")
            state0, obs = jax.vmap(env.reset_to)(start, jnp.asarray(partner, jnp.int32))
        elif partner is None:
            state0, obs = jax.vmap(env.reset)(reset_keys)
        else:
            state0, obs = jax.vmap(env.reset)(reset_keys, jnp.asarray(partner, jnp.int32))
        init = (
            state0,
            first_step(obs),
            policy.init_carry((n,)),
            batch_carry(model.init_carry(env.spec), n),
            jnp.ones((n,), bool),
            # The partners' data of the last K steps (newest last), lined up with the window.
            jnp.zeros((n, k, spec.num_others, spec.other_obs_dim), jnp.float32),
            jnp.zeros((n, k, spec.num_others), jnp.int32),
        )

        def body(carry: tuple[Any, ...], key: jax.Array) -> tuple[tuple[Any, ...], Any]:
            env_state, x, pc, mc, alive, past_obs, past_act = carry
            k_act, k_env = jax.random.split(key)
            k_drop = jax.random.fold_in(key, 1) if dropout else None  # a2c.act_dropout
            pc, mc, z, logits, _ = act(
                policy, model, policy_params, model_params, pc, mc, x, env_state, k_drop
            )
            if greedy:
                action = jnp.argmax(logits, -1).astype(jnp.int32)
            else:
                action = jax.random.categorical(k_act, logits).astype(jnp.int32)
            env_state, ts, x = env_step(env, k_env, env_state, action)
            live = alive.astype(jnp.float32)
            scores = {
                POLICY_ENTROPY: policy_entropy(logits) * live,
                OBS_NORM: jnp.linalg.norm(x.obs, axis=-1) * live,
                Z_NORM: jnp.linalg.norm(z_scale * z, axis=-1) * live,
            }
            rec = ts.record
            obs_pred, act_logits = jax.vmap(model.decode, in_axes=(None, 0, 0))(
                model_params, z, rec.other_obs
            )
            if act_logits is not None:
                correct = jnp.argmax(act_logits, -1) == rec.other_actions
                scores[ACC_NEWEST] = correct.mean(-1) * live
            if obs_pred is not None:
                err = (obs_pred - rec.other_obs.reshape(n, -1)) ** 2
                scores["obs_mse"] = err.mean(-1) * live
            shift = lambda buf, new: jnp.concatenate([buf[:, 1:], new[:, None]], axis=1)
            past_obs = shift(past_obs, rec.other_obs.astype(jnp.float32))
            past_act = shift(past_act, rec.other_actions.astype(jnp.int32))
            if window is not None:
                (w_obs, w_logits), valid = jax.vmap(window.decode_window, in_axes=(None, 0, 0))(
                    model_params, mc, past_obs
                )  # [n, K, ...]
                assert w_logits is not None
                w = valid.astype(jnp.float32)
                count = jnp.maximum(w.sum(-1), 1.0)
                hit = (jnp.argmax(w_logits, -1) == past_act).mean(-1)  # [n, K]
                scores[ACC_ALL] = (hit * w).sum(-1) / count * live
                if w_obs is not None:
                    sq = ((w_obs - past_obs.reshape(n, k, -1)) ** 2).mean(-1)
                    scores[MSE_ALL] = (sq * w).sum(-1) / count * live
            out = (ts.reward * live, live, z, scores, action)
            return (env_state, x, pc, mc, alive & ~ts.done, past_obs, past_act), out

        keys = jax.random.split(k_run, length)
        _, (reward, live, z, scores, action) = jax.lax.scan(body, init, keys)
        return Episodes(
            reward=reward, live=live, z=z, partner=state0.partner, scores=scores, action=action
        )

    return episodes


def make_evaluate(config: TrainConfig, env: ControlledEnv, model: AgentModel) -> EvalFn:
    """A jitted ``(policy_params, model_params, key) -> metrics`` over ``config.eval.episodes``
    episodes (partners drawn uniformly). Metrics: ``return`` (mean), ``return_std``,
    ``policy_entropy`` (mean over steps) and, with a decoder, ``action_accuracy_newest`` and
    ``obs_mse`` where the model predicts them (no all-positions metrics here: training logs
    them from the model's loss)."""
    episodes = make_episodes(config, env, model, config.eval.episodes)

    def evaluate(policy_params: Any, model_params: Any, key: jax.Array) -> dict[str, jax.Array]:
        ep = episodes(policy_params, model_params, key, None)
        returns = ep.reward.sum(0)
        per_t = jnp.maximum(ep.live.sum(1), 1.0)
        out = {"return": returns.mean(), "return_std": returns.std()}
        for k, v in ep.scores.items():
            out[k] = v.sum() / ep.live.sum()
            out[f"per_step/{k}"] = v.sum(1) / per_t
        return out

    return jax.jit(evaluate)
