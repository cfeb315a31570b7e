"""A compact IPPO / MAPPO trainer for partner policies (pure JAX, one jitted program).

Why its own trainer: partners are small feed-forward actor-critics trained once, offline, on a
:class:`~transam.envs.joint.JointView`; the agent-modeling A2C in ``transam.train`` solves a
different problem (one recurrent agent among fixed partners).

* Every learner has its own actor and critic (parameters stacked on a leading agent axis and
  vmapped), so the agents of one run can specialise (e.g. Overcooked onion vs dish roles).
* IPPO: each critic sees its agent's own features; MAPPO: each critic sees the concatenated
  features of all learners (centralised critic). Actors always see only their own observation.
* PPO-clip with GAE; episodes end at the game's terminal or its time limit (no bootstrap).
* ``gamma`` and the shaping ``weights`` are traced arguments, so seeds and discount factors of
  one recipe family share a single compiled program and are vmapped (``train_many``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, Literal, cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from transam import registry
from transam.envs.joint import JointView
from transam.envs.population import PolicyFn, ProbsFn

Algorithm = Literal["ippo", "mappo"]
Params = Any
LogitsFn = Callable[[jax.Array], jax.Array]
"""One member's logits over its actions from its own observation."""

ACT_MODES = ("sample", "argmax")
"""How a learned member picks its action from its logits (a property of each member)."""

FeatureFn = Callable[[jax.Array], jax.Array]


