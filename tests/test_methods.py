"""The agent-model contract, checked for every method in ``PAPER_METHODS`` on Spread (and for
TransAM with streaming attention, ``transam+stream``).

Per method (tiny settings, so each compiles in seconds): the execution path (``step`` with its
carry) and the training path (``embed_rollout``) agree across an episode boundary; only the
Oracle's execution path can take partner data, by signature; the auxiliary loss is finite and
falls under Adam (zero, with no parameters, for NAM and the Oracle); the runner state
round-trips through a checkpoint. A tiny training run per code path checks that evaluation
reports accuracy / MSE only where the method predicts them and that kill-and-resume
reproduces the run exactly.
"""

from __future__ import annotations

import dataclasses
import inspect
import re
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from flax import serialization
from local_data import random_rollout

from transam.compose import make_env
from transam.envs.core import ControlledEnv
from transam.models import AgentModel, BaselineConfig, TransAMConfig, make_model
from transam.models.base import LocalStep, PartnerView, run_embed
from transam.registry import PAPER_METHODS
from transam.rundir import read_metrics
from transam.train import a2c
from transam.train.config import A2CConfig, EvalConfig, TrainConfig
from transam.train.loop import train

TINY_T = TransAMConfig(context=3, width=16, layers=1, heads=2, ff_width=32, dropout=0.0)
TINY_B = BaselineConfig(hidden=16, embed_dim=16, decoder_hidden=16)
STEPS = 60  # Spread episodes are 25 steps: boundaries at 25 and 50
ENVS = 8


@pytest.fixture(scope="module")
def env() -> ControlledEnv:
    return make_env("spread", partners="heuristic")  # the data the thresholds were set on


STREAM = "transam+stream"
"""TransAM with streaming attention (``model.attention stream``): a variant checked as a method."""
MODELS = [*PAPER_METHODS, STREAM]


def settings(method: str) -> tuple[str, TransAMConfig]:
    """(method name, transformer settings) of a test id ``method[+stream]``."""
    name, _, attention = method.partition("+")
    return name, dataclasses.replace(TINY_T, attention="stream") if attention else TINY_T


def tiny(env: ControlledEnv, method: str) -> AgentModel:
    name, config = settings(method)
    return make_model(name, env.spec, config, TINY_B)


@pytest.fixture(scope="module")
def data(env: ControlledEnv) -> tuple[LocalStep, PartnerView, Any]:
    return random_rollout(env, jax.random.key(0), ENVS, STEPS)


def _step_fn(model: AgentModel) -> Any:
    if model.privileged:
        return model.step
    return lambda p, c, x, _view: model.step(p, c, x)


def _embed_fn(model: AgentModel) -> Any:
    if model.privileged:
        return model.embed_rollout
    return lambda p, c, xs, _views: model.embed_rollout(p, c, xs)


@pytest.mark.parametrize("method", MODELS)
def test_execution_and_training_paths_agree(env: ControlledEnv, data: Any, method: str) -> None:
    model = tiny(env, method)
    params = model.init(jax.random.key(1), env.spec)
    xs, views, _ = jax.tree.map(lambda a: a[:, 0], data)  # one environment
    assert np.flatnonzero(np.asarray(xs.first)).tolist() == [0, 25, 50]
    step = _step_fn(model)

    @jax.jit
    def run(params: Any) -> tuple[Any, jax.Array, jax.Array, jax.Array]:
        def body(c: Any, inp: Any) -> Any:
            c2, z = step(params, c, *inp)
            return c2, (c, z)

        carries, zs = jax.lax.scan(body, model.init_carry(env.spec), (xs, views))[1]
        # The training path over the whole rollout, and from a carry in mid-episode (step 37)
        # over a slice that crosses the boundary at 50.
        whole = _embed_fn(model)(params, model.init_carry(env.spec), xs, views)
        part = jax.tree.map(lambda a: a[37:], (xs, views))
        tail = _embed_fn(model)(params, jax.tree.map(lambda a: a[37], carries), *part)
        return carries, zs, whole, tail

    _, zs, whole, tail = run(params)
    assert zs.shape == (STEPS, model.embed_dim)
    np.testing.assert_allclose(whole, zs, atol=1e-5, rtol=1e-5)
    np.testing.assert_allclose(tail, zs[37:], atol=1e-5, rtol=1e-5)
    # Nothing crosses an episode boundary: the first z of an episode is the same whatever came
    # before it (compare with a fresh carry).
    fresh = jax.jit(step)(
        params, model.init_carry(env.spec), *jax.tree.map(lambda a: a[25, 0], data[:2])
    )
    np.testing.assert_allclose(fresh[1], zs[25], atol=1e-5)


