"""How distinguishable a population's joint policies are (is there anything to model?).

* ``partner_id_accuracy``: a small MLP classifier predicts the partner (team) index from a
  window of W steps, either of the other agents' observations and actions (privileged view) or
  of the controlled agent's own observations, actions and rewards (local view), collected with
  a uniformly random controlled agent from the start of fresh episodes. Reported as held-out
  top-1 accuracy next to chance (1 / M).
* ``cross_play``: mean score of member i (partner slot) with member j in the stand-in's slot,
  for the games where learned members can fill the controlled slot (LBF, Overcooked).
* ``action_levels``: where the agent models' action accuracy can lie, from the partners' steps
  under a uniformly random controlled agent (whole episodes, every team equally often):

  - the *ceiling* E[max_a pi(a | o)] of the partners under their own observations, averaged
    over teams, slots and steps: no predictor of their actions can expect more, even knowing
    the team and the partner's observation (1 for deterministic members). A member that
    declares its distribution (``Member.probs``: learned members) gives it exactly; for one
    that does not (heuristics), ``act`` is sampled ``samples`` times per observation and the
    most frequent action of one half is scored on the other half (a deterministic member
    scores exactly 1; a stochastic one is not inflated by picking the winner on the data
    that scores it, and reads slightly low where the first half picks a runner-up);
  - the *memoryless, team-agnostic* level: the held-out accuracy of an MLP predicting a
    partner's action from that partner's current observation and slot alone, trained pooled
    over all teams (every 4th episode of each team held out). A model at this level has
    learned nothing about whom it plays with; ``majority`` (each slot's most frequent action)
    gives the scale. The same from the controlled agent's view, from one step and from two
    (:func:`memoryless_accuracy`'s ``view``).

  ``controlled`` replaces the uniformly random controlled agent by a policy of its own
  observation (e.g. Spread's landmark rule), to see how much the levels depend on the states
  the controlled agent visits (a trained agent's are not random play's).
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from transam.envs.core import ControlledEnv
from transam.envs.population import Member, PolicyFn, Population
from transam.partners import learned
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


def fit_accuracy(
    x: np.ndarray,
    y: np.ndarray,
    classes: int,
    cfg: ClassifierConfig,
    test: np.ndarray | None = None,
) -> float:
    """Held-out top-1 accuracy of a 2-layer MLP (``test``: the held-out samples; default every
    4th sample)."""
    test = np.arange(len(y)) % 4 == 0 if test is None else np.asarray(test, bool)
    return float(np.mean(fit_hits(x, y, classes, cfg, test)))


def fit_hits(
    x: np.ndarray, y: np.ndarray, classes: int, cfg: ClassifierConfig, test: np.ndarray
) -> np.ndarray:
    """Whether a 2-layer MLP trained on the samples outside ``test`` predicts each ``test``
    sample right (bool, in order): :func:`fit_accuracy` per sample, for per-step levels."""
    test = np.asarray(test, bool)
    # Standardised part by part and handed to the program as arguments, not closed over as
    # constants: Overcooked's window features (2,601 numbers a sample) are gigabytes.
    seen = x[~test]
    mean, std = seen.mean(0), seen.std(0) + 1e-6
    xtr, ytr = jnp.asarray((seen - mean) / std), jnp.asarray(y[~test])
    del seen
    net = Classifier(cfg.hidden, classes)
    tx = optax.adam(cfg.lr)

    def loss(p: Any, xb: jax.Array, yb: jax.Array) -> jax.Array:
        return optax.softmax_cross_entropy_with_integer_labels(apply(net, p, xb), yb).mean()

    @jax.jit
    def train(key: jax.Array, xtr: jax.Array, ytr: jax.Array) -> Any:
        p = net.init(key, xtr[:1])

        def step(carry: tuple, k: jax.Array) -> tuple:
            p, o = carry
            idx = jax.random.choice(k, xtr.shape[0], (256,))
            g = jax.grad(loss)(p, xtr[idx], ytr[idx])
            u, o = tx.update(g, o, p)
            return (optax.apply_updates(p, u), o), None

        keys = jax.random.split(key, cfg.train_steps)
        return jax.lax.scan(step, (p, tx.init(p)), keys)[0][0]

    params = train(jax.random.PRNGKey(cfg.seed), xtr, ytr)
    del xtr
    pred = np.asarray(jnp.argmax(apply(net, params, jnp.asarray((x[test] - mean) / std)), -1))
    return pred == y[test]


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


# ---------------------------------------------------------------- action levels


@dataclass(frozen=True)
class LevelsConfig:
    """Settings of :func:`action_levels`."""

    steps_per_team: int = 25_600
    """env steps of whole episodes per team (3/4 train the memoryless classifier, 1/4 test
    it): 1,024 episodes of Spread, 64 of Overcooked. The levels are fits, so lower bounds: with
    64 Spread episodes and 2,000 steps (the settings until 2026-12-02) they read 0.08-0.13
    lower than with these (e.g. the authors' population, own view 0.39 against 0.50, two
    steps 0.52 against 0.65), and these still rise a little with more steps"""
    episodes_per_team: int | None = None
    """whole episodes per team instead of ``steps_per_team``'s (at least 4)"""
    samples: int = 64
    """draws of ``act`` per observation for a member without declared probabilities"""
    window: int = 5
    """K of the window level: the controlled agent's last K observations (view ``ownK``), the
    window TransAM's encoder reads by default (its ``context``)"""
    hidden: int = 128
    train_steps: int = 20_000
    lr: float = 1e-3
    seed: int = 0

    def episodes(self, episode_len: int) -> int:
        """Episodes per team for a game of ``episode_len`` steps."""
        if self.episodes_per_team is not None:
            return self.episodes_per_team
        return max(4, -(-self.steps_per_team // episode_len))


@dataclass(frozen=True)
class PartnerSteps:
    """The partners' observations and actions over whole episodes, one team per episode."""

    obs: np.ndarray  # [E, T, N, D] each partner's own observation
    own_obs: np.ndarray  # [E, T, D0] the controlled agent's observation at the same step
    actions: np.ndarray  # [E, T, N] int
    team: np.ndarray  # [E] team index
    live: np.ndarray  # [E, T] bool: the step belongs to the episode
    episode: np.ndarray  # [E] index of the episode within its team


def collect_partner_steps(
    env: ControlledEnv, episodes_per_team: int, seed: int, controlled: PolicyFn | None = None
) -> PartnerSteps:
    """Whole episodes of every team with a uniformly random controlled agent, or with
    ``controlled(key, obs) -> action``."""
    if episodes_per_team < 1:
        raise ValueError(f"episodes_per_team must be >= 1, got {episodes_per_team}")
    m, length = env.num_partners, env.spec.episode_len
    team = np.repeat(np.arange(m, dtype=np.int32), episodes_per_team)
    n_act = env.spec.num_actions

    def episode(key: jax.Array, partner: jax.Array) -> tuple[jax.Array, ...]:
        k0, k1 = jax.random.split(key)
        state, _ = env.reset(k0, partner)

        def body(carry: tuple, k: jax.Array) -> tuple:
            state, alive = carry
            ka, ks = jax.random.split(k)
            own = state.obs
            if controlled is None:
                a = jax.random.randint(ka, (), 0, n_act, dtype=jnp.int32)
            else:
                a = jnp.asarray(controlled(ka, own), jnp.int32)
            state, ts = env.step(ks, state, a)
            rec = ts.record
            return (state, alive & ~ts.done), (rec.other_obs, own, rec.other_actions, alive)

        keys = jax.random.split(k1, length)
        return jax.lax.scan(body, (state, jnp.ones((), bool)), keys)[1]

    keys = jax.random.split(jax.random.PRNGKey(seed), team.shape[0])
    obs, own, actions, live = jax.jit(jax.vmap(episode))(keys, jnp.asarray(team))
    return PartnerSteps(
        obs=np.asarray(obs, np.float32),
        own_obs=np.asarray(own, np.float32),
        actions=np.asarray(actions, np.int64),
        team=team,
        live=np.asarray(live, bool),
        episode=np.tile(np.arange(episodes_per_team), m),
    )


def max_probability(
    member: Member, obs: np.ndarray, num_actions: int, samples: int = 64, seed: int = 0
) -> np.ndarray:
    """max_a pi(a | o) [B] of ``member`` at each observation ``obs`` [B, D]: exact from its
    declared probabilities, else estimated by sampling (split halves, see the module doc)."""
    x = jnp.asarray(obs)
    if member.probs is not None:
        probs_fn = member.probs
        return np.asarray(jax.jit(jax.vmap(lambda o: jnp.max(probs_fn(o))))(x))
    if samples < 2:
        raise ValueError(f"samples must be >= 2 (two halves), got {samples}")
    act = member.act

    def one(key: jax.Array, o: jax.Array) -> jax.Array:
        draws = jax.vmap(lambda k: act(k, o))(jax.random.split(key, samples))
        half = samples // 2
        best = jnp.argmax(jnp.bincount(draws[:half], length=num_actions))
        return jnp.mean(draws[half:] == best)

    keys = jax.random.split(jax.random.PRNGKey(seed), x.shape[0])
    return np.asarray(jax.jit(jax.vmap(one))(keys, x))


def action_ceiling(
    population: Population,
    steps: PartnerSteps,
    num_actions: int,
    samples: int = 64,
    seed: int = 0,
) -> dict[str, Any]:
    """{"ceiling": E[max_a pi(a|o)] over the live (episode, step, slot) triples, "members":
    {name: its mean over the steps it plays}, "sampled": [members estimated by sampling]}.

    Every team has the same number of episodes, so the pooled mean weighs teams equally."""
    num_slots = steps.obs.shape[2]
    if num_slots != population.num_others:
        raise ValueError(
            f"steps have {num_slots} partner slots; population {population.name!r} has "
            f"{population.num_others}"
        )
    member_of = population.table[steps.team]  # [E, N]
    values = np.zeros(steps.actions.shape, np.float64)  # [E, T, N]
    members: dict[str, float] = {}
    sampled: list[str] = []
    for idx in np.unique(member_of):
        member = population.members[int(idx)]
        plays = np.broadcast_to((member_of == idx)[:, None, :], values.shape)
        where = plays & steps.live[..., None]
        got = max_probability(member, steps.obs[where], num_actions, samples, seed + int(idx))
        values[where] = got
        members[member.name] = float(got.mean())
        if member.probs is None:
            sampled.append(member.name)
    mask = np.broadcast_to(steps.live[..., None], values.shape)
    return {"ceiling": float(values[mask].mean()), "members": members, "sampled": sampled}


def own_window(own: np.ndarray, k: int) -> np.ndarray:
    """The controlled agent's last ``k`` observations as features: [E, T, D] -> [E, T, k*D],
    o_t and the k-1 changes o_{t-j+1} - o_{t-j} between them (a change reaching before the
    episode's first observation is zero). Changes rather than the observations themselves,
    which hold the same information, because the MLP learns them far faster."""
    feats, prev = [own], own
    for _ in range(1, k):
        before = np.concatenate([prev[:, :1], prev[:, :-1]], 1)
        feats.append(prev - before)
        prev = before
    return np.concatenate(feats, -1)


def memoryless_accuracy(
    steps: PartnerSteps, num_actions: int, cfg: LevelsConfig | None = None, view: str = "partner"
) -> dict[str, Any]:
    """{"accuracy": held-out accuracy of an MLP on (observation, slot one-hot) -> partner
    action pooled over all teams, "by_step": the same per timestep of the episode (None where
    no test episode runs), "majority": each slot's most frequent training action scored on the
    test samples}; every 4th episode of each team is test. ``view``: ``"partner"`` reads the
    partner's own observation; ``"own"`` the controlled agent's current observation (what an
    agent model has at one step, without its history: the level it must beat, and, by step,
    the level its accuracy within the episode is read against: early steps are easier);
    ``"own2"`` its current observation and the change since the previous one (none at the
    first step; the change rather than the previous observation itself, which holds the same
    information, because the MLP learns it far faster): the partners' velocities, which their
    own observations hold and the agent's one does not, are then readable, so a model above
    ``"own"`` but not above ``"own2"`` may have learned the state and nothing of whom it plays
    with. ``"ownK"`` (K >= 2): its last K observations (:func:`own_window`), what a model with
    a K-step window is given."""
    cfg = cfg or LevelsConfig()
    e, t, n, _ = steps.obs.shape
    slot = np.broadcast_to(np.eye(n, dtype=np.float32), (e, t, n, n))
    if view == "partner":
        seen = steps.obs
    elif view == "own" or re.fullmatch(r"own([2-9]|[1-9]\d+)", view):
        own = own_window(steps.own_obs, 1 if view == "own" else int(view[3:]))
        seen = np.broadcast_to(own[:, :, None, :], (e, t, n, own.shape[-1]))
    else:
        raise ValueError(
            f"unknown view {view!r}; valid choices: partner, own, own2 (or ownK, the last K "
            "observations, K >= 2)"
        )
    x = np.concatenate([seen, slot], -1)
    test = np.broadcast_to((steps.episode % 4 == 0)[:, None, None], (e, t, n))
    live = np.broadcast_to(steps.live[..., None], (e, t, n))
    slots = np.broadcast_to(np.arange(n), (e, t, n))
    times = np.broadcast_to(np.arange(t)[None, :, None], (e, t, n))
    x, y, test, slots, times = x[live], steps.actions[live], test[live], slots[live], times[live]
    if test.all() or not test.any():
        raise ValueError("memoryless_accuracy needs at least 2 episodes per team (train and test)")
    hits = 0
    for j in range(n):
        train_j = y[(slots == j) & ~test]
        top = np.bincount(train_j, minlength=num_actions).argmax()
        hits += int(np.sum(y[(slots == j) & test] == top))
    mlp = ClassifierConfig(hidden=cfg.hidden, train_steps=cfg.train_steps, lr=cfg.lr, seed=cfg.seed)
    right = fit_hits(x, y, num_actions, mlp, test)
    at = times[test]
    by_step = [float(right[at == i].mean()) if np.any(at == i) else None for i in range(t)]
    return {
        "accuracy": float(np.mean(right)),
        "by_step": by_step,
        "majority": hits / int(test.sum()),
    }


def action_levels(
    env: ControlledEnv, cfg: LevelsConfig | None = None, controlled: PolicyFn | None = None
) -> dict[str, Any]:
    """The ceiling and the memoryless levels of ``env``'s population (module docstring):
    {"ceiling", "members", "sampled", "memoryless" (from the partner's own observation),
    "memoryless_own" (from the controlled agent's current observation), "memoryless_own_by_step"
    (the same per timestep), "memoryless_own2" and "memoryless_own2_by_step" (from its
    current and previous ones), "majority", "steps"}."""
    cfg = cfg or LevelsConfig()
    episodes = cfg.episodes(env.spec.episode_len)
    steps = collect_partner_steps(env, episodes, cfg.seed, controlled)
    num_actions = env.spec.other_num_actions
    ceiling = action_ceiling(env.population, steps, num_actions, cfg.samples, cfg.seed)
    memoryless = memoryless_accuracy(steps, num_actions, cfg)
    own = memoryless_accuracy(steps, num_actions, cfg, view="own")
    own2 = memoryless_accuracy(steps, num_actions, cfg, view="own2")
    window = memoryless_accuracy(steps, num_actions, cfg, view=f"own{cfg.window}")
    return {
        **ceiling,
        "memoryless": memoryless["accuracy"],
        "memoryless_own": own["accuracy"],
        "memoryless_own_by_step": own["by_step"],
        "memoryless_own2": own2["accuracy"],
        "memoryless_own2_by_step": own2["by_step"],
        "memoryless_window": window["accuracy"],
        "memoryless_window_by_step": window["by_step"],
        "majority": memoryless["majority"],
        "steps": int(steps.live.sum()) * steps.obs.shape[2],
        "episodes_per_team": episodes,
    }


def _rounded(by_step: list[float | None]) -> list[float | None]:
    return [None if v is None else round(v, 4) for v in by_step]


def diversity_record(
    env: str,
    heldout: bool,
    window: int,
    acc: dict[str, Any],
    levels: dict[str, Any],
    lv_cfg: LevelsConfig,
    root: Path | None = None,
) -> dict[str, Any]:
    """What ``transam partners diversity ENV --record`` stores in the shipped manifest, or in
    the manifest of the population directory ``root`` (the README and the report quote it):
    the classifier accuracies of :func:`partner_id_accuracy` and the levels of
    :func:`action_levels`, rounded."""
    split = "heldout" if heldout else "default"
    command = f"transam partners diversity {env}" + (" --heldout" if heldout else "")
    return {
        "partner_id_accuracy_others": round(acc["others"], 3),
        "partner_id_accuracy_local": round(acc["local"], 3),
        "chance": round(acc["chance"], 4),
        "teams": acc["teams"],
        "window": window,
        "episodes_per_team": ClassifierConfig().episodes_per_team,
        "action_ceiling": round(levels["ceiling"], 4),
        "memoryless_accuracy": round(levels["memoryless"], 4),
        "memoryless_own_accuracy": round(levels["memoryless_own"], 4),
        "memoryless_own_accuracy_by_step": _rounded(levels["memoryless_own_by_step"]),
        "memoryless_own2_accuracy": round(levels["memoryless_own2"], 4),
        "memoryless_own2_accuracy_by_step": _rounded(levels["memoryless_own2_by_step"]),
        "memoryless_window_accuracy": round(levels["memoryless_window"], 4),
        "memoryless_window_accuracy_by_step": _rounded(levels["memoryless_window_by_step"]),
        "majority_rate": round(levels["majority"], 4),
        "member_ceilings": {n: round(v, 4) for n, v in levels["members"].items()},
        "ceiling_sampled": levels["sampled"],
        "levels_settings": {**asdict(lv_cfg), "episodes_per_team": levels["episodes_per_team"]},
        "measured_by": command + (f" --population {root}" if root else ""),
        "population_digest": learned.directory_digest(root) if root else learned.digest(env, split),
    }


# ---------------------------------------------------------------- the command's measurement

CROSS_PLAY_ENVS = ("lbf", "overcooked")
"""The games whose learned members can fill the controlled slot (:func:`cross_play`)."""


@dataclass(frozen=True)
class Diversity:
    """What ``transam partners diversity`` measures of one population (:func:`measure`)."""

    members: list[str]
    """the learned members of the cross-play matrix, in its order (empty: no matrix)"""
    cross_play: np.ndarray | None
    """:func:`cross_play` of ``members`` (LBF and Overcooked's shipped splits only)"""
    accuracy: dict[str, Any]
    """:func:`partner_id_accuracy`"""
    levels: dict[str, Any]
    """:func:`action_levels`"""
    levels_config: LevelsConfig
    window: int


def levels_config(
    episodes_per_team: int | None = None, train_steps: int | None = None
) -> LevelsConfig:
    """:class:`LevelsConfig` with the given settings (None: its default)."""
    given = {"episodes_per_team": episodes_per_team, "train_steps": train_steps}
    return dataclasses.replace(LevelsConfig(), **{k: v for k, v in given.items() if v is not None})


def measure(
    env: ControlledEnv,
    shipped: str | None,
    window: int = 10,
    levels: LevelsConfig | None = None,
    controlled: PolicyFn | None = None,
) -> Diversity:
    """Measure the population ``env`` plays: the partner-index classifier over ``window``
    steps, the action levels (with ``controlled`` as the controlled agent's policy; None:
    uniformly random) and, where ``env`` plays ``shipped``, a shipped learned split ('default'
    or 'heldout'; None for any other population) of a game in :data:`CROSS_PLAY_ENVS`, its
    cross-play matrix."""
    name = env.spec.name
    members: list[str] = []
    matrix = None
    if shipped is not None and name in CROSS_PLAY_ENVS:
        found = learned.learned_members(name, shipped)
        members = list(found)
        matrix = cross_play(name, [found[n] for n in members])
    levels = levels or LevelsConfig()
    return Diversity(
        members=members,
        cross_play=matrix,
        accuracy=partner_id_accuracy(env, ClassifierConfig(window=window)),
        levels=action_levels(env, levels, controlled),
        levels_config=levels,
        window=window,
    )


def record(env: str, heldout: bool, found: Diversity, root: Path | None = None) -> Path:
    """Store ``found`` (of the shipped ``env`` split, or of the population directory ``root``)
    in its manifest, as :func:`diversity_record`; returns the manifest's path."""
    entry = diversity_record(
        env, heldout, found.window, found.accuracy, found.levels, found.levels_config, root
    )
    learned.record_diversity(env, "heldout" if heldout else "default", entry, root)
    return (root or learned.data_dir(env)) / "manifest.json"
