"""Spread: parity with mpe2 simple_spread_v3, the rewards, heuristics, and the JAX contract."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from transam import make_env as make
from transam.envs import EnvError
from transam.envs.spread import CONTROLLED, Config, SpreadGame
from transam.partners.moves import DOWN, LEFT, RIGHT, UP
from transam.partners.spread import (
    AUTHORS_HEURISTICS,
    HEURISTICS,
    heuristic_population,
    landmark_agent,
)

EPISODES = 20
REFERENCE = Path(__file__).resolve().parents[2] / "shared" / "reference" / "authors-spread"
T = 25


def _mpe2_episodes() -> dict[str, np.ndarray]:
    """Random joint actions through mpe2's parallel env; its obs, rewards and world states."""
    from mpe2 import simple_spread_v3

    rng = np.random.default_rng(0)
    env = simple_spread_v3.parallel_env(
        N=3, local_ratio=0.5, max_cycles=T, continuous_actions=False
    )
    names = env.possible_agents
    out: dict[str, list[np.ndarray]] = {"obs": [], "rew": [], "pos": [], "vel": [], "act": []}
    for ep in range(EPISODES):
        obs, _ = env.reset(seed=ep)
        world = env.unwrapped.world
        entities = world.agents + world.landmarks
        acts = rng.integers(0, 5, size=(T, 3))
        ep_obs = [np.stack([obs[a] for a in names])]
        ep_rew, ep_pos, ep_vel = [], [], []
        ep_pos.append(np.stack([e.state.p_pos for e in entities]))
        ep_vel.append(np.stack([e.state.p_vel for e in entities]))
        for t in range(T):
            obs, rew, _, trunc, _ = env.step({a: int(acts[t, i]) for i, a in enumerate(names)})
            ep_obs.append(np.stack([obs[a] for a in names]))
            ep_rew.append(np.array([rew[a] for a in names]))
            ep_pos.append(np.stack([e.state.p_pos for e in entities]))
            ep_vel.append(np.stack([e.state.p_vel for e in entities]))
        assert all(trunc.values()) and not env.agents  # mpe2 ends after exactly T steps
        for k, v in zip(out, (ep_obs, ep_rew, ep_pos, ep_vel, [acts]), strict=True):
            out[k].append(np.stack(v) if k != "act" else v[0])
    return {k: np.stack(v) for k, v in out.items()}


def _mpe_formula(pos: np.ndarray, self_collision: bool) -> np.ndarray:
    """Original MPE spread reward of agent 2 from world positions [..., 6, 2] (numpy)."""
    agents, landmarks = pos[..., :3, :], pos[..., 3:, :]
    d = np.linalg.norm(agents[..., None, :, :] - landmarks[..., :, None, :], axis=-1)
    cover = -d.min(axis=-1).sum(axis=-1)
    near = np.linalg.norm(agents - agents[..., 2:3, :], axis=-1) < 0.3
    if not self_collision:
        near[..., 2] = False
    return cover - near.sum(axis=-1)


def test_parity_with_mpe2() -> None:
    ref = _mpe2_episodes()
    mpe2 = Config(dynamics="mpe2")
    game = SpreadGame(mpe2)
    rewarders = {
        "mpe": SpreadGame(mpe2),
        "noself": SpreadGame(Config(dynamics="mpe2", self_collision=False)),
        "pettingzoo": SpreadGame(Config(dynamics="mpe2", reward="pettingzoo")),
    }

    def episode(pos0: jax.Array, vel0: jax.Array, acts: jax.Array):
        state = game.reset(jax.random.key(0)).replace(p_pos=pos0, p_vel=vel0)

        def body(state, a):
            state, reward, terminal = game.transition(jax.random.key(1), state, a[2], a[:2])
            obs, other = game.observe(state)
            rewards = {k: g.reward(state) for k, g in rewarders.items()}
            return state, (jnp.concatenate([other, obs[None]]), reward, terminal, rewards)

        obs, other = game.observe(state)
        _, (seq, reward, terminal, rewards) = jax.lax.scan(body, state, acts)
        return (
            jnp.concatenate([jnp.concatenate([other, obs[None]])[None], seq]),
            reward,
            terminal,
            rewards,
        )

    f = jax.jit(jax.vmap(episode))
    obs, reward, terminal, rewards = f(
        jnp.asarray(ref["pos"][:, 0], jnp.float32),
        jnp.asarray(ref["vel"][:, 0], jnp.float32),
        jnp.asarray(ref["act"], jnp.int32),
    )
    assert obs.shape == ref["obs"].shape == (EPISODES, T + 1, 3, 18)
    np.testing.assert_allclose(np.asarray(obs), ref["obs"], atol=1e-4)
    np.testing.assert_allclose(np.asarray(rewards["pettingzoo"]), ref["rew"][..., 2], atol=1e-4)
    np.testing.assert_allclose(np.asarray(reward), np.asarray(rewards["mpe"]))
    np.testing.assert_allclose(
        np.asarray(rewards["mpe"]), _mpe_formula(ref["pos"][:, 1:], True), atol=1e-4
    )
    np.testing.assert_allclose(
        np.asarray(rewards["noself"]), _mpe_formula(ref["pos"][:, 1:], False), atol=1e-4
    )
    # The self term is a constant -1, and the episodes did include partner collisions.
    np.testing.assert_allclose(np.asarray(rewards["noself"] - rewards["mpe"]), 1.0, atol=1e-5)
    assert not bool(terminal.any())
    # Sanity: the episodes moved the agents and had some partner collisions.
    assert np.abs(ref["pos"][:, -1] - ref["pos"][:, 0]).max() > 0.3
    near = np.linalg.norm(ref["pos"][:, 1:, :2] - ref["pos"][:, 1:, 2:3], axis=-1) < 0.3
    assert near.any()


