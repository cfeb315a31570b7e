"""How distinguishable a population's joint policies are (is there anything to model?).

* ``partner_id_accuracy``: a small MLP classifier predicts the partner (team) index from a
  window of W steps, either of the other agents' observations and actions (privileged view) or
  of the controlled agent's own observations, actions and rewards (local view), collected with
  a uniformly random controlled agent from the start of fresh episodes. Reported as held-out
  top-1 accuracy next to chance (1 / M).
* ``cross_play``: mean score of member i (partner slot) with member j in the stand-in's slot,
  for the games where learned members can fill the controlled slot (LBF, Overcooked).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from transam.envs.core import ControlledEnv
from transam.envs.population import Member
from transam.partners.train import apply


@dataclass(frozen=True)
class ClassifierConfig:
    window: int = 10  # steps per sample, from the episode start
    episodes_per_team: int = 96  # 3/4 train, 1/4 test
    hidden: int = 128
    train_steps: int = 400
    lr: float = 1e-3
    seed: int = 0


def collect(env: ControlledEnv, cfg: ClassifierConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(privileged windows [N, F1], local windows [N, F2], labels [N]) from fresh episodes."""
    m = env.num_partners
    labels = jnp.repeat(jnp.arange(m, dtype=jnp.int32), cfg.episodes_per_team)
    n_act, n_oth = env.spec.num_actions, env.spec.other_num_actions

    def episode(key: jax.Array, partner: jax.Array) -> tuple[jax.Array, jax.Array]:
        k0, k1 = jax.random.split(key)
        state, obs = env.reset(k0, partner)

        def body(carry: tuple, k: jax.Array) -> tuple:
            state, obs = carry
            ka, ks = jax.random.split(k)
            a = jax.random.randint(ka, (), 0, n_act, dtype=jnp.int32)
            state, ts = env.step(ks, state, a)
            rec = ts.record
            priv = jnp.concatenate(
                [rec.other_obs.ravel(), jax.nn.one_hot(rec.other_actions, n_oth).ravel()]
            )
            local = jnp.concatenate([obs, jax.nn.one_hot(a, n_act), ts.reward[None]])
            return (state, ts.obs), (priv, local)

        seq: Any = jax.lax.scan(body, (state, obs), jax.random.split(k1, cfg.window))[1]
        return seq[0].ravel(), seq[1].ravel()

    keys = jax.random.split(jax.random.PRNGKey(cfg.seed), labels.shape[0])
    out = jax.jit(jax.vmap(episode))(keys, labels)
    return np.asarray(out[0]), np.asarray(out[1]), np.asarray(labels)


class Classifier(nn.Module):
    hidden: int
    classes: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = nn.relu(nn.Dense(self.hidden)(x))
        x = nn.relu(nn.Dense(self.hidden)(x))
        return nn.Dense(self.classes)(x)


def fit_accuracy(x: np.ndarray, y: np.ndarray, classes: int, cfg: ClassifierConfig) -> float:
    """Held-out top-1 accuracy of a 2-layer MLP (every 4th sample of each class is test)."""
    test = np.arange(len(y)) % 4 == 0
    mean, std = x[~test].mean(0), x[~test].std(0) + 1e-6
    xs = (x - mean) / std
    net = Classifier(cfg.hidden, classes)
    tx = optax.adam(cfg.lr)
    xtr, ytr = jnp.asarray(xs[~test]), jnp.asarray(y[~test])

    def loss(p: Any, xb: jax.Array, yb: jax.Array) -> jax.Array:
        return optax.softmax_cross_entropy_with_integer_labels(apply(net, p, xb), yb).mean()

    @jax.jit
    def train(key: jax.Array) -> Any:
        p = net.init(key, xtr[:1])

        def step(carry: tuple, k: jax.Array) -> tuple:
            p, o = carry
            idx = jax.random.choice(k, xtr.shape[0], (256,))
            g = jax.grad(loss)(p, xtr[idx], ytr[idx])
            u, o = tx.update(g, o, p)
            return (optax.apply_updates(p, u), o), None

        keys = jax.random.split(key, cfg.train_steps)
        return jax.lax.scan(step, (p, tx.init(p)), keys)[0][0]

    params = train(jax.random.PRNGKey(cfg.seed))
    pred = np.asarray(jnp.argmax(apply(net, params, jnp.asarray(xs[test])), -1))
    return float(np.mean(pred == y[test]))


def partner_id_accuracy(env: ControlledEnv, cfg: ClassifierConfig | None = None) -> dict:
    """{"others": acc, "local": acc, "chance": 1/M, "teams": M}."""
    cfg = cfg or ClassifierConfig()
    priv, local, y = collect(env, cfg)
    m = env.num_partners
    return {
        "others": fit_accuracy(priv, y, m, cfg),
        "local": fit_accuracy(local, y, m, cfg),
        "chance": 1.0 / m,
        "teams": m,
    }


def cross_play(env: str, members: list[Member], episodes: int = 16) -> np.ndarray:
    """[n, n] team score with member i in the partner slot and member j in the stand-in's.

    Team score: the partner's sparse score in Overcooked (the soup reward is shared), the
    summed shares (fraction of food collected) in LBF. One compiled program for all pairs.
    """
    from transam.envs.joint import play
    from transam.partners.learned import joint_view

    view = joint_view(env)
    if view.controlled is None:
        raise ValueError(f"cross-play needs a learner in the controlled slot; {env} has none")
    slot, ctrl = view.partner_slots[0], view.controlled
    acts = [m.act for m in members]

    def pair(i: jax.Array, j: jax.Array) -> jax.Array:
        def pol(idx: jax.Array) -> Any:
            return lambda k, o: jax.lax.switch(idx, acts, k, o)

        pols = [pol(i)] * view.num_agents
        pols[ctrl] = pol(j)
        score = play(view, pols, jax.random.PRNGKey(0), episodes)[0]
        return jnp.sum(score) if env == "lbf" else score[slot]

    n = len(members)
    ii, jj = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    fn = jax.jit(jax.vmap(pair))
    return np.asarray(fn(jnp.asarray(ii.ravel()), jnp.asarray(jj.ravel()))).reshape(n, n)