@pytest.mark.parametrize("method", MODELS)
def test_only_the_oracle_execution_path_takes_partner_data(
    env: ControlledEnv, data: Any, method: str
) -> None:
    model = tiny(env, method)
    state, _ = env.reset(jax.random.key(0))
    if method != "oracle":
        assert not model.privileged
        # A PRNG key (dropout while acting, the authors' preset) is the only extra input.
        step_args = [p for p in inspect.signature(model.step).parameters if p != "key"]
        assert step_args == ["params", "carry", "x"]
        rollout_args = [p for p in inspect.signature(model.embed_rollout).parameters if p != "key"]
        assert rollout_args == ["params", "carry", "xs"]
        assert a2c.partner_view(model, state) is None  # the trainer hands it nothing
        return
    # The Oracle's z does see the other agents (privileged by design).
    assert model.privileged and a2c.partner_view(model, state) is not None
    xs, views, _ = jax.tree.map(lambda a: a[1, 0], data)
    params = model.init(jax.random.key(0), env.spec)
    _, z = model.step(params, model.init_carry(env.spec), xs, views)
    moved = views.replace(other_obs=views.other_obs + 1.0)
    _, z2 = model.step(params, model.init_carry(env.spec), xs, moved)
    assert not np.allclose(z, z2)


@pytest.mark.parametrize("method", MODELS)
def test_every_model_has_the_whole_protocol(env: ControlledEnv, data: Any, method: str) -> None:
    """Every model has every member the trainer calls (so that it never asks which model it
    holds, the next test): a dropout key on both paths, ``prior_steps`` and ``loss_and_embed``,
    whose loss is ``loss``'s and whose z, where it gives one, is the training path's."""
    model = tiny(env, method)
    for path in (model.step, model.embed_rollout):
        assert inspect.signature(path).parameters["key"].default is None
    prior = model.prior_steps
    assert prior == (
        TINY_T.context - 1 if method in ("transam", "transam-fuse", "transam-im") else 0
    )
    params = model.init(jax.random.key(2), env.spec)
    xs, views, record = jax.tree.map(lambda a: a[:10], data)  # from the episode's start
    carry = a2c.batch_carry(model.init_carry(env.spec), ENVS)
    loss, metrics = jax.jit(model.loss)(params, carry, xs, record)
    loss2, metrics2, z = jax.jit(model.loss_and_embed)(params, carry, xs, record)
    assert float(loss2) == float(loss) and metrics2.keys() == metrics.keys()
    if z is not None:  # the TransAM family

        def one(c: Any, x: Any, v: Any) -> Any:
            return run_embed(model, params, c, x, v)

        want = jax.vmap(one, in_axes=(0, 1, 1), out_axes=1)(carry, xs, views)
        np.testing.assert_allclose(z, want, atol=1e-5, rtol=1e-5)


def test_the_trainer_never_asks_which_model_it_holds() -> None:
    """No class checks, ``hasattr`` or ``getattr`` in the A2C update: the protocol's members
    (:mod:`transam.models.base`) are all it uses."""
    source = Path(a2c.__file__).read_text()
    assert not re.search(r"\b(hasattr|isinstance|getattr)\(", source)


