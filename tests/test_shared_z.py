"""The policy's z off the agent-model loss's own pass (``a2c.z_pass="shared"``, the authors'
one forward per update): ``loss_and_embed`` gives the loss of ``loss`` and, per rollout, the z
that ``embed_rollout`` gives with that rollout's dropout key; the trainer feeds it to the
policy loss, and a model without dropout trains the same either way."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import numpy as np
import pytest
from local_data import random_rollout

from transam.compose import make_env
from transam.envs.core import ControlledEnv
from transam.models import make_model
from transam.models.transam import TransAMConfig
from transam.train import a2c
from transam.train.config import ConfigError, TrainConfig

TINY = TransAMConfig(width=16, layers=1, heads=2, ff_width=16, context=3)
MODELS = [
    pytest.param(TINY, id="window"),
    pytest.param(dataclasses.replace(TINY, pool="mean"), id="window-pool"),
    pytest.param(dataclasses.replace(TINY, attention="stream"), id="stream"),
]
NUM_ENVS, STEPS = 3, 30  # an episode boundary (step 25) inside the rollout


@pytest.fixture(scope="module")
def env() -> ControlledEnv:
    return make_env("spread", partners="heuristic")


@pytest.mark.parametrize("config", MODELS)
def test_loss_and_embed_is_the_loss_and_each_rollouts_z(env: ControlledEnv, config: Any) -> None:
    method = "transam-pool" if config.pool == "mean" else "transam"
    model: Any = make_model(method, env.spec, config)
    params = model.init(jax.random.key(0), env.spec)
    xs, _, rec = random_rollout(env, jax.random.key(1), NUM_ENVS, STEPS)
    carry = a2c.batch_carry(model.init_carry(env.spec), NUM_ENVS)
    key = jax.random.key(2)
    total, metrics, z = jax.jit(model.loss_and_embed)(params, carry, xs, rec, key)
    plain, plain_metrics = jax.jit(model.loss)(params, carry, xs, rec, key)
    np.testing.assert_array_equal(total, plain)
    assert metrics.keys() == plain_metrics.keys()
    for name in metrics:
        np.testing.assert_array_equal(metrics[name], plain_metrics[name])
    assert z.shape == (STEPS, NUM_ENVS, model.embed_dim)
    keys = jax.random.split(key, NUM_ENVS)
    embed = jax.jit(model.embed_rollout)
    for i in range(NUM_ENVS):
        one = jax.tree.map(lambda a, i=i: a[:, i], xs)
        want = embed(params, jax.tree.map(lambda a, i=i: a[i], carry), one, keys[i])
        np.testing.assert_allclose(z[:, i], want, rtol=1e-5, atol=1e-6)
    # Dropout is in play: another key, another z; no key, the deterministic z.
    other = jax.jit(model.loss_and_embed)(params, carry, xs, rec, jax.random.key(3))[2]
    assert not np.allclose(z, other)
    det = jax.jit(model.loss_and_embed)(params, carry, xs, rec, None)[2]
    one = jax.tree.map(lambda a: a[:, 0], xs)
    np.testing.assert_allclose(
        det[:, 0], embed(params, jax.tree.map(lambda a: a[0], carry), one), rtol=1e-5, atol=1e-6
    )


def _tiny_train(z_pass: str, dropout: float) -> TrainConfig:
    model = dataclasses.replace(TINY, dropout=dropout)
    a = dataclasses.replace(TrainConfig().a2c, num_envs=2, hidden=8, z_pass=z_pass)  # type: ignore[arg-type]
    return TrainConfig(env="spread", method="transam", partners="heuristic", model=model, a2c=a)


def _one_collection(config: TrainConfig) -> dict[str, float]:
    env = make_env(config.env, partners=config.partners)
    model = make_model(config.method, env.spec, config.model)
    rs = a2c.init_runner(config, env, model, jax.random.key(0))
    _, metrics = jax.jit(a2c.make_update(config, env, model))(rs)
    return {k: float(v) for k, v in metrics.items()}


def test_trainer_feeds_the_shared_z_to_the_policy_loss() -> None:
    # Without dropout both passes compute the same z: bit for bit the same update.
    names = ("policy_loss", "value_loss", "entropy", "model_loss", "grad_norm/policy")
    shared = _one_collection(_tiny_train("shared", 0.0))
    separate = _one_collection(_tiny_train("separate", 0.0))
    assert [shared[k] for k in names] == [separate[k] for k in names]
    # With dropout the shared z carries the loss pass's mask, the separate one a fresh mask:
    # the policy's terms differ, the agent-model loss (the same pass in both) does not.
    shared = _one_collection(_tiny_train("shared", 0.5))
    separate = _one_collection(_tiny_train("separate", 0.5))
    assert shared["model_loss"] == separate["model_loss"]
    assert shared["value_loss"] != separate["value_loss"]
    assert shared["policy_loss"] != separate["policy_loss"]


def test_shared_pass_needs_dropout_where_z_is_computed() -> None:
    cfg = _tiny_train("shared", 0.1)
    no_drop = dataclasses.replace(cfg, a2c=dataclasses.replace(cfg.a2c, act_dropout=False))
    with pytest.raises(ConfigError, match=r"a2c\.z_pass 'shared'.*--a2c\.z-pass separate"):
        no_drop.validate()
    # ... fine with the separate pass, or for a method without dropout.
    dataclasses.replace(no_drop, a2c=dataclasses.replace(no_drop.a2c, z_pass="separate")).validate()
    dataclasses.replace(no_drop, method="liam").validate()
    assert TrainConfig().a2c.z_pass == "shared"


@pytest.mark.parametrize("method", ["liam", "nam"])
def test_methods_without_a_loss_pass_are_unchanged_by_the_setting(method: str) -> None:
    # LIAM and NAM have no loss_and_embed: runs made before the setting existed are runs under
    # the current defaults (the parity table's LIAM and NAM rows rely on it).
    def run(z_pass: str) -> dict[str, float]:
        cfg = _tiny_train(z_pass, 0.0)
        cfg = dataclasses.replace(cfg, method=method)
        return _one_collection(cfg)

    assert run("shared") == run("separate")
