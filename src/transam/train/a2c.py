"""A2C with an agent model, PureJaxRL style: pure functions, one jitted program per chunk.

One *update* = a rollout of ``n_steps`` (``lax.scan`` over time; environments, agent model and
policy batched over ``num_envs``), then GAE, the A2C loss and the agent-model loss, their
gradients and one Adam step for each network (each with its own optimiser and gradient clip).
:func:`make_chunk` scans U updates into one program; the Python loop around it logs, evaluates
and checkpoints.

Data flow per step (the execution path sees only :class:`LocalStep` data)::

    z_t = model.step(carry, LocalStep(o_t, a_{t-1}, r_{t-1}, t, first_t))
    logits_t, V_t = policy(o_t, z_t)            # LSTM carry zeroed when first_t
    a_t ~ logits_t; env.step -> r_t, done_t, o_{t+1}, PartnerRecord_t (training-only targets)
    first_{t+1} = done_t; a_t, r_t become 0 in the next LocalStep when done_t

Each rollout stores the carries it started from, so the training path (``policy.unroll``,
``model.loss`` and, with ``backprop_encoder``, ``model.embed_rollout``) recomputes exactly what
acting computed, with gradients. With ``recompute_z`` (default) the policy loss reads z
recomputed by the model's current parameters, as the reference does: with ``z_pass="shared"``
(default, the reference's one forward per update) it is the z of the agent-model loss's own
pass (``model.loss_and_embed``, TransAM family), otherwise a pass of its own; without
``recompute_z``, the stored execution-path z.

Episodes end by time limit or termination alike (``done``); no bootstrapping across ``done``,
as in the reference A2C; at a time limit the return bootstraps from the running mean of returns
(``end_bootstrap="return_mean"``, what the reference's code does; ``"zero"``: the end is
terminal). With ``normalize_returns`` the critic predicts standardised returns (running
mean/std of the GAE returns) and advantages are on the same scale. Steps are controlled-agent
steps summed over parallel environments.

The defaults are the reference's scheme (``rollouts_per_collect`` C = 5, see
:func:`make_update`): C rollouts are collected with the same parameters (returns and the return
normaliser computed rollout by rollout as they come in), then C updates run in order, update c
on rollout c, each from the policy carry and window that acting had at the start of rollout c;
the advantage is the normalised return minus the value recomputed in the update, the value
loss (R - V)^2, z is recomputed by the update (``recompute_z``) in the loss's own pass
(``z_pass``) with the encoder's dropout on (``act_dropout``), and the model reconstructs at
``recon_at="window"``. C = 1, ``advantage="gae"`` and the other alternatives are each one
setting away (docs/methods.md lists them and what each was measured to do; ``time_feature``
adds the agent's clock t / episode_len to the policy input, which the reference does not have).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from transam.envs.core import ControlledEnv, EnvState, PartnerRecord
from transam.models.base import (
    AgentModel,
    LocalStep,
    PartnerView,
    partner_view,
    run_embed,
    run_step,
)
from transam.models.policy import Policy
from transam.train.config import TrainConfig

Metrics = dict[str, jax.Array]


@struct.dataclass
class RunningStat:
    """Running mean and variance of the returns (parallel Welford), for value normalisation."""

    mean: jax.Array
    var: jax.Array
    count: jax.Array

    @staticmethod
    def create() -> RunningStat:
        return RunningStat(jnp.zeros(()), jnp.ones(()), jnp.full((), 1e-4, jnp.float32))

    def update(self, x: jax.Array) -> RunningStat:
        b_mean, b_var, b_count = x.mean(), x.var(), jnp.asarray(x.size, jnp.float32)
        delta = b_mean - self.mean
        total = self.count + b_count
        m2 = self.var * self.count + b_var * b_count + delta**2 * self.count * b_count / total
        return RunningStat(self.mean + delta * b_count / total, m2 / total, total)

    @property
    def std(self) -> jax.Array:
        return jnp.sqrt(self.var + 1e-8)


@struct.dataclass
class RunnerState:
    """Everything a run carries from one update to the next (checkpointed whole).

    Batched leaves have a leading ``num_envs`` axis (and a seed axis in front when seeds are
    vmapped). ``key`` holds raw key data so the state serialises with msgpack.
    """

    policy_params: Any
    policy_opt: Any
    model_params: Any
    model_opt: Any
    env_state: EnvState
    x: LocalStep  # what the agent knows at its next step
    policy_carry: Any  # LSTM carry before x
    model_carry: Any  # agent-model carry before x
    ret_stat: RunningStat
    ep_return: jax.Array  # [num_envs] return so far of each running episode
    key: jax.Array  # raw uint32 key data
    update: jax.Array  # int32 updates done
    episodes: jax.Array  # int32 training episodes completed


@struct.dataclass
class Trajectory:
    """One rollout, time-major ([T, num_envs, ...]), plus the carries it started from."""

    x: LocalStep
    z: jax.Array  # execution-path embeddings
    action: jax.Array
    reward: jax.Array
    done: jax.Array
    truncated: jax.Array  # done by the time limit (not by termination)
    value: jax.Array  # critic output (normalised scale when normalize_returns)
    record: PartnerRecord  # training-only targets of the agent-model loss
    partner: PartnerView | None  # the Oracle's execution-time partner input (None otherwise)
    finished_return: jax.Array  # return of the episode that ended at t (0 where none did)
    policy_carry0: Any
    model_carry0: Any


def steps_per_update(config: TrainConfig) -> int:
    return config.a2c.num_envs * config.a2c.n_steps


def total_updates(config: TrainConfig) -> int:
    """Updates in the run: total_steps rounded up to whole collections (of
    ``rollouts_per_collect`` updates each)."""
    per_collect = steps_per_update(config) * config.a2c.rollouts_per_collect
    return -(-config.total_steps // per_collect) * config.a2c.rollouts_per_collect


def anneal_updates(config: TrainConfig) -> int:
    """Updates over which an annealed policy learning rate falls to 0."""
    steps = config.a2c.anneal_steps
    return -(-steps // steps_per_update(config)) if steps else total_updates(config)


def make_policy(config: TrainConfig, env: ControlledEnv) -> Policy:
    a = config.a2c
    horizon = env.spec.episode_len if a.time_feature else None
    return Policy(
        env.spec.num_actions,
        a.hidden,
        horizon=horizon,
        critic_z=a.critic_z,
        torch_init=a.init == "torch",
        z_scale=a.z_scale,
    )


def make_optimizers(config: TrainConfig) -> tuple[optax.GradientTransformation, ...]:
    """(policy optimiser, agent-model optimiser): each clips its own gradient norm."""
    a = config.a2c
    lr: float | optax.Schedule = a.lr
    if a.anneal_lr:
        lr = optax.linear_schedule(a.lr, 0.0, anneal_updates(config))
    policy_tx = optax.chain(
        optax.clip_by_global_norm(a.max_grad_norm), optax.adam(lr, eps=a.adam_eps)
    )
    model_tx = optax.chain(
        optax.clip_by_global_norm(a.max_grad_norm), optax.adam(a.model_lr, eps=a.model_adam_eps)
    )
    return policy_tx, model_tx


def first_step(obs: jax.Array) -> LocalStep:
    """The LocalStep of a batch of freshly reset environments."""
    n = obs.shape[:-1]
    return LocalStep(
        obs=obs,
        prev_action=jnp.zeros(n, jnp.int32),
        prev_reward=jnp.zeros(n, jnp.float32),
        t=jnp.zeros(n, jnp.int32),
        first=jnp.ones(n, bool),
    )


def batch_carry(carry: Any, n: int) -> Any:
    """Copy a single-env carry ``n`` times along a new leading axis."""
    return jax.tree.map(lambda a: jnp.broadcast_to(a, (n, *jnp.shape(a))), carry)


def model_step(
    model: AgentModel,
    params: Any,
    carry: Any,
    x: LocalStep,
    partner: PartnerView | None,
    key: jax.Array | None = None,
) -> tuple[Any, jax.Array]:
    """``model.step`` on a batch (:func:`~transam.models.base.run_step`: only a privileged
    model is handed the partner view). With a ``key`` (``act_dropout``) the model applies its
    dropout, one key per env."""
    keys = None if key is None else jax.random.split(key, x.first.shape[0])

    def one(c: Any, x: LocalStep, view: PartnerView | None, k: jax.Array | None) -> Any:
        return run_step(model, params, c, x, view, k)

    return jax.vmap(one)(carry, x, partner, keys)


def act(
    policy: Policy,
    model: AgentModel,
    policy_params: Any,
    model_params: Any,
    policy_carry: Any,
    model_carry: Any,
    x: LocalStep,
    env_state: EnvState,
    key: jax.Array | None = None,
) -> tuple[Any, Any, jax.Array, jax.Array, jax.Array]:
    """Execution path on a batch (``x`` is what the agent knows in ``env_state``): (policy
    carry, model carry, z, logits, value). ``key``: the model's dropout (``act_dropout``)."""
    partner = partner_view(model, env_state)
    model_carry, z = model_step(model, model_params, model_carry, x, partner, key)
    policy_carry, logits, value = policy.step(policy_params, policy_carry, x, z)
    return policy_carry, model_carry, z, logits, value