def _obs_with_landmarks(offsets: list[tuple[float, float]]) -> jax.Array:
    obs = np.zeros(18, np.float32)
    obs[2:4] = (0.3, -0.2)
    obs[4:10] = np.asarray(offsets, np.float32).ravel()
    obs[10:14] = (0.1, 0.1, -0.1, 0.05)  # other agents: must not matter
    return jnp.asarray(obs)


def test_heuristics_head_for_their_landmark() -> None:
    # landmark 0 far +x, landmark 1 near -y, landmark 2 mid -x
    obs = _obs_with_landmarks([(0.9, 0.1), (0.05, -0.2), (-0.5, 0.3)])
    key = jax.random.key(0)
    act = {n: int(f(key, obs)) for n, f in HEURISTICS.items()}
    assert act == {
        "first": RIGHT,
        "second": DOWN,
        "third": LEFT,
        "closest": DOWN,
        "farthest": RIGHT,
    }
    obs = _obs_with_landmarks([(-0.1, -0.8), (0.2, 0.6), (0.0, 0.01)])
    act = {n: int(f(key, obs)) for n, f in HEURISTICS.items()}
    assert act == {"first": DOWN, "second": UP, "third": UP, "closest": UP, "farthest": DOWN}
    # Coasting fast toward a near landmark: brake (steer at offset - LEAD * velocity).
    obs = (
        _obs_with_landmarks([(0.1, 0.0), (0.0, 0.5), (-1.0, 0.0)])
        .at[0:2]
        .set(jnp.array([2.0, 0.0]))
    )
    assert int(HEURISTICS["first"](key, obs)) == LEFT
    assert int(HEURISTICS["second"](key, obs)) == UP  # the 0.5 y gap beats the 0.4 x drift
    assert int(HEURISTICS["third"](key, obs)) == LEFT


ENVS = 1024
STEPS = 30  # crosses the episode boundary at step 25


@pytest.fixture(scope="module")
def rollout():
    """Jitted once: ENVS envs (partner per env given), random controlled actions, STEPS steps."""
    env = make("spread", partners="heuristic")

    def one(key, partner):
        k0, k1 = jax.random.split(key)
        state, obs = env.reset(k0, partner)

        def body(state, k):
            ka, ks = jax.random.split(k)
            a = jax.random.randint(ka, (), 0, env.spec.num_actions, dtype=jnp.int32)
            state, ts = env.step(ks, state, a)
            return state, (ts.obs, ts.reward, ts.done, ts.truncated, ts.record)

        _, out = jax.lax.scan(body, state, jax.random.split(k1, STEPS))
        return obs, out

    f = jax.jit(lambda key, partners: jax.vmap(one)(jax.random.split(key, ENVS), partners))
    return env, f


