"""Streaming TransAM (``attention="stream"``): acting with the key/value cache and the training
pass with the rollout's starting carry as memory give the same z, across episode boundaries
inside a rollout and across rollout boundaries; episodes and the future are isolated; the span
is ``memory`` tokens; the memory takes no gradient; the settings are validated."""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import tyro
from local_data import random_rollout

from transam.compose import make_env
from transam.envs.core import ControlledEnv, PartnerRecord
from transam.models import make_model
from transam.models.base import ACC_NEWEST, LocalStep
from transam.models.stream import StreamCarry, StreamTransAM
from transam.models.transam import TransAM, TransAMConfig
from transam.train.config import ConfigError, TrainConfig

TINY = TransAMConfig(width=32, layers=2, heads=2, ff_width=64, attention="stream")
CONFIGS = [
    pytest.param(TINY, id="tiny"),
    pytest.param(
        dataclasses.replace(TINY, tokens="fuse", norm="pre", memory=4), id="fuse-pre-memory4"
    ),
    pytest.param(
        dataclasses.replace(TINY, decoder="imitate", init="authors", memory=20), id="im-memory20"
    ),
]
STEPS, EPISODE = 60, 25  # Spread: episodes start at 0, 25, 50


@pytest.fixture(scope="module")
def env() -> ControlledEnv:
    return make_env("spread", partners="heuristic")


@pytest.fixture(scope="module")
def traj(env: ControlledEnv) -> tuple[LocalStep, PartnerRecord]:
    """One environment's 60 random steps [T]."""
    xs, _, rec = random_rollout(env, jax.random.key(0), 2, STEPS)
    xs, rec = jax.tree.map(lambda a: np.asarray(a[:, 0]), (xs, rec))
    assert np.flatnonzero(xs.first).tolist() == [0, EPISODE, 2 * EPISODE]
    return xs, rec


def take(tree: Any, idx: Any) -> Any:
    return jax.tree.map(lambda a: a[idx], tree)


@partial(jax.jit, static_argnums=0)
def run_steps(model: StreamTransAM, params: Any, carry: StreamCarry, xs: LocalStep) -> Any:
    """The execution path in order: (carry before each step [T], z [T])."""

    def body(c: StreamCarry, x: LocalStep) -> tuple[StreamCarry, Any]:
        c2, z = model.step(params, c, x)
        return c2, (c, z)

    return jax.lax.scan(body, carry, xs)[1]


@partial(jax.jit, static_argnums=0)
def embed(model: StreamTransAM, params: Any, carry: StreamCarry, xs: LocalStep) -> jax.Array:
    return model.embed_rollout(params, carry, xs)


def junk_carry(model: StreamTransAM, seed: int) -> StreamCarry:
    """A full carry of arbitrary keys and values, every slot marked valid."""
    c = model.init_carry(model.spec)
    rng = np.random.default_rng(seed)
    return StreamCarry(
        key=rng.normal(size=c.key.shape).astype(np.float32) * 3,
        value=rng.normal(size=c.value.shape).astype(np.float32) * 3,
        valid=np.ones(c.valid.shape, bool),
    )


@pytest.mark.parametrize("config", CONFIGS)
def test_step_and_training_paths_agree(env: ControlledEnv, traj: Any, config: Any) -> None:
    xs, _ = traj
    model = make_model("transam", env.spec, config)
    assert isinstance(model, StreamTransAM)
    params = model.init(jax.random.key(0), env.spec)
    carries, z_step = run_steps(model, params, model.init_carry(env.spec), xs)
    assert z_step.shape == (STEPS, config.width) and np.all(np.isfinite(z_step))
    # One training pass over all 60 steps: episode boundaries at 25 and 50 inside it.
    whole = embed(model, params, model.init_carry(env.spec), xs)
    np.testing.assert_allclose(whole, z_step, atol=1e-5, rtol=0)
    # Consecutive rollouts, each from the carry acting had at its start (what the trainer
    # stores): 5 steps (rollouts end where episodes do), 7 (episodes start mid-rollout and
    # rollouts start mid-episode), 24 (one boundary inside each rollout).
    for n in (5, 7, 24):
        parts = [
            embed(model, params, take(carries, s), take(xs, slice(s, s + n)))
            for s in range(0, STEPS, n)
        ]
        np.testing.assert_allclose(np.concatenate(parts), z_step, atol=1e-5, rtol=0)


@pytest.mark.parametrize("config", CONFIGS[:2])
def test_episodes_and_the_future_are_isolated(env: ControlledEnv, traj: Any, config: Any) -> None:
    xs, _ = traj
    model = make_model("transam", env.spec, config)
    params = model.init(jax.random.key(1), env.spec)
    clean = model.init_carry(env.spec)
    z = embed(model, params, clean, xs)
    junk = junk_carry(model, 2)
    # A carry of another episode is never attended to, whatever it holds (xs[0] is a first).
    np.testing.assert_allclose(embed(model, params, junk, xs), z, atol=1e-6, rtol=0)
    np.testing.assert_allclose(run_steps(model, params, junk, xs)[1], z, atol=1e-5, rtol=0)
    # Everything before the boundary at 25 changed: z from 25 on is unchanged (both paths).
    rng = np.random.default_rng(3)
    before = (np.arange(STEPS) < EPISODE)[:, None]
    xs_b = xs.replace(obs=np.where(before, xs.obs + rng.normal(size=xs.obs.shape), xs.obs))
    z_b = embed(model, params, clean, xs_b)
    assert not np.allclose(z_b[:EPISODE], z[:EPISODE], atol=1e-3)
    np.testing.assert_allclose(z_b[EPISODE:], z[EPISODE:], atol=1e-6, rtol=0)
    np.testing.assert_allclose(run_steps(model, params, clean, xs_b)[1], z_b, atol=1e-5, rtol=0)
    # Step 30 changed: z before it is unchanged (causal), z at it is not.
    xs_f = xs.replace(obs=xs.obs.copy())
    xs_f.obs[30] += 1.0
    z_f = embed(model, params, clean, xs_f)
    np.testing.assert_array_equal(z_f[:30], z[:30])
    assert not np.allclose(z_f[30], z[30], atol=1e-3)