def env_step(
    env: ControlledEnv, key: jax.Array, env_state: EnvState, action: jax.Array
) -> tuple[EnvState, Any, LocalStep]:
    """Step a batch of environments; the next LocalStep forgets a_t and r_t at an episode end
    (the environment has already auto-reset, and ``first`` marks the new episode)."""
    keys = jax.random.split(key, action.shape[0])
    env_state, ts = jax.vmap(env.step)(keys, env_state, action)
    x = LocalStep(
        obs=ts.obs,
        prev_action=jnp.where(ts.done, 0, action).astype(jnp.int32),
        prev_reward=jnp.where(ts.done, 0.0, ts.reward),
        t=env_state.t,
        first=ts.done,
    )
    return env_state, ts, x


def init_runner(
    config: TrainConfig, env: ControlledEnv, model: AgentModel, key: jax.Array
) -> RunnerState:
    """A fresh run: parameters, optimiser states, reset environments, zero carries."""
    n = config.a2c.num_envs
    policy = make_policy(config, env)
    policy_tx, model_tx = make_optimizers(config)
    k_policy, k_model, k_env, k_run = jax.random.split(key, 4)
    model_params = model.init(k_model, env.spec)
    policy_params = policy.init(k_policy, env.spec.obs_dim, model.embed_dim)
    env_state, obs = jax.vmap(env.reset)(jax.random.split(k_env, n))
    state = RunnerState(
        policy_params=policy_params,
        policy_opt=policy_tx.init(policy_params),
        model_params=model_params,
        model_opt=model_tx.init(model_params),
        env_state=env_state,
        x=first_step(obs),
        policy_carry=policy.init_carry((n,)),
        model_carry=batch_carry(model.init_carry(env.spec), n),
        ret_stat=RunningStat.create(),
        ep_return=jnp.zeros((n,), jnp.float32),
        key=jax.random.key_data(k_run),
        update=jnp.zeros((), jnp.int32),
        episodes=jnp.zeros((), jnp.int32),
    )
    # No weak types (e.g. an environment's Python-int step counter): a state restored from a
    # checkpoint has none, and it must hit the same compiled program as a fresh one.
    return jax.tree.map(lambda a: jnp.asarray(a, dtype=a.dtype), state)