def test_heuristic_partners_reach_their_landmarks(rollout) -> None:
    env, f = rollout
    team = env.population.team_names.index("first+second")
    _, (_, _, _, _, record) = f(jax.random.key(3), jnp.full(ENVS, team, jnp.int32))
    offsets = np.asarray(record.other_obs[:, :, :, 4:10]).reshape(ENVS, STEPS, 2, 3, 2)
    # slot 0 (agent 0) heads for landmark 0, slot 1 (agent 1) for landmark 1
    start = np.linalg.norm(offsets[:, 0, [0, 1], [0, 1]], axis=-1)
    end = np.linalg.norm(offsets[:, T - 1, [0, 1], [0, 1]], axis=-1)
    assert end.mean() < 0.15 < 0.5 < start.mean()
    assert np.median(end) < 0.1
    # and not toward the landmark of the other slot
    assert np.linalg.norm(offsets[:, T - 1, [0, 1], [1, 0]], axis=-1).mean() > 0.5


def test_jit_vmap_1024_envs_and_determinism(rollout) -> None:
    env, f = rollout
    assert env.spec.obs_dim == 18 and env.spec.num_others == 2 and env.spec.episode_len == T
    assert env.num_partners == 13
    partners0 = jax.random.randint(jax.random.key(0), (ENVS,), 0, 13, dtype=jnp.int32)
    obs0, (obs, reward, done, trunc, record) = f(jax.random.key(7), partners0)
    assert obs0.shape == (ENVS, 18) and obs0.dtype == jnp.float32
    assert obs.shape == (ENVS, STEPS, 18) and obs.dtype == jnp.float32
    assert record.other_obs.shape == (ENVS, STEPS, 2, 18)
    assert record.other_actions.shape == (ENVS, STEPS, 2)
    assert record.other_actions.dtype == jnp.int32
    assert reward.dtype == jnp.float32 and bool(jnp.isfinite(reward).all())
    expected_done = np.zeros(STEPS, bool)
    expected_done[T - 1] = True
    assert (np.asarray(done) == expected_done).all() and (np.asarray(trunc) == done).all()
    assert (np.asarray(record.t[0]) == np.arange(STEPS) % T).all()
    # The controlled agent is agent 2: its self position is what the partners see of it.
    own_pos = np.asarray(obs0[:, 2:4])
    seen = np.asarray(record.other_obs[:, 0])  # o^{-1}_0, aligned with obs0
    for slot in range(2):
        np.testing.assert_allclose(own_pos - seen[:, slot, 2:4], seen[:, slot, 12:14], atol=1e-6)
    # the partner is fixed within an episode and redrawn (over all teams) after it
    partners = np.asarray(record.partner)
    assert (partners[:, :T] == np.asarray(partners0)[:, None]).all()
    assert set(np.unique(partners[:, T])) == set(range(13))
    # random play on the original MPE reward: about -2.6 per step (self term -1 included)
    assert -3.2 < float(reward[:, :T].sum(1).mean()) / T < -2.0
    # same key, same trajectory; another key, another one
    again = f(jax.random.key(7), partners0)
    other = f(jax.random.key(8), partners0)
    np.testing.assert_array_equal(np.asarray(again[1][0]), np.asarray(obs))
    np.testing.assert_array_equal(np.asarray(again[1][1]), np.asarray(reward))
    np.testing.assert_array_equal(np.asarray(again[1][4].other_actions), record.other_actions)
    assert not np.array_equal(np.asarray(other[1][0]), np.asarray(obs))


def test_config_and_population() -> None:
    with pytest.raises(EnvError, match="reward"):
        Config(reward="shared")  # type: ignore[arg-type]
    with pytest.raises(EnvError, match="local_ratio"):
        Config(local_ratio=1.5)
    with pytest.raises(EnvError, match="must be a Config"):
        make("spread", config=object())
    pop = heuristic_population(Config())
    assert len(set(pop.team_names)) == pop.size == 13
    assert {s for t in pop.teams for s in t.slots} == set(HEURISTICS)
    assert CONTROLLED == 2


