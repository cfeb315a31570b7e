"""The recurrent baselines (LIAM, CARL, CAIL): method-specific checks on top of the generic
contract of test_methods.py. CARL's positives and masking on handcrafted batches, LIAM's loss
against its formula, CAIL's decoder reading the other agents' observations, and each loss
learning on Spread data (random controlled agent, tiny settings)."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from local_data import random_rollout

from transam.compose import make_env
from transam.envs.core import ControlledEnv, PartnerRecord
from transam.models import BaselineConfig, make_model
from transam.models.base import LocalStep
from transam.models.cail import CAIL
from transam.models.carl import CARL, episode_labels, top1_accuracy
from transam.models.liam import LIAM
from transam.models.recurrent import RecurrentModel

TINY = BaselineConfig(hidden=32, embed_dim=16, decoder_hidden=32)
STEPS, ENVS = 30, 24  # Spread episodes are 25 steps: one boundary at 25 in every env
TRAIN, HELD = slice(0, 16), slice(16, 24)


@pytest.fixture(scope="module")
def env() -> ControlledEnv:
    return make_env("spread", partners="heuristic")  # the data the thresholds were set on


@pytest.fixture(scope="module")
def data(env: ControlledEnv) -> tuple[LocalStep, PartnerRecord]:
    xs, _, rec = random_rollout(env, jax.random.key(0), ENVS, STEPS)
    return jax.tree.map(np.asarray, (xs, rec))


def zero_carry(model: RecurrentModel, n: int) -> Any:
    return jax.tree.map(lambda a: jnp.broadcast_to(a, (n, *a.shape)), model.init_carry(model.spec))


def take(tree: Any, idx: Any) -> Any:
    return jax.tree.map(lambda a: a[idx], tree)


def take_env(xs: LocalStep, n: int) -> LocalStep:
    return take(xs, (slice(None), n))


def count(tree: Any) -> int:
    return sum(int(a.size) for a in jax.tree.leaves(tree))


# -- CARL ----------------------------------------------------------------------------------------


def supcon_reference(emb: np.ndarray, labels: np.ndarray, tau: float) -> float:
    """Multi-positive NT-Xent, written out: anchors with a positive, -mean log softmax of their
    positives over all other items."""
    unit = emb / (np.linalg.norm(emb, axis=-1, keepdims=True) + 1e-8)
    sim = unit @ unit.T / tau
    terms = []
    for i in range(len(emb)):
        others = [j for j in range(len(emb)) if j != i]
        pos = [j for j in others if labels[j] == labels[i]]
        if not pos:
            continue
        log_z = np.log(np.sum(np.exp(sim[i, others])))
        terms.append(-np.mean([sim[i, j] - log_z for j in pos]))
    return float(np.mean(terms)) if terms else 0.0


def test_carl_episode_labels_split_at_boundaries() -> None:
    first = np.zeros((5, 4), bool)
    first[2, 1] = True  # env 1: steps 0-1 | 2-4
    first[4, 2] = True  # env 2: steps 0-3 | 4 (alone: no positive)
    first[0, 3] = first[1, 3] = first[3, 3] = True  # env 3: 0 | 1-2 | 3-4
    labels = np.asarray(episode_labels(jnp.asarray(first)))
    groups = lambda n: [np.flatnonzero(labels[:, n] == v).tolist() for v in np.unique(labels[:, n])]
    assert groups(0) == [[0, 1, 2, 3, 4]]
    assert groups(1) == [[0, 1], [2, 3, 4]]
    assert groups(2) == [[0, 1, 2, 3], [4]]
    assert groups(3) == [[0], [1, 2], [3, 4]]
    assert len(np.unique(labels)) == 1 + 2 + 2 + 3  # no label shared across environments


def test_carl_loss_matches_reference_on_a_split_batch(env: ControlledEnv, data: Any) -> None:
    """The loss on the projected z equals the written-out multi-positive NT-Xent: positives
    only inside one episode, an episode split by a boundary gives two groups, a lone step is
    no anchor; ``partner`` mode groups by partner index instead."""
    xs, rec = jax.tree.map(lambda a: a[21:26, :6], data)  # boundary at 25 = rollout step 4
    first = np.asarray(xs.first).copy()
    first[1, 0] = True  # env 0 also restarts at rollout step 1 (a lone step 0)
    xs = xs.replace(first=first)
    model = CARL(env.spec, dataclasses.replace(TINY, carl_positives="episode"))
    params = model.init(jax.random.key(0), env.spec)
    carry = zero_carry(model, 6)
    total, metrics = jax.jit(model.loss)(params, carry, xs, rec, None)
    z = model.embed_batch(params, carry, xs)
    proj = np.asarray(model.projection.apply({"params": params["projection"]}, z))
    emb = proj.reshape(-1, proj.shape[-1])
    labels = np.asarray(episode_labels(jnp.asarray(first))).reshape(-1)
    np.testing.assert_allclose(total, supcon_reference(emb, labels, TINY.temperature), rtol=1e-5)
    np.testing.assert_allclose(metrics["contrastive"], total)
    assert 0.0 <= float(metrics["contrastive_accuracy"]) <= 1.0

    partner = CARL(env.spec, TINY)  # the default: positives share the partner index
    labels_p = np.asarray(rec.partner).reshape(-1)
    assert len(np.unique(labels_p)) > 1
    total_p = jax.jit(partner.loss)(params, carry, xs, rec, None)[0]
    np.testing.assert_allclose(
        total_p, supcon_reference(emb, labels_p, TINY.temperature), rtol=1e-5
    )


def test_carl_without_positives_is_zero(env: ControlledEnv, data: Any) -> None:
    """Every step starts an episode: no two steps share one, so no anchor: loss 0, no gradient."""
    xs, rec = jax.tree.map(lambda a: a[:4, :5], data)
    xs = xs.replace(first=np.ones_like(xs.first))
    model = CARL(env.spec, dataclasses.replace(TINY, carl_positives="episode"))
    params = model.init(jax.random.key(1), env.spec)
    grad_fn = jax.value_and_grad(lambda p: model.loss(p, zero_carry(model, 5), xs, rec)[0])
    value, grads = jax.jit(grad_fn)(params)
    assert float(value) == 0.0
    assert all(np.all(np.asarray(g) == 0) for g in jax.tree.leaves(grads))


def test_carl_top1_accuracy() -> None:
    emb = jnp.asarray([[1.0, 0.0], [0.9, 0.1], [0.0, 1.0], [0.1, 0.9], [-1.0, 0.0]])
    labels = jnp.asarray([0, 0, 1, 2, 3])  # items 2, 3 and 4 have no positive
    assert float(top1_accuracy(emb, labels)) == 1.0
    labels = jnp.asarray([0, 1, 0, 1, 2])  # 0's nearest is 1 (wrong), 1's is 0 (wrong), ...
    assert float(top1_accuracy(emb, labels)) == 0.0


def test_carl_decodes_nothing(env: ControlledEnv) -> None:
    model = make_model("carl", env.spec, baseline=TINY)
    params = model.init(jax.random.key(0), env.spec)
    assert set(params) == {"encoder", "projection"}
    other = jnp.zeros((env.spec.num_others, env.spec.other_obs_dim))
    assert model.decode(params, jnp.zeros((TINY.embed_dim,)), other) == (None, None)


# -- LIAM ----------------------------------------------------------------------------------------


def test_liam_loss_is_the_formula(env: ControlledEnv, data: Any) -> None:
    """0.5 * SSE over the joint observation + the sum over other agents of the NLL, averaged
    over steps and envs; obs_mse is per element, action_ce per other agent."""
    xs, rec = jax.tree.map(lambda a: a[20:27, :3], data)  # crosses the boundary at 25
    model = LIAM(env.spec, TINY)
    params = model.init(jax.random.key(2), env.spec)
    carry = zero_carry(model, 3)
    total, metrics = jax.jit(model.loss)(params, carry, xs, rec, None)
    sse, nll, sq, ce, hits = [], [], [], [], []
    other = jnp.zeros((env.spec.num_others, env.spec.other_obs_dim))
    for n in range(3):
        zs = model.embed_rollout(params, take(carry, n), take_env(xs, n))
        for t in range(7):
            obs, logits = model.decode(params, zs[t], other)
            obs, logits = np.asarray(obs), np.asarray(logits)
            err = obs - np.asarray(rec.other_obs[t, n]).reshape(-1)
            logp = logits - np.log(np.exp(logits).sum(-1, keepdims=True))
            nll_i = -logp[np.arange(env.spec.num_others), rec.other_actions[t, n]]
            sse.append(0.5 * np.sum(err**2))
            nll.append(nll_i.sum())
            sq.append(np.mean(err**2))
            ce.append(nll_i.mean())
            hits.append(np.mean(logits.argmax(-1) == rec.other_actions[t, n]))
    np.testing.assert_allclose(total, np.mean(sse) + np.mean(nll), rtol=1e-5)
    np.testing.assert_allclose(metrics["obs_mse"], np.mean(sq), rtol=1e-5)
    np.testing.assert_allclose(metrics["action_ce"], np.mean(ce), rtol=1e-5)
    np.testing.assert_allclose(metrics["action_accuracy_newest"], np.mean(hits), rtol=1e-6)
    # A reconstruction decoder ignores other_obs.
    z = jnp.ones((TINY.embed_dim,))
    a, b = model.decode(params, z, other), model.decode(params, z, other + 1.0)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


# -- CAIL ----------------------------------------------------------------------------------------


def test_cail_decoder_reads_other_obs(env: ControlledEnv, data: Any) -> None:
    model = make_model("cail", env.spec, baseline=TINY)
    assert isinstance(model, CAIL)
    params = model.init(jax.random.key(3), env.spec)
    assert set(params) == {"encoder", "decoder"}
    z = jnp.ones((TINY.embed_dim,))
    other = jnp.asarray(data[1].other_obs[3, 0])
    obs, logits = model.decode(params, z, other)
    assert obs is None and logits is not None
    assert logits.shape == (env.spec.num_others, env.spec.other_num_actions)
    # Agent 1's observation changes: only agent 1's logits change.
    _, moved = model.decode(params, z, other.at[1].add(1.0))
    assert moved is not None
    np.testing.assert_allclose(moved[0], logits[0], rtol=1e-6)
    assert not np.allclose(moved[1], logits[1])
    # And the embedding matters too.
    assert not np.allclose(model.decode(params, z * 0.0, other)[1], logits)


# -- all three -----------------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["liam", "carl", "cail"])
def test_loss_falls_on_spread(env: ControlledEnv, data: Any, method: str) -> None:
    """Adam on the loss alone over 16 envs x 30 steps: the training loss and the held-out loss
    (8 other envs) both fall."""
    # CARL with episode positives: held-out envs share no partner labels with the training
    # envs' items in a useful way, but "steps of one episode" generalises.
    cfg = dataclasses.replace(TINY, carl_positives="episode") if method == "carl" else TINY
    model = make_model(method, env.spec, baseline=cfg)
    assert isinstance(model, RecurrentModel) and model.name == method and not model.privileged
    train, held = take(data, (slice(None), TRAIN)), take(data, (slice(None), HELD))
    params = model.init(jax.random.key(4), env.spec)
    opt = optax.adam(3e-3)

    @jax.jit
    def loss(p: Any, batch: Any) -> Any:
        n = batch[0].first.shape[1]
        return model.loss(p, zero_carry(model, n), *batch, None)  # type: ignore[arg-type]

    @jax.jit
    def update(p: Any, s: Any) -> Any:
        v, g = jax.value_and_grad(lambda p: loss(p, train)[0])(p)
        u, s = opt.update(g, s, p)
        return optax.apply_updates(p, u), s, v

    held0, m0 = loss(params, held)
    state, values = opt.init(params), []
    for _ in range(50):
        params, state, v = update(params, state)
        values.append(float(v))
    held1, m1 = loss(params, held)
    held0, held1 = float(held0), float(held1)
    print(f"{method}: train {values[0]:.3f} -> {values[-1]:.3f}, held {held0:.3f} -> {held1:.3f}")
    print({k: (round(float(m0[k]), 3), round(float(m1[k]), 3)) for k in m0})
    assert np.all(np.isfinite(values))
    assert values[-1] < 0.8 * values[0]
    assert held1 < 0.95 * held0


def test_default_parameter_counts(env: ControlledEnv) -> None:
    """Default BaselineConfig on Spread: the shared encoder's size, and each method's heads."""
    b, s = BaselineConfig(), env.spec
    h, e, d = b.hidden, b.embed_dim, b.decoder_hidden
    inp = s.obs_dim + s.num_actions
    encoder = 4 * (inp * h) + 4 * (h * h + h) + (h * h + h) + (h * e + e)
    heads = {
        "liam": 2 * ((e * d + d) + (d * d + d))
        + (d + 1) * s.num_others * (s.other_obs_dim + s.other_num_actions),
        "cail": (s.other_obs_dim + e + s.num_others + 1) * d
        + (d * d + d)
        + (d + 1) * s.other_num_actions,
        "carl": (e * d + d) + (d * e + e),
    }
    for method, n_heads in heads.items():
        params = make_model(method, s).init(jax.random.key(0), s)
        print(f"{method}: encoder {count(params['encoder'])}, total {count(params)}")
        assert count(params["encoder"]) == encoder
        assert count(params) == encoder + n_heads