def make_rollout(
    config: TrainConfig, env: ControlledEnv, model: AgentModel
) -> Callable[[RunnerState, jax.Array], tuple[RunnerState, Trajectory]]:
    """``(state, key) -> (state after n_steps, trajectory)`` (pure; not jitted)."""
    policy = make_policy(config, env)
    dropout = config.acting_dropout

    def rollout(rs: RunnerState, key: jax.Array) -> tuple[RunnerState, Trajectory]:
        def body(carry: tuple[Any, ...], key: jax.Array) -> tuple[tuple[Any, ...], Any]:
            env_state, x, pc, mc, ep_ret = carry
            k_act, k_env = jax.random.split(key)
            k_drop = jax.random.fold_in(key, 1) if dropout else None
            partner = partner_view(model, env_state)
            pc, mc, z, logits, value = act(
                policy, model, rs.policy_params, rs.model_params, pc, mc, x, env_state, k_drop
            )
            action = jax.random.categorical(k_act, logits).astype(jnp.int32)
            env_state, ts, x_next = env_step(env, k_env, env_state, action)
            ep_ret = ep_ret + ts.reward
            finished = jnp.where(ts.done, ep_ret, 0.0)
            ep_ret = jnp.where(ts.done, 0.0, ep_ret)
            out = (x, z, action, ts.reward, ts.done, ts.truncated, value, ts.record, partner)
            return (env_state, x_next, pc, mc, ep_ret), (*out, finished)

        init = (rs.env_state, rs.x, rs.policy_carry, rs.model_carry, rs.ep_return)
        keys = jax.random.split(key, config.a2c.n_steps)
        (env_state, x, pc, mc, ep_ret), outs = jax.lax.scan(body, init, keys)
        x_seq, z, action, reward, done, truncated, value, record, partner, finished = outs
        traj = Trajectory(
            x=x_seq,
            z=z,
            action=action,
            reward=reward,
            done=done,
            truncated=truncated,
            value=value,
            record=record,
            partner=partner,
            finished_return=finished,
            policy_carry0=rs.policy_carry,
            model_carry0=rs.model_carry,
        )
        rs = dataclasses.replace(
            rs,
            env_state=env_state,
            x=x,
            policy_carry=pc,
            model_carry=mc,
            ep_return=ep_ret,
            episodes=rs.episodes + traj.done.sum(dtype=jnp.int32),
        )
        return rs, traj

    return rollout