@pytest.mark.parametrize("method", MODELS)
def test_auxiliary_loss_finite_and_falls(env: ControlledEnv, data: Any, method: str) -> None:
    model = tiny(env, method)
    xs, record = jax.tree.map(lambda a: a[10:30], (data[0], data[2]))  # [20, 8], crosses 25
    carry = jax.tree.map(
        lambda a: jnp.broadcast_to(a, (ENVS, *a.shape)), model.init_carry(env.spec)
    )
    params = model.init(jax.random.key(2), env.spec)
    # The carry before step 10 is rebuilt by running the execution path over steps 0..9.
    step = _step_fn(model)
    head = jax.tree.map(lambda a: a[:10], (data[0], data[1]))

    def carry_at_10(p: Any) -> Any:
        def one(c: Any, x: Any, v: Any) -> Any:
            return jax.lax.scan(lambda c, inp: (step(p, c, *inp)[0], None), c, (x, v))[0]

        return jax.vmap(one, in_axes=(0, 1, 1))(carry, *head)

    carry = jax.jit(carry_at_10)(params)
    leaves = jax.tree.leaves(params)
    value, metrics = jax.jit(model.loss)(params, carry, xs, record, None)
    assert np.isfinite(float(value))
    if not leaves:  # NAM, Oracle: no parameters, no auxiliary loss
        assert float(value) == 0.0 and metrics == {}
        return
    assert all(np.isfinite(float(v)) for v in metrics.values())
    opt = optax.adam(3e-3)

    @jax.jit
    def update(p: Any, s: Any) -> Any:
        v, g = jax.value_and_grad(lambda p: model.loss(p, carry, xs, record, None)[0])(p)
        u, s = opt.update(g, s, p)
        return optax.apply_updates(p, u), s, v

    state, values = opt.init(params), []
    for _ in range(60):
        params, state, v = update(params, state)
        values.append(float(v))
    assert np.all(np.isfinite(values))
    assert values[-1] < 0.9 * values[0], (values[0], values[-1])


def tiny_run(method: str, out: Path) -> TrainConfig:
    name, config = settings(method)
    return TrainConfig(
        env="spread",
        method=name,  # type: ignore[arg-type]
        total_steps=200,  # two chunks of 4 episodes x 25 steps
        out=str(out),
        progress=False,
        a2c=A2CConfig(num_envs=4, n_steps=5, hidden=16),
        model=config,
        baseline=TINY_B,
        eval=EvalConfig(every_episodes=4, episodes=8),
    )


@pytest.mark.parametrize("method", MODELS)
def test_checkpoint_round_trip(env: ControlledEnv, method: str) -> None:
    """A method's parameters, optimiser state and carry survive the checkpoint format (msgpack)
    leaf for leaf (the rest of the runner state is the same for every method)."""
    model = tiny(env, method)
    params = model.init(jax.random.key(3), env.spec)
    params = jax.tree.map(lambda a: a + 0.5, params)  # not the template's zeros
    opt_state = optax.adam(1e-3).init(params)
    state = {"params": params, "opt": opt_state, "carry": model.init_carry(env.spec)}
    template = jax.tree.map(jnp.zeros_like, state)
    restored = serialization.from_bytes(template, serialization.to_bytes(state))
    assert jax.tree.structure(restored) == jax.tree.structure(state)
    for a, b in zip(jax.tree.leaves(restored), jax.tree.leaves(state), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


# One method per code path (transformer, privileged, contrastive with pairing): a whole run per
# method costs a full compile of the training program. The recurrent path (LIAM) is trained,
# interrupted and resumed exactly by the smoke grid (test_reproduce.py, test_grid_ray.py).
@pytest.mark.parametrize("method", ["transam", "oracle", "pel", STREAM])
def test_tiny_run_writes_the_keys_and_resume_is_exact(method: str, tmp_path: Path) -> None:
    cfg = tiny_run(method, tmp_path / "ref")
    assert train(cfg).finished
    records = read_metrics(tmp_path / "ref" / "metrics.jsonl")
    assert len(records) == 2
    for rec in records:
        assert np.isfinite(rec["eval/return"]) and np.isfinite(rec["train/policy_loss"])
        assert ("eval/action_accuracy_newest" in rec) == (method != "oracle")
        assert ("eval/obs_mse" in rec) == (method in ("transam", "liam", STREAM))
        assert rec["eval/obs_norm"] > 0 and rec["eval/z_norm"] > 0  # the policy's input sizes
    # Kill after one chunk (its checkpoint written), resume: identical metrics. The cut run
    # starts afresh with the same seed, so this also shows the run is deterministic (and, for
    # the streaming model, that its key/value cache is checkpointed with the runner state).
    cut = dataclasses.replace(cfg, out=str(tmp_path / "cut"))
    assert not train(cut, stop_after_chunks=1).finished
    assert train(dataclasses.replace(cut, resume=True)).finished
    assert read_metrics(tmp_path / "cut" / "metrics.jsonl") == records
