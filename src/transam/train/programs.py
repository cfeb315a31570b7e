"""The compiled programs of a run: how it splits into jitted chunks, and a cache of the jitted
init, chunk and evaluation functions keyed by what they depend on.

A program depends on the config but not on the seed, the paths or (except through the
learning-rate schedule) the run length: :func:`program_key` maps a config to that part, so
repeated runs in one process (a grid's seeds, a final evaluation after training) compile once.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp

from transam.compose import make_env, resolve_partners
from transam.envs.core import ControlledEnv
from transam.models import make_model
from transam.models.base import AgentModel
from transam.train.a2c import (
    RunnerState,
    init_runner,
    make_chunk,
    steps_per_update,
    total_updates,
)
from transam.train.config import TrainConfig
from transam.train.episodes import make_evaluate


@dataclass(frozen=True)
class Plan:
    """How a run splits into jitted chunks (one chunk per evaluation interval)."""

    steps_per_update: int
    total_updates: int
    updates_per_chunk: int

    @property
    def chunks(self) -> list[int]:
        """Updates in each chunk (the last may be shorter)."""
        full, rest = divmod(self.total_updates, self.updates_per_chunk)
        return [self.updates_per_chunk] * full + ([rest] if rest else [])

    @property
    def total_steps(self) -> int:
        return self.total_updates * self.steps_per_update


def make_plan(config: TrainConfig, episode_len: int) -> Plan:
    """Chunks of whole collections (``a2c.rollouts_per_collect`` updates each)."""
    per_update = steps_per_update(config)
    per = config.a2c.rollouts_per_collect
    every = round(config.eval.every_episodes * episode_len / (per_update * per)) * per
    return Plan(per_update, total_updates(config), max(per, every))


@functools.lru_cache(maxsize=8)
def env_and_model(config: TrainConfig) -> tuple[ControlledEnv, AgentModel]:
    e = make_env(config.env, partners=config.partners)
    return e, make_model(config.method, e.spec, config.model, config.baseline)


def program_key(config: TrainConfig) -> TrainConfig:
    """The part of the config a compiled program depends on (not the seed or the paths; the
    run length only through the learning-rate schedule)."""
    return dataclasses.replace(
        config,
        total_steps=config.total_steps if config.schedule_by_run else 1,
        seed=0,
        num_seeds=1,
        seed_mode="vmap",
        out="",
        resume=False,
        force=False,
        progress=False,
        checkpoint_every=1,
    )


@dataclass(frozen=True)
class Programs:
    """Each a ``jax.jit`` function: ``init`` (one seed), ``chunks[updates]`` (state -> (state,
    metrics)) and ``evaluate`` (policy and model parameters, key -> metrics)."""

    init: jax.stages.Wrapped
    chunks: dict[int, jax.stages.Wrapped]
    evaluate: jax.stages.Wrapped


@functools.lru_cache(maxsize=8)
def programs(config: TrainConfig, sizes: tuple[int, ...], vmapped: bool) -> Programs:
    """Jitted init (one seed), chunk (one per chunk size) and evaluation functions, the latter
    vmapped over a leading seed axis when ``vmapped``. Cached so repeated runs in one process
    compile once."""
    env, model = env_and_model(config)

    def init(key: jax.Array) -> RunnerState:
        return init_runner(config, env, model, key)

    evaluate = make_evaluate(config, env, model)
    chunks = {u: make_chunk(config, env, model, u) for u in sizes}
    if vmapped:  # init stays per seed: vmapped orthogonal inits (batched QR) hang XLA:CPU
        evaluate = jax.vmap(evaluate)
        chunks = {u: jax.vmap(f) for u, f in chunks.items()}
    return Programs(
        init=jax.jit(init),
        chunks={u: jax.jit(f) for u, f in chunks.items()},
        evaluate=jax.jit(evaluate),
    )


def run_programs(config: TrainConfig, vmapped: bool = False) -> Programs:
    """The compiled programs a run of ``config`` uses (shared with the training loop's cache)."""
    env, _ = env_and_model(config)
    chunks = make_plan(config, env.spec.episode_len).chunks
    return programs(program_key(config), tuple(sorted(set(chunks))), vmapped)


def compile_ahead(config: TrainConfig) -> None:
    """Compile the programs of a one-seed run of ``config`` now, without running them, so
    that the run finds them compiled. Compiling releases the GIL: the demo does this in a
    thread while it evaluates the shipped runs, using both cores for what it would otherwise
    compile one program after another."""
    config = dataclasses.replace(config, partners=resolve_partners(config.partners))  # as train's
    progs = run_programs(config)
    key = jax.random.key(0)
    state = jax.eval_shape(progs.init, key)
    progs.init.lower(key).compile()
    progs.evaluate.lower(state.policy_params, state.model_params, key).compile()
    for chunk in progs.chunks.values():
        chunk.lower(state).compile()


def uniform_policy_params(policy_params: Any) -> Any:
    """The policy's parameters all zeroed: every logit is equal, so the policy is a uniformly
    random controlled agent (the "random play" reference of training and final evaluation)."""
    return jax.tree.map(jnp.zeros_like, policy_params)


def uniform_policy_eval(config: TrainConfig, seed: int, chunk: int) -> dict[str, float]:
    """What a uniformly random controlled agent scores on the evaluation episodes of chunk
    ``chunk`` (0-based) of seed ``seed``: the run's own "random" reference (actor zeroed, so
    all logits are equal; same partners, same starts)."""
    progs = run_programs(config)
    init_key, eval_key = jax.random.split(jax.random.key(seed))
    state = progs.init(init_key)
    params = uniform_policy_params(state.policy_params)
    out = progs.evaluate(params, state.model_params, jax.random.fold_in(eval_key, chunk))
    return {k: float(v) for k, v in out.items() if not k.startswith("per_step/")}
