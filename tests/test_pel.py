"""PEL: TransAM's encoder with mean pooling and the imitation decoder, trained with conditional
imitation (conditioned on another environment's z with the same partner) + alpha * supervised
contrastive over partner labels. Checked against a slow reference, and that both terms learn."""

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
from transam.models import BaselineConfig, TransAMConfig, make_model
from transam.models.base import LocalStep
from transam.models.pel import PEL, paired_index
from transam.models.transam import TransAM

TINY_T = TransAMConfig(context=3, width=16, layers=1, heads=2, ff_width=32, dropout=0.0)
TINY_B = BaselineConfig(hidden=16, embed_dim=16, decoder_hidden=16, temperature=0.2)
ENVS, STEPS, START = 12, 40, 10  # losses over steps START.. (crossing the boundary at 25)


@pytest.fixture(scope="module")
def env() -> ControlledEnv:
    return make_env("spread", partners="heuristic")  # the data the thresholds were set on


@pytest.fixture(scope="module")
def batch(env: ControlledEnv) -> tuple[Any, LocalStep, PartnerRecord]:
    """(carry before START [N], xs [T, N], records [T, N]) for the tiny PEL."""
    # First episodes' partners 0,0,1,1,..,5,5: pairs of envs share a partner.
    xs, _, rec = random_rollout(env, jax.random.key(0), ENVS, STEPS, jnp.arange(ENVS) // 2)
    model = tiny(env)
    push = model.encoder.push

    def carry_at(xs_env: LocalStep) -> Any:
        return jax.lax.scan(lambda c, x: (push(c, x), None), model.init_carry(env.spec), xs_env)[0]

    head = jax.tree.map(lambda a: a[:START], xs)
    carry = jax.jit(jax.vmap(carry_at, in_axes=1))(head)
    xs, rec = jax.tree.map(lambda a: np.asarray(a[START:]), (xs, rec))
    labels = rec.partner
    assert np.flatnonzero(xs.first[:, 0]).tolist() == [25 - START]
    assert (labels[0] == np.arange(ENVS) // 2).all()
    return carry, xs, rec


def tiny(env: ControlledEnv, **baseline: Any) -> PEL:
    model = make_model("pel", env.spec, TINY_T, dataclasses.replace(TINY_B, **baseline))
    assert isinstance(model, PEL)
    return model


def test_paired_index() -> None:
    labels = jnp.array([[0, 1, 0, 2, 0], [3, 3, 3, 3, 3], [0, 1, 2, 3, 4]])
    np.testing.assert_array_equal(
        paired_index(labels), [[2, 1, 4, 3, 0], [1, 2, 3, 4, 0], [0, 1, 2, 3, 4]]
    )


def test_pel_is_transam_pool_im_with_its_own_loss(env: ControlledEnv, batch: Any) -> None:
    carry, xs, rec = batch
    model = tiny(env)
    assert model.name == "pel" and not model.privileged and model.embed_dim == TINY_T.width
    inner = TransAM(
        env.spec,
        dataclasses.replace(TINY_T, pool="mean", decoder="imitate"),
        decoder_hidden=TINY_B.decoder_hidden,
    )
    assert model.encoder == inner
    params = model.init(jax.random.key(1), env.spec)
    assert jax.tree.structure(params) == jax.tree.structure(inner.init(jax.random.key(1), env.spec))
    c0, x0 = jax.tree.map(lambda a: a[0], carry), jax.tree.map(lambda a: a[:, 0], xs)
    np.testing.assert_array_equal(
        jax.jit(model.embed_rollout)(params, c0, x0), jax.jit(inner.embed_rollout)(params, c0, x0)
    )
    z = jnp.zeros(TINY_T.width)
    obs_pred, logits = jax.jit(model.decode)(params, z, rec.other_obs[0, 0])
    assert obs_pred is None and logits.shape == (env.spec.num_others, env.spec.other_num_actions)
    with pytest.raises(ValueError, match="temperature"):
        tiny(env, temperature=0.0)
    with pytest.raises(ValueError, match="tokens/pool/decoder"):
        PEL(env.spec, dataclasses.replace(TINY_T, tokens="bad"))  # type: ignore[arg-type]


def supcon_reference(emb: np.ndarray, labels: np.ndarray, temperature: float) -> float:
    e = emb / np.linalg.norm(emb, axis=-1, keepdims=True)
    sim = e @ e.T / temperature
    losses = []
    for i in range(len(e)):
        others = np.arange(len(e)) != i
        log_z = np.log(np.sum(np.exp(sim[i, others])))
        pos = others & (labels == labels[i])
        if pos.any():
            losses.append(-np.mean(sim[i, pos] - log_z))
    return float(np.mean(losses))


def test_loss_matches_reference(env: ControlledEnv, batch: Any) -> None:
    """Own z where no other env has the partner; the next such env's z otherwise."""
    carry, xs, rec = batch
    model = tiny(env, pel_alpha=0.5)
    params = model.init(jax.random.key(2), env.spec)
    total, metrics = jax.jit(model.loss)(params, carry, xs, rec, None)
    assert set(metrics) == {"action_ce", "action_accuracy_newest", "contrastive"}
    embed = jax.jit(jax.vmap(model.embed_rollout, in_axes=(None, 0, 1), out_axes=1))
    z = np.asarray(embed(params, carry, xs))
    labels = np.asarray(rec.partner)
    num_steps, n = labels.shape
    pair = np.zeros((num_steps, n), int)
    for t in range(num_steps):
        for i in range(n):
            same = [m for m in range(n) if m != i and labels[t, m] == labels[t, i]]
            pair[t, i] = min(same, key=lambda m: (m - i) % n) if same else i
    paired = int(np.sum(pair != np.arange(n)))
    z_pair = z[np.arange(num_steps)[:, None], pair]
    logits = np.asarray(jax.jit(model.decode)(params, z_pair, rec.other_obs)[1])  # [T, N, 2, A]
    logp = logits - np.log(np.exp(logits).sum(-1, keepdims=True))
    act = rec.other_actions
    ce = -np.take_along_axis(logp, act[..., None], -1).mean()
    correct = logits.argmax(-1) == act
    assert 0 < paired < num_steps * n  # both cases occur (second episodes: random partners)
    dis = supcon_reference(z.reshape(num_steps * n, -1), labels.reshape(-1), TINY_B.temperature)
    np.testing.assert_allclose(metrics["action_ce"], ce, rtol=1e-5)
    np.testing.assert_allclose(metrics["action_accuracy_newest"], np.mean(correct), rtol=1e-6)
    np.testing.assert_allclose(metrics["contrastive"], dis, rtol=1e-4)
    np.testing.assert_allclose(total, ce + 0.5 * dis, rtol=1e-5)


def test_dropout_only_with_key(env: ControlledEnv, batch: Any) -> None:
    carry, xs, rec = batch
    model = PEL(env.spec, dataclasses.replace(TINY_T, dropout=0.1), TINY_B)
    params = model.init(jax.random.key(3), env.spec)
    fn = jax.jit(model.loss)
    base = fn(params, carry, xs, rec, None)[0]
    np.testing.assert_array_equal(fn(params, carry, xs, rec, None)[0], base)
    d1 = fn(params, carry, xs, rec, jax.random.key(1))[0]
    assert np.isfinite(d1) and d1 != base


def test_both_terms_learn(env: ControlledEnv, batch: Any) -> None:
    """Adam on the PEL loss: the imitation CE and the contrastive term both fall."""
    carry, xs, rec = batch
    model = tiny(env)
    params = model.init(jax.random.key(4), env.spec)
    opt = optax.adam(3e-3)

    @jax.jit
    def update(p: Any, s: Any) -> Any:
        (_, m), g = jax.value_and_grad(model.loss, has_aux=True)(p, carry, xs, rec, None)
        u, s = opt.update(g, s, p)
        return optax.apply_updates(p, u), s, m

    state, history = opt.init(params), []
    for _ in range(80):
        params, state, m = update(params, state)
        history.append({k: float(v) for k, v in m.items()})
    first, last = history[0], history[-1]
    print(f"PEL metrics {first} -> {last}")
    assert last["action_ce"] < 0.9 * first["action_ce"]
    assert last["contrastive"] < 0.9 * first["contrastive"]
    assert last["action_accuracy_newest"] > first["action_accuracy_newest"]