def gae(
    reward: jax.Array,
    value: jax.Array,
    done: jax.Array,
    last_value: jax.Array,
    gamma: float,
    lam: float,
    end_value: jax.Array | None = None,
    truncated: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """(advantages, returns), time-major; nothing is bootstrapped across ``done``. With
    ``end_value`` and ``truncated``, a step that ends its episode by the time limit bootstraps
    from ``end_value`` instead of 0 (the advantage recursion still stops there)."""
    if end_value is None or truncated is None:
        end_value, truncated = jnp.zeros_like(last_value), jnp.zeros_like(done)

    def body(carry: tuple[jax.Array, jax.Array], inp: tuple[jax.Array, ...]) -> Any:
        next_adv, next_value = carry
        r, v, d, tr = inp
        cont = 1.0 - d.astype(jnp.float32)
        end = tr.astype(jnp.float32) * end_value
        delta = r + gamma * (next_value * cont + end) - v
        adv = delta + gamma * lam * cont * next_adv
        return (adv, v), adv

    _, adv = jax.lax.scan(
        body,
        (jnp.zeros_like(last_value), last_value),
        (reward, value, done, truncated),
        reverse=True,
    )
    return adv, adv + value


def policy_entropy(logits: jax.Array) -> jax.Array:
    """The categorical policy's entropy (nats) per row of ``logits`` [..., actions]."""
    logp = jax.nn.log_softmax(logits)
    return -(jnp.exp(logp) * logp).sum(-1)


def a2c_losses(
    policy: Policy,
    policy_params: Any,
    traj: Trajectory,
    z: jax.Array,
    advantages: jax.Array,
    targets: jax.Array,
    advantage: str = "gae",
    value_loss: str = "half_squared",
    normalize_advantages: bool = False,
) -> dict[str, jax.Array]:
    """Policy-gradient, value and entropy terms of the rollout (means over steps and envs).

    ``advantage="gae"``: the policy gradient weighs log pi by ``advantages``;
    ``"recomputed"`` (the reference): by ``targets`` minus the value the critic gives now
    (``advantages`` unused). ``value_loss``: 0.5 (R - V)^2 or (R - V)^2 (the reference).
    """
    _, logits, values = policy.unroll(policy_params, traj.policy_carry0, traj.x, z)
    logp_all = jax.nn.log_softmax(logits)
    logp = jnp.take_along_axis(logp_all, traj.action[..., None], axis=-1)[..., 0]
    entropy = policy_entropy(logits).mean()
    if advantage == "recomputed":
        advantages = targets - values
    advantages = jax.lax.stop_gradient(advantages)
    adv_mean = advantages.mean()
    if normalize_advantages and advantage == "recomputed":
        advantages = (advantages - adv_mean) / (advantages.std() + 1e-8)
    scale = 0.5 if value_loss == "half_squared" else 1.0
    return {
        "policy_loss": -(advantages * logp).mean(),
        "value_loss": scale * ((values - targets) ** 2).mean(),
        "entropy": entropy,
        "advantage_mean": adv_mean,
    }


@struct.dataclass
class Collected:
    """What one rollout of a collection leaves for its update (time-major [T, num_envs])."""

    traj: Trajectory
    advantages: jax.Array  # GAE advantages (divided by the return std when normalised)
    targets: jax.Array  # value targets (standardised when normalised)


def make_collect(
    config: TrainConfig, env: ControlledEnv, model: AgentModel
) -> Callable[[RunnerState, jax.Array], tuple[RunnerState, Collected]]:
    """``(state, keys [C]) -> (state, Collected [C, T, ...])``: C rollouts with the state's
    parameters, each followed by its bootstrap value (acting on the next observation with the
    same parameters), GAE and the update of the return normaliser (pure; not jitted)."""
    a = config.a2c
    policy = make_policy(config, env)
    rollout = make_rollout(config, env, model)

    def one(rs: RunnerState, key: jax.Array) -> tuple[RunnerState, Collected]:
        rs, traj = rollout(rs, key)
        k_drop = jax.random.fold_in(key, 1) if config.acting_dropout else None
        _, _, _, _, last_value = act(
            policy,
            model,
            rs.policy_params,
            rs.model_params,
            rs.policy_carry,
            rs.model_carry,
            rs.x,
            rs.env_state,
            k_drop,
        )
        stat = rs.ret_stat
        if a.normalize_returns:
            value, last_value = traj.value * stat.std + stat.mean, last_value * stat.std + stat.mean
        else:
            value = traj.value
        # The reference bootstraps an episode's end from 0 in normalised units, i.e. from the
        # running mean of returns once de-normalised (its done flags never cut the last step).
        end_value = stat.mean if a.end_bootstrap == "return_mean" else None
        adv, returns = gae(
            traj.reward,
            value,
            traj.done,
            last_value,
            a.gamma,
            a.gae_lambda,
            end_value,
            traj.truncated,
        )
        if a.normalize_returns:
            # The critic regresses standardised returns, and the advantages are put on the
            # same scale (as the reference's "normalised return - value"), so that the entropy
            # bonus weighs the same against them whatever the reward scale.
            stat = stat.update(returns)
            targets = (returns - stat.mean) / stat.std
            adv = adv / stat.std
        else:
            targets = returns
        return dataclasses.replace(rs, ret_stat=stat), Collected(traj, adv, targets)

    def collect(rs: RunnerState, keys: jax.Array) -> tuple[RunnerState, Collected]:
        return jax.lax.scan(one, rs, keys)

    return collect


def _prior_records(
    records: PartnerRecord, index: jax.Array, k: int
) -> tuple[PartnerRecord, jax.Array]:
    """The K-1 = ``k`` records before rollout ``index`` of a collection ([C, T, N, ...]), and
    which of them exist (those from before the collection do not): [k, N, ...], [k, N]."""
    c, t, n = records.t.shape
    flat = jax.tree.map(lambda r: r.reshape(c * t, *r.shape[2:]), records)
    padded = jax.tree.map(lambda r: jnp.concatenate([jnp.zeros_like(r[:k]), r]), flat)
    start = index * t  # padded[start + i] is step index * t - k + i of the collection
    prior = jax.tree.map(lambda r: jax.lax.dynamic_slice_in_dim(r, start, k), padded)
    ok = (start - k + jnp.arange(k)) >= 0
    return prior, jnp.broadcast_to(ok[:, None], (k, n))


def make_update(
    config: TrainConfig, env: ControlledEnv, model: AgentModel
) -> Callable[[RunnerState], tuple[RunnerState, Metrics]]:
    """One collection and its updates (pure; not jitted): ``rollouts_per_collect`` = C
    rollouts collected with the same parameters (:func:`make_collect`), then C A2C +
    agent-model updates in order, update c on rollout c, each a gradient step of both
    networks from the parameters the previous one left. C = 1 is plain A2C: rollout, update.
    With ``model_passes`` P > 1, P - 1 further passes over the C rollouts follow, each an
    agent-model-only step per rollout. Metrics are means over the C updates (``episodes``,
    ``return_sum``: sums)."""
    a = config.a2c
    num = a.rollouts_per_collect
    policy = make_policy(config, env)
    policy_tx, model_tx = make_optimizers(config)
    collect = make_collect(config, env, model)
    prior_k = model.prior_steps  # positions before a rollout that get their targets

    def prior_of(records: PartnerRecord, index: jax.Array) -> dict[str, Any]:
        """The targets of the window positions before rollout ``index`` (recon_at="window")."""
        if not prior_k:
            return {}
        prior, prior_ok = _prior_records(records, index, prior_k)
        return {"prior": prior, "prior_ok": prior_ok}

    def learn(
        rs: RunnerState, col: Collected, key: jax.Array, index: jax.Array, records: PartnerRecord
    ) -> tuple[RunnerState, Metrics]:
        traj, adv, targets = col.traj, col.advantages, col.targets
        adv_mean = adv.mean()  # ~0 when the critic is unbiased
        if a.normalize_advantages and a.advantage == "gae":
            adv = (adv - adv_mean) / (adv.std() + 1e-8)
        prior = prior_of(records, index)
        z_keys = None
        if config.acting_dropout:  # the policy's z is recomputed (or back-propagated) with dropout
            z_keys = jax.random.split(jax.random.fold_in(key, 1), traj.x.first.shape[1])

        def embed(model_params: Any) -> jax.Array:
            """z [T, N, ...] of the rollout by the training path (a privileged model also gets
            the rollout's partner views; with ``z_keys``, dropout)."""

            def one(c: Any, xs: LocalStep, views: PartnerView | None, k: Any) -> jax.Array:
                return run_embed(model, model_params, c, xs, views, k)

            fn = jax.vmap(one, in_axes=(0, 1, 1, 0), out_axes=1)
            return fn(traj.model_carry0, traj.x, traj.partner, z_keys)

        def loss_fn(policy_params: Any, model_params: Any) -> tuple[jax.Array, Metrics]:
            model_args = (model_params, traj.model_carry0, traj.x, traj.record, key)
            am, am_metrics, z_loss = model.loss_and_embed(*model_args, **prior)
            if config.z_from_loss_pass and z_loss is not None:
                # z_pass="shared": z off the loss's own pass (the reference's one forward), for
                # a model whose loss has one (the TransAM family)
                z = jax.lax.stop_gradient(z_loss)
            elif a.backprop_encoder:
                z = embed(model_params)
            elif a.recompute_z:  # the model's current parameters, no gradient into it
                z = jax.lax.stop_gradient(embed(model_params))
            else:
                z = traj.z
            terms = a2c_losses(
                policy,
                policy_params,
                traj,
                z,
                adv,
                targets,
                advantage=a.advantage,
                value_loss=a.value_loss,
                normalize_advantages=a.normalize_advantages,
            )
            a2c = (
                terms["policy_loss"]
                + a.vf_coef * terms["value_loss"]
                - a.ent_coef * terms["entropy"]
            )
            metrics = dict(terms)
            metrics["model_loss"] = am
            metrics.update({f"model/{k}": v for k, v in am_metrics.items()})
            return a2c + am, metrics

        grad_fn = jax.grad(loss_fn, argnums=(0, 1), has_aux=True)
        (g_policy, g_model), metrics = grad_fn(rs.policy_params, rs.model_params)
        upd, policy_opt = policy_tx.update(g_policy, rs.policy_opt, rs.policy_params)
        policy_params = optax.apply_updates(rs.policy_params, upd)
        upd, model_opt = model_tx.update(g_model, rs.model_opt, rs.model_params)
        model_params = optax.apply_updates(rs.model_params, upd)
        metrics["grad_norm/policy"] = optax.tree.norm(g_policy)
        metrics["grad_norm/model"] = optax.tree.norm(g_model)
        if a.advantage == "gae":
            metrics["advantage_mean"] = adv_mean
        metrics["episodes"] = traj.done.sum(dtype=jnp.int32)
        metrics["return_sum"] = traj.finished_return.sum()
        rs = dataclasses.replace(
            rs,
            policy_params=policy_params,
            policy_opt=policy_opt,
            model_params=model_params,
            model_opt=model_opt,
            update=rs.update + 1,
        )
        return rs, metrics

    def refit(
        rs: RunnerState, col: Collected, key: jax.Array, index: jax.Array, records: PartnerRecord
    ) -> tuple[RunnerState, jax.Array]:
        """A further agent-model-only gradient step on one rollout (``model_passes`` > 1)."""
        traj = col.traj

        def loss_fn(model_params: Any) -> tuple[jax.Array, Any]:
            args = (model_params, traj.model_carry0, traj.x, traj.record, key)
            return model.loss(*args, **prior_of(records, index))

        (loss, _), grads = jax.value_and_grad(loss_fn, has_aux=True)(rs.model_params)
        upd, model_opt = model_tx.update(grads, rs.model_opt, rs.model_params)
        model_params = optax.apply_updates(rs.model_params, upd)
        return dataclasses.replace(rs, model_params=model_params, model_opt=model_opt), loss

    def update(rs: RunnerState) -> tuple[RunnerState, Metrics]:
        key, k_roll, k_loss = jax.random.split(jax.random.wrap_key_data(rs.key), 3)
        # One rollout (the default) uses k_roll and k_loss themselves, as before collections.
        roll_keys = k_roll[None] if num == 1 else jax.random.split(k_roll, num)
        loss_keys = k_loss[None] if num == 1 else jax.random.split(k_loss, num)
        rs, collected = collect(rs, roll_keys)
        records = collected.traj.record

        def body(rs: RunnerState, inp: tuple[Any, ...]) -> tuple[RunnerState, Metrics]:
            col, k, index = inp
            return learn(rs, col, k, index, records)

        rs, metrics = jax.lax.scan(body, rs, (collected, loss_keys, jnp.arange(num)))
        metrics = _reduce(metrics)
        if a.model_passes > 1:  # each pass: the rollouts again, in order, fresh dropout keys
            pass_keys = jax.random.split(jax.random.fold_in(k_loss, 2), (a.model_passes - 1, num))

            def one_pass(rs: RunnerState, keys: jax.Array) -> tuple[RunnerState, jax.Array]:
                xs = (collected, keys, jnp.arange(num))
                return jax.lax.scan(lambda rs, inp: refit(rs, *inp, records), rs, xs)

            rs, losses = jax.lax.scan(one_pass, rs, pass_keys)
            metrics["model_loss_last_pass"] = losses[-1].mean()
        rs = dataclasses.replace(rs, key=jax.random.key_data(key))
        return rs, metrics

    return update


_SUMMED = ("episodes", "return_sum")


def _reduce(metrics: Metrics) -> Metrics:
    """Metrics stacked over updates -> sums of ``episodes`` and ``return_sum``, means of the
    rest."""
    return {k: v.sum(0) if k in _SUMMED else v.mean(0) for k, v in metrics.items()}


def make_chunk(
    config: TrainConfig, env: ControlledEnv, model: AgentModel, num_updates: int
) -> Callable[[RunnerState], tuple[RunnerState, Metrics]]:
    """A jitted ``state -> (state, metrics)`` doing ``num_updates`` updates in one ``lax.scan``
    (whole collections: a multiple of ``rollouts_per_collect``).

    Metrics are reduced over the chunk: ``episodes`` and ``return_sum`` are sums (training
    return = return_sum / episodes), everything else is a mean over updates, except the
    non-finite check's ``nonfinite`` and ``nonfinite_update`` (:func:`nonfinite_check`).
    """
    per = config.a2c.rollouts_per_collect
    if num_updates % per:
        raise ValueError(f"{num_updates} updates are not whole collections of {per}")
    update = make_update(config, env, model)

    def chunk(rs: RunnerState) -> tuple[RunnerState, Metrics]:
        start = rs.update
        rs, metrics = jax.lax.scan(lambda s, _: update(s), rs, None, length=num_updates // per)
        out = _reduce(metrics)
        out.update(nonfinite_check(metrics, rs, start, per))
        return rs, out

    return jax.jit(chunk)


NONFINITE_SCALARS = (
    "policy_loss",
    "value_loss",
    "entropy",
    "model_loss",
    "grad_norm/policy",
    "grad_norm/model",
)
NONFINITE_QUANTITIES = (*NONFINITE_SCALARS, "policy_params", "model_params")
"""What :func:`nonfinite_check` watches, in the order of its ``nonfinite`` flags."""
HEALTH_KEYS = ("nonfinite", "nonfinite_update")
"""The chunk metrics that are the check's output (not logged as training metrics)."""


def nonfinite_check(metrics: Metrics, rs: RunnerState, start: jax.Array, per: int = 1) -> Metrics:
    """Inside the chunk: ``nonfinite`` [Q] bool, which of NONFINITE_QUANTITIES went non-finite
    (the scalars at the first update where any did; the parameters at the chunk's end), and
    ``nonfinite_update``, the number (1-based) of that first update (0 when all are finite).
    ``metrics`` are stacked per collection of ``per`` updates (their means, so a non-finite
    update makes its collection's mean non-finite): the number is then that collection's first
    update. A few reductions per chunk over per-update scalars and one over the parameters."""
    bad = jnp.stack([~jnp.isfinite(metrics[k]) for k in NONFINITE_SCALARS], -1)  # [U, Q]
    any_bad = bad.any(-1)
    first = jnp.argmax(any_bad)
    params_bad = jnp.stack([~_all_finite(rs.policy_params), ~_all_finite(rs.model_params)])
    flags = jnp.concatenate([bad[first] & any_bad[first], params_bad])
    update = jnp.where(
        any_bad.any(), start + first * per + 1, jnp.where(params_bad.any(), rs.update, 0)
    )
    return {"nonfinite": flags, "nonfinite_update": update.astype(jnp.int32)}


def _all_finite(tree: Any) -> jax.Array:
    leaves = jax.tree.leaves(tree)
    if not leaves:  # e.g. NAM has no agent-model parameters
        return jnp.array(True)
    return jnp.stack([jnp.isfinite(x).all() for x in leaves]).all()