@dataclass(frozen=True)
class PPOConfig:
    """Static trainer settings (shared by every member of a compiled family)."""

    algorithm: Algorithm = "ippo"
    total_steps: int = 200_000  # joint transitions, summed over parallel environments
    num_envs: int = 32
    rollout_len: int = 64
    lr: float = 5e-4
    gae_lambda: float = 0.95
    clip: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    epochs: int = 4
    minibatches: int = 4
    hidden: int = 64
    checkpoints: int = 1  # actor snapshots at evenly spaced points (the last = final policy)

    @property
    def num_updates(self) -> int:
        per = self.checkpoints
        return max(per, self.total_steps // (self.num_envs * self.rollout_len) // per * per)


class MLP(nn.Module):
    """Two tanh hidden layers and a linear head."""

    hidden: int
    out: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = nn.tanh(nn.Dense(self.hidden)(x))
        x = nn.tanh(nn.Dense(self.hidden)(x))
        return nn.Dense(self.out, kernel_init=nn.initializers.orthogonal(0.01))(x)


def apply(net: nn.Module, params: Params, x: jax.Array) -> jax.Array:
    """``net.apply`` typed as returning one array."""
    return cast(jax.Array, net.apply(params, x))


def identity_features(obs: jax.Array) -> jax.Array:
    return obs


def lbf_features(obs: jax.Array) -> jax.Array:
    """LBF (4 foods, full view): foods relative to self, so a small MLP learns fast.

    Absolute coordinates make "go to the nearest food" a hard function for an MLP; the
    relative offsets (scaled by the grid size) make it nearly linear.
    """
    foods, me, other = obs[:12].reshape(4, 3), obs[12:15], obs[15:18]
    alive = (foods[:, 2] > 0).astype(jnp.float32)
    rel = (foods[:, :2] - me[:2]) * alive[:, None] / 20.0
    near = (jnp.sum(jnp.abs(foods[:, :2] - me[:2]), -1) == 1).astype(jnp.float32) * alive
    orel = (other[:2] - me[:2]) / 20.0
    return jnp.concatenate(
        [rel.ravel(), foods[:, 2] / 4.0, alive, near, me[2:3] / 2.0, me[:2] / 20.0, orel, other[2:]]
    )


def overcooked_features(obs: jax.Array) -> jax.Array:
    """Overcooked 520-vector with the cook-time channel (19..1) scaled into [0, 1]."""
    grid = obs.reshape(4, 5, 26)
    return grid.at[..., 20].multiply(1.0 / 20.0).reshape(-1)


def features(view_name: str) -> FeatureFn:
    """A learned partner's observation features in env ``view_name`` (its registry entry's
    ``features``; the observation itself by default)."""
    feat: FeatureFn = registry.resolve(registry.env_entry(view_name).features) or identity_features
    return feat


def make_logits(params: Params, view_name: str, num_actions: int, hidden: int) -> LogitsFn:
    """The actor's logits as a function of one observation, closing over ``params``."""
    net = MLP(hidden, num_actions)
    feat = features(view_name)
    params = jax.tree.map(jnp.asarray, params)
    return lambda obs: apply(net, params, feat(obs))


def check_act(act: str) -> None:
    """Raise ValueError for an action selection outside :data:`ACT_MODES`, naming the choices."""
    if act not in ACT_MODES:
        raise ValueError(f"unknown action selection {act!r}; valid choices: {', '.join(ACT_MODES)}")


def select(logits_fn: LogitsFn, act: str = "sample") -> PolicyFn:
    """A member's act function from its logits: ``"sample"`` draws from the softmax,
    ``"argmax"`` plays the most likely action (greedy, deterministic; the key is unused)."""
    check_act(act)
    if act == "argmax":
        return lambda key, obs: jnp.argmax(logits_fn(obs)).astype(jnp.int32)
    return lambda key, obs: jax.random.categorical(key, logits_fn(obs)).astype(jnp.int32)


def select_probs(logits_fn: LogitsFn, act: str = "sample") -> ProbsFn:
    """The action distribution :func:`select` draws from: the softmax for ``"sample"``, a
    one-hot of the argmax for ``"argmax"``."""
    check_act(act)
    if act == "argmax":

        def greedy(obs: jax.Array) -> jax.Array:
            logits = logits_fn(obs)
            return jax.nn.one_hot(jnp.argmax(logits), logits.shape[-1])

        return greedy
    return lambda obs: jax.nn.softmax(logits_fn(obs))


def make_policy(
    params: Params, view_name: str, num_actions: int, hidden: int, act: str = "sample"
) -> PolicyFn:
    """A population member's act function: the actor closing over ``params``, sampling or
    greedy (:func:`select`)."""
    return select(make_logits(params, view_name, num_actions, hidden), act)


def make_train(
    view: JointView, cfg: PPOConfig
) -> Callable[[jax.Array, jax.Array, jax.Array], tuple[Params, jax.Array]]:
    """``train(key, gamma, weights [A, 3]) -> (actor params [K, A, ...], curve [U, A])``.

    K = ``cfg.checkpoints`` snapshots (the last is the final policy).

    The curve is the mean per-step score of each agent in each update's rollout, times the
    episode length (an on-policy estimate of the episode return).
    """
    A, E, T = view.num_agents, cfg.num_envs, cfg.rollout_len
    feat = features(view.name)
    actor = MLP(cfg.hidden, view.num_actions)
    critic = MLP(cfg.hidden, 1)
    fdim = int(feat(jnp.zeros(view.obs_dim)).shape[0])
    cdim = fdim * A if cfg.algorithm == "mappo" else fdim
    tx = optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), optax.adam(cfg.lr, eps=1e-5))

    def critic_in(f: jax.Array) -> jax.Array:
        """[..., A, F] -> [..., A, C] critic inputs (own or all features)."""
        if cfg.algorithm == "mappo":
            flat = f.reshape(*f.shape[:-2], A * fdim)
            return jnp.broadcast_to(flat[..., None, :], (*f.shape[:-2], A, A * fdim))
        return f

    def apply_actor(p: Params, f: jax.Array) -> jax.Array:  # f [..., A, F]
        lead = f.shape[:-2]
        f2 = jnp.moveaxis(f.reshape(-1, A, f.shape[-1]), 1, 0)
        out = jax.vmap(partial(apply, actor))(p, f2)
        return jnp.moveaxis(out, 0, 1).reshape(*lead, A, -1)

    def apply_critic(p: Params, c: jax.Array) -> jax.Array:
        lead = c.shape[:-2]
        c2 = jnp.moveaxis(c.reshape(-1, A, c.shape[-1]), 1, 0)
        out = jax.vmap(partial(apply, critic))(p, c2)[..., 0]
        return jnp.moveaxis(out, 0, 1).reshape(*lead, A)

    def env_reset(key: jax.Array) -> tuple[Any, jax.Array]:
        s = view.reset(key)
        return s, jnp.zeros((), jnp.int32)

    def train(key: jax.Array, gamma: jax.Array, weights: jax.Array) -> tuple[Params, jax.Array]:
        k_a, k_c, k_env, k_loop = jax.random.split(key, 4)
        params = {
            "actor": jax.vmap(actor.init, (0, None))(jax.random.split(k_a, A), jnp.zeros(fdim)),
            "critic": jax.vmap(critic.init, (0, None))(jax.random.split(k_c, A), jnp.zeros(cdim)),
        }
        opt = tx.init(params)
        env_state, env_t = jax.vmap(env_reset)(jax.random.split(k_env, E))

        def env_step(carry: Any, key: jax.Array) -> tuple[Any, Any]:
            params, env_state, env_t = carry
            obs = jax.vmap(view.observe)(env_state)  # [E, A, D]
            f = jax.vmap(jax.vmap(feat))(obs)
            logits = apply_actor(params["actor"], f)
            value = apply_critic(params["critic"], critic_in(f))
            k_act, k_step, k_reset = jax.random.split(key, 3)
            action = jax.random.categorical(k_act, logits).astype(jnp.int32)
            logp = jnp.take_along_axis(jax.nn.log_softmax(logits), action[..., None], -1)[..., 0]
            nxt, reward, score, term = jax.vmap(view.step, (0, 0, 0, None))(
                jax.random.split(k_step, E), env_state, action, weights
            )
            t = env_t + 1
            done = term | (t >= view.episode_len)
            fresh, t0 = jax.vmap(env_reset)(jax.random.split(k_reset, E))
            pick = lambda a, b: jnp.where(done.reshape(-1, *([1] * (a.ndim - 1))), a, b)
            nxt = jax.tree.map(pick, fresh, nxt)
            t = jnp.where(done, t0, t)
            step = (f, action, logp, value, reward, score, done)
            return (params, nxt, t), step

        def update(carry: Any, key: jax.Array) -> tuple[Any, jax.Array]:
            params, opt, env_state, env_t = carry
            k_roll, k_perm = jax.random.split(key)
            (_, env_state, env_t), traj = jax.lax.scan(
                env_step, (params, env_state, env_t), jax.random.split(k_roll, T)
            )
            f, action, logp, value, reward, score, done = traj
            last_obs = jax.vmap(view.observe)(env_state)
            last_f = jax.vmap(jax.vmap(feat))(last_obs)
            last_v = apply_critic(params["critic"], critic_in(last_f))

            def gae(carry: Any, x: Any) -> tuple[Any, jax.Array]:
                adv, next_v = carry
                r, v, d = x
                nonterm = 1.0 - d[:, None].astype(jnp.float32)
                delta = r + gamma * next_v * nonterm - v
                adv = delta + gamma * cfg.gae_lambda * nonterm * adv
                return (adv, v), adv

            _, adv = jax.lax.scan(
                gae, (jnp.zeros_like(last_v), last_v), (reward, value, done), reverse=True
            )
            ret = adv + value
            batch = jax.tree.map(
                lambda x: x.reshape(T * E, *x.shape[2:]), (f, action, logp, adv, ret)
            )

            def loss_fn(p: Params, mb: Any) -> jax.Array:
                f, a, old_logp, adv, ret = mb
                logits = apply_actor(p["actor"], f)
                logp_all = jax.nn.log_softmax(logits)
                new_logp = jnp.take_along_axis(logp_all, a[..., None], -1)[..., 0]
                adv = (adv - adv.mean(0)) / (adv.std(0) + 1e-8)
                ratio = jnp.exp(new_logp - old_logp)
                clipped = jnp.clip(ratio, 1 - cfg.clip, 1 + cfg.clip)
                pg = -jnp.mean(jnp.minimum(ratio * adv, clipped * adv))
                v = apply_critic(p["critic"], critic_in(f))
                vf = 0.5 * jnp.mean(jnp.square(v - ret))
                ent = -jnp.mean(jnp.sum(jnp.exp(logp_all) * logp_all, -1))
                return pg + cfg.vf_coef * vf - cfg.ent_coef * ent

            def epoch(carry: Any, key: jax.Array) -> tuple[Any, None]:
                params, opt = carry
                perm = jax.random.permutation(key, T * E)
                mbs = jax.tree.map(
                    lambda x: x[perm].reshape(cfg.minibatches, -1, *x.shape[1:]), batch
                )

                def sgd(carry: Any, mb: Any) -> tuple[Any, None]:
                    params, opt = carry
                    grads = jax.grad(loss_fn)(params, mb)
                    upd, opt = tx.update(grads, opt, params)
                    return (optax.apply_updates(params, upd), opt), None

                return jax.lax.scan(sgd, (params, opt), mbs)[0], None

            (params, opt), _ = jax.lax.scan(
                epoch, (params, opt), jax.random.split(k_perm, cfg.epochs)
            )
            curve = jnp.mean(score, axis=(0, 1)) * view.episode_len
            return (params, opt, env_state, env_t), curve

        def chunk(carry: Any, keys: jax.Array) -> tuple[Any, tuple[Params, jax.Array]]:
            carry, curve = jax.lax.scan(update, carry, keys)
            return carry, (carry[0]["actor"], curve)

        keys = jax.random.split(k_loop, cfg.num_updates).reshape(cfg.checkpoints, -1, 2)
        _, (snaps, curve) = jax.lax.scan(chunk, (params, opt, env_state, env_t), keys)
        return snaps, curve.reshape(-1, A)

    return train


def train_many(
    view: JointView,
    cfg: PPOConfig,
    seeds: list[int],
    gammas: list[float],
    weights: list[np.ndarray] | None = None,
) -> tuple[Params, np.ndarray]:
    """Train one run per (seed, gamma, weights) in one vmapped, jitted program.

    Returns actor params with leading axes [run, checkpoint, agent] and score curves
    [run, update, agent].
    """
    n = len(seeds)
    if weights is None:
        weights = [np.zeros((view.num_agents, 3), np.float32)] * n
    keys = jnp.stack([jax.random.PRNGKey(s) for s in seeds])
    fn = jax.jit(jax.vmap(make_train(view, cfg)))
    params, curve = fn(keys, jnp.asarray(gammas, jnp.float32), jnp.asarray(np.stack(weights)))
    return jax.device_get(params), np.asarray(curve)