def test_one_layer_sees_exactly_memory_tokens_back(env: ControlledEnv, traj: Any) -> None:
    """One layer, M = 6: step t's observation token sees tokens 3t+2-6 ... 3t+2, so o_s
    reaches z_s, z_{s+1}, z_{s+2} and no later z. (With L layers the reach is L*M tokens, as
    in Transformer-XL: each layer's cached keys already looked M tokens back.)"""
    xs, _ = traj
    model = make_model("transam", env.spec, dataclasses.replace(TINY, layers=1, memory=6))
    params = model.init(jax.random.key(4), env.spec)
    clean = model.init_carry(env.spec)
    z = embed(model, params, clean, xs)
    xs_p = xs.replace(obs=xs.obs.copy())
    xs_p.obs[30] += 1.0
    z_p = embed(model, params, clean, xs_p)
    changed = ~np.isclose(z_p, z, atol=1e-6, rtol=0).all(-1)
    assert np.flatnonzero(changed).tolist() == [30, 31, 32]


def test_loss_metrics_gradients_and_dropout(env: ControlledEnv, traj: Any) -> None:
    xs, rec = traj
    model = make_model("transam", env.spec, TINY)
    assert isinstance(model, StreamTransAM)
    params = model.init(jax.random.key(5), env.spec)
    carries, _ = run_steps(model, params, model.init_carry(env.spec), xs)
    carry, sx, sr = take(carries, 20), take(xs, slice(20, 30)), take(rec, slice(20, 30))
    loss = jax.jit(model.rollout_loss)
    total, metrics = loss(params, carry, sx, sr)
    # One decoded z per step: no all-positions metric.
    assert set(metrics) == {ACC_NEWEST, "action_ce", "obs_mse"}
    np.testing.assert_allclose(total, metrics["obs_mse"] + metrics["action_ce"], rtol=1e-5)
    # The memory is fixed (stop_gradient): no gradient reaches the cached keys and values;
    # the encoder gets one.
    g_key, g_value = jax.grad(
        lambda k, v: loss(params, carry.replace(key=k, value=v), sx, sr)[0], argnums=(0, 1)
    )(carry.key, carry.value)
    assert np.any(carry.valid) and not np.any(g_key) and not np.any(g_value)
    g_params = jax.grad(lambda p: loss(p, carry, sx, sr)[0])(params)
    assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(g_params))
    assert float(optax_norm(g_params["encoder"])) > 0
    # Dropout only with a key, and the same key gives the same loss.
    d1 = loss(params, carry, sx, sr, jax.random.key(1))[0]
    assert d1 != total and d1 == loss(params, carry, sx, sr, jax.random.key(1))[0]
    _, z_drop = jax.jit(model.step)(params, carry, take(sx, 0), jax.random.key(2))
    _, z_det = jax.jit(model.step)(params, carry, take(sx, 0))
    assert not np.allclose(z_drop, z_det)


def optax_norm(tree: Any) -> jax.Array:
    return jnp.sqrt(sum(jnp.sum(a**2) for a in jax.tree.leaves(tree)))


def count(tree: Any) -> int:
    return sum(int(a.size) for a in jax.tree.leaves(tree))


def test_selection_sizes_and_validation(env: ControlledEnv) -> None:
    s = env.spec
    assert TransAMConfig().attention == "window"  # the faithful model stays the default
    assert isinstance(make_model("transam", s), TransAM)
    stream = dataclasses.replace(TransAMConfig(), attention="stream")
    for method in ("transam", "transam-fuse", "transam-im"):
        model = make_model(method, s, stream)
        assert isinstance(model, StreamTransAM) and model.name == f"{method}-stream"
        # Same parameters as the window model: only the attention pattern differs.
        window = make_model(method, s)
        p, pw = model.init(jax.random.key(0), s), window.init(jax.random.key(0), s)
        assert (count(p["encoder"]), count(p["head"])) == (
            count(pw["encoder"]),
            count(pw["head"]),
        )
    c = make_model("transam", s, stream).init_carry(s)
    assert c.key.shape == (4, 15, 4, 32) and c.valid.shape == (15,)  # M = 3K by default
    # Refused by the model and by the training config.
    with pytest.raises(ValueError, match="pool='last' only"):
        make_model("transam-pool", s, stream)
    with pytest.raises(ValueError, match="memory"):
        make_model("transam", s, dataclasses.replace(stream, memory=0))
    with pytest.raises(ValueError, match="window model"):
        TransAM(s, stream)
    for method in ("pel", "transam-pool"):
        with pytest.raises(ConfigError, match=r"model\.attention 'stream' applies"):
            TrainConfig(method=method, model=stream).validate()  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"model\.memory"):
        TrainConfig(model=dataclasses.replace(stream, memory=0)).validate()
    cli = tyro.cli(TrainConfig, args=["--model.attention", "stream", "--model.memory", "6"])
    assert cli.model == dataclasses.replace(TransAMConfig(), attention="stream", memory=6)