def test_authors_dynamics_move_with_the_new_velocity() -> None:
    """Constructed state: one agent at rest pushed +x for one step. The fork (authors) moves it
    by dt * v_new = 0.1 * (0.1 * 5) = 0.05 at once; mpe2 moves with the old velocity (0) first,
    so it has not moved after one step and moves 0.05 * 0.75 + 0.05 after two."""
    pos = jnp.asarray([[-0.9, -0.9], [0.9, 0.9], [0.0, 0.0], [0.5, 0.5], [-0.5, 0.5], [0.5, -0.5]])
    push = jnp.asarray(RIGHT, jnp.int32)
    still = jnp.zeros(2, jnp.int32)
    moved = {}
    for dynamics in ("authors", "mpe2"):
        game = SpreadGame(Config(dynamics=dynamics))
        state = game.reset(jax.random.key(0)).replace(p_pos=pos, p_vel=jnp.zeros_like(pos))
        xs = []
        for _ in range(2):
            state, _, _ = game.transition(jax.random.key(1), state, push, still)
            xs.append(float(state.p_pos[CONTROLLED, 0]))
        moved[dynamics] = xs
    np.testing.assert_allclose(moved["authors"], [0.05, 0.05 + 0.1 * (0.75 * 0.5 + 0.5)], atol=1e-6)
    np.testing.assert_allclose(moved["mpe2"], [0.0, 0.05], atol=1e-6)


def test_authors_landmarks_spawn_in_the_smaller_square() -> None:
    """Landmarks in 0.8 * U(-1, 1)^2 (authors) vs U(-1, 1)^2 (mpe2); agents in U(-1, 1)^2 both."""
    keys = jax.random.split(jax.random.key(0), 4096)
    for dynamics, bound in (("authors", 0.8), ("mpe2", 1.0)):
        game = SpreadGame(Config(dynamics=dynamics))
        pos = np.asarray(jax.vmap(game.reset)(keys).p_pos)
        landmarks, agents = np.abs(pos[:, 3:]), np.abs(pos[:, :3])
        assert landmarks.max() <= bound and landmarks.max() > bound - 0.01
        assert agents.max() <= 1.0 and agents.max() > 0.99
    with pytest.raises(EnvError, match="dynamics must be one of authors, mpe2; got 'fork'"):
        Config(dynamics="fork")  # type: ignore[arg-type]


def test_authors_heuristics_on_constructed_observations() -> None:
    """One-axis steering without lead: ties go to x, a zero component moves +, never no-op;
    farthest/closest by squared distance with the lowest index on ties."""
    key = jax.random.key(0)
    obs = _obs_with_landmarks([(0.3, 0.3), (0.0, -0.5), (-0.1, 0.0)])
    obs = obs.at[0:2].set(jnp.asarray([5.0, -5.0]))  # velocity: the authors' rules ignore it
    acts = {n: int(f(key, obs)) for n, f in AUTHORS_HEURISTICS.items()}
    assert acts == {
        "after_first_landmark": RIGHT,  # |dx| == |dy|: x
        "after_second_landmark": DOWN,
        "after_third_landmark": LEFT,
        "after_farthest_landmark": DOWN,  # 0.25 > 0.18 > 0.01
        "after_closest_landmark": LEFT,
    }
    zero = _obs_with_landmarks([(0.0, 0.0), (0.2, 0.0), (0.0, 0.2)])
    assert int(AUTHORS_HEURISTICS["after_first_landmark"](key, zero)) == RIGHT  # 0: + along x
    tie = _obs_with_landmarks([(0.0, -0.4), (0.4, 0.0), (0.1, 0.1)])
    assert int(AUTHORS_HEURISTICS["after_farthest_landmark"](key, tie)) == DOWN  # first of ties


def test_authors_heuristics_match_their_code() -> None:
    """Every row of the authors' reference observations, against their loader's heuristics
    (fork numbering 1 +x, 2 -x, 3 +y, 4 -y mapped to ours)."""
    path = REFERENCE / "reference_io.npz"
    if not path.exists():
        pytest.skip(f"reference folder {REFERENCE} absent (the authors' Spread fixtures)")
    ref = np.load(path)
    fork_to_ours = np.asarray([0, RIGHT, LEFT, UP, DOWN])
    obs = jnp.asarray(ref["obs"], jnp.float32)
    for name, fn in AUTHORS_HEURISTICS.items():
        ours = np.asarray(jax.vmap(fn, in_axes=(None, 0))(jax.random.key(0), obs))
        np.testing.assert_array_equal(ours, fork_to_ours[ref[f"heur_{name}_action"]], name)


def test_landmark_agent_heads_for_the_uncovered_landmark() -> None:
    obs = _obs_with_landmarks([(0.5, 0.0), (-0.5, 0.1), (0.0, 0.6)])
    obs = obs.at[10:14].set(jnp.asarray([0.5, 0.05, 0.0, 0.55]))  # partners on landmarks 0, 2
    assert int(landmark_agent(jax.random.key(0), obs)) == LEFT  # landmark 1 is uncovered
