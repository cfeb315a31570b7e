"""Tag (LIAM predator-prey): rewards, view box, walls, fork physics, heuristics, batching."""

from __future__ import annotations

from collections import Counter
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from transam import make_env as make
from transam.envs.population import Member
from transam.envs.tag import (
    AGENT_SIZE,
    LANDMARK_SIZE,
    Config,
    TagGame,
    boundary_penalty,
    capture_reward,
    strip_boundary_penalty,
)
from transam.partners.moves import DOWN, LEFT, NOOP, RIGHT, UP
from transam.partners.tag import (
    LEARNED_SLOTS,
    after_agent_close,
    after_agent_far,
    after_pred,
    after_prey,
    heuristic_population,
    liam_population,
)

GAME = TagGame(Config())
NO_PENALTY = TagGame(Config(boundary_penalty=False))
HARD = TagGame(Config(hard_walls=True))
STEP = jax.jit(GAME.transition)
OBSERVE = jax.jit(GAME.observe)
KEY = jax.random.PRNGKey(0)
FAR = [[-0.8, -0.8], [-0.8, 0.8], [0.8, -0.8]]  # predators well away from the origin


def make_state(prey, preds=FAR, landmarks=((0.6, 0.6), (-0.6, 0.6)), game=GAME):
    pos = jnp.asarray([*preds, prey, *landmarks], jnp.float32)
    return game.reset(KEY).replace(p_pos=pos)


# --- rewards -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("preds", "expected"),
    [
        (FAR, 0.0),
        ([[0.2, 0.0], *FAR[1:]], 1.0),  # one predator at 0.2 < 0.28
        ([[0.2, 0.0], [0.0, -0.27], FAR[2]], -1.0),  # two within 0.28
        ([[0.2, 0.0], [0.0, -0.27], [-0.15, 0.15]], -1.0),  # three
        ([[0.29, 0.0], *FAR[1:]], 0.0),  # just outside the capture distance
    ],
)
def test_capture_reward(preds, expected):
    state = make_state([0.0, 0.0], preds)
    assert float(capture_reward(state)) == expected
    # transition charges the reward of the state AFTER the step: with no-ops and no contact
    # (all distances > 0.14) nobody moves, so it is the same number.
    nxt, r, terminal = STEP(KEY, state, jnp.int32(NOOP), jnp.zeros(3, jnp.int32))
    np.testing.assert_allclose(nxt.p_pos, state.p_pos, atol=1e-9)
    assert float(r) == expected and not bool(terminal)


@pytest.mark.parametrize("prey", [[0.995, 0.0], [0.0, -0.995], [-1.2, 1.2]])
def test_boundary_penalty(prey):
    state = make_state(prey, landmarks=((0.0, 0.0), (-0.6, 0.6)))
    assert float(boundary_penalty(state)) == -10.0
    assert float(boundary_penalty(make_state([0.985, -0.985]))) == 0.0
    nop = jnp.zeros(3, jnp.int32)
    _, r_on, _ = STEP(KEY, state, jnp.int32(NOOP), nop)
    assert float(r_on) == -10.0 and float(NO_PENALTY.reward(state)) == 0.0
    # a capture on top of the penalty, and the evaluator's stripping rule
    caught = make_state(prey, [[prey[0] - 0.2, prey[1]], *FAR[1:]])
    _, r, _ = STEP(KEY, caught, jnp.int32(NOOP), nop)
    assert float(r) == -9.0
    rewards = jnp.array([-11.0, -10.0, -9.0, -1.0, 0.0, 1.0])
    np.testing.assert_array_equal(strip_boundary_penalty(rewards), [-1, 0, 1, -1, 0, 1])


# --- observations ------------------------------------------------------------------------------


def test_prey_view_box():
    prey = [0.0, 0.0]
    landmarks = ((0.5, -0.5), (0.3, 0.51))  # on the box edge (kept); |dy| > 0.5 (hidden)
    preds = [[-0.4, 0.2], [0.7, 0.0], [0.1, -0.6]]  # inside; |dx| > 0.5; |dy| > 0.5
    state = make_state(prey, preds, landmarks)
    state = state.replace(p_vel=jax.random.uniform(KEY, (6, 2)).at[4:].set(0.0))
    obs, other = OBSERVE(state)
    assert obs.shape == (14,) and obs.dtype == jnp.float32
    expected = [*state.p_vel[3], 0, 0, 0.5, -0.5, -5, -5, -0.4, 0.2, -5, -5, -5, -5]
    np.testing.assert_allclose(obs, expected, atol=1e-7)
    # predators see everything: [vel, pos, lm rel x2, other preds (index order), prey rel, vel]
    assert other.shape == (3, 16)
    pos, vel = np.asarray(state.p_pos), np.asarray(state.p_vel)
    for i in range(3):
        others = [j for j in range(3) if j != i]
        want = np.concatenate(
            [vel[i], pos[i], *(pos[4:] - pos[i]), *(pos[others] - pos[i]), pos[3] - pos[i], vel[3]]
        )
        np.testing.assert_allclose(other[i], want, atol=1e-6)
    # a shifted prey: positions are relative to it, and the same box rule applies
    state = make_state([0.2, 0.1], [[-0.4, 0.2], [0.6, 0.0], [0.1, -0.6]], landmarks)
    obs, _ = OBSERVE(state)
    np.testing.assert_allclose(obs[2:4], [0.2, 0.1])
    np.testing.assert_array_equal(obs[4:6], [-5, -5])  # landmark 0 now at dy = -0.6
    np.testing.assert_allclose(obs[6:8], [0.1, 0.41], atol=1e-6)
    np.testing.assert_array_equal(obs[8:10], [-5, -5])  # predator 0 at dx = -0.6
    np.testing.assert_allclose(obs[10:12], [0.4, -0.1], atol=1e-6)
    np.testing.assert_array_equal(obs[12:14], [-5, -5])  # predator 2 at dy = -0.7


# --- walls -------------------------------------------------------------------------------------


@partial(jax.jit, static_argnums=(0, 1))
def _push(game, steps, state, prey_action, pred_action):
    def body(s, key):
        acts = jnp.full(3, pred_action, jnp.int32)
        s, _, _ = game.transition(key, s, jnp.int32(prey_action), acts)
        return s, s.p_pos

    return jax.lax.scan(body, state, jax.random.split(KEY, steps))[1]


def push(game, steps, prey_action, pred_action, prey_start=(1.0, 0.0)):
    """Positions [steps, 6, 2] while the prey and all predators repeat one action."""
    preds = [[0.0, 0.0], [0.0, 0.3], [1.0, -0.6]]
    state = make_state(list(prey_start), preds, landmarks=((-0.6, 0.6), (-0.6, -0.6)), game=game)
    return _push(game, steps, state, prey_action, pred_action)


def test_soft_walls_leak_and_hard_walls_hold():
    soft = push(GAME, 15, RIGHT, RIGHT)
    assert float(soft[-1, 3, 0]) > 1.3  # the prey leaves through the x = 1.3 wall
    assert float(soft[-1, 2, 0]) > 1.3  # and so does a predator
    hard = push(HARD, 15, RIGHT, RIGHT)
    limit = 1.3 - 0.05 - AGENT_SIZE
    assert float(jnp.max(hard[:, :4, 0])) <= limit + 1e-6
    assert float(hard[-1, 3, 0]) > limit - 0.01  # pressed against the wall
    # corners are covered too, and the agent can leave the wall again
    corner = push(HARD, 15, UP, UP, prey_start=(1.1, 1.1))
    assert float(jnp.max(corner[:, 3, 1])) <= limit + 1e-6
    back = push(HARD, 15, LEFT, NOOP)
    assert float(back[4, 3, 0]) < 1.0
    # predators 0 and 1 share x = 0 and are pressed onto one point: no NaN
    assert bool(jnp.all(jnp.isfinite(corner)))
    np.testing.assert_allclose(corner[-1, 0], corner[-1, 1])


# --- physics against a numpy re-implementation of the fork ----------------------------------------

SIZE = np.array([AGENT_SIZE] * 4 + [LANDMARK_SIZE] * 2)
ACCEL = np.array([3.0, 3.0, 3.0, 4.0])
MAX_SPEED = np.array([1.0, 1.0, 1.0, 1.3])
DIRS = np.array([[0, 0], [-1, 0], [1, 0], [0, -1], [0, 1]], float)  # by meaning
WALLS = [(1, -1.3), (1, 1.3), (0, -1.3), (0, 1.3)]  # (perpendicular axis, line)


def softplus_pen(dist, dist_min, k=1e-3):
    return np.logaddexp(0, -(dist - dist_min) / k) * k


def np_wall_force(p, size):
    total = np.zeros(2)
    for perp, line in WALLS:
        prll = 1 - perp
        if p[prll] < -1 - size or p[prll] > 1 + size:
            continue
        past = p[prll] + 1 if p[prll] < -1 else (p[prll] - 1 if p[prll] > 1 else 0.0)
        theta = np.arcsin(past / size)
        dist_min = np.cos(theta) * size + 0.05
        delta = p[perp] - line
        mag = 100 * delta / abs(delta) * softplus_pen(abs(delta), dist_min)
        total[perp] += np.cos(theta) * mag
        total[prll] += np.sin(theta) * abs(mag)
    return total


def np_fork_step(pos, vel, actions, walls=True):
    """One step of the shariq MPE fork as LIAM runs it (float64)."""
    pos, vel = pos.astype(np.float64).copy(), vel.astype(np.float64).copy()
    force = np.zeros_like(pos)
    force[:4] = (ACCEL**2)[:, None] * DIRS[actions]  # mass * accel * (accel * u)
    for a in range(6):
        for b in range(a + 1, 6):
            if a >= 4 and b >= 4:
                continue  # two landmarks: neither moves
            delta = pos[a] - pos[b]
            dist = np.linalg.norm(delta)
            f = 100 * delta / dist * softplus_pen(dist, SIZE[a] + SIZE[b])
            force[a] += f if a < 4 else 0
            force[b] -= f if b < 4 else 0
        if a < 4 and walls:
            force[a] += np_wall_force(pos[a], SIZE[a])
    for i in range(4):  # landmarks are immovable
        v = vel[i] * 0.75 + force[i] * 0.1
        speed = np.linalg.norm(v)
        if speed > MAX_SPEED[i]:
            v = v / speed * MAX_SPEED[i]
        vel[i] = v
        pos[i] = pos[i] + v * 0.1
    return pos, vel


def random_contact_state(rng):
    pos = np.concatenate([rng.uniform(-1.0, 1.0, (4, 2)), rng.uniform(-0.9, 0.9, (2, 2))])
    pos[1] = pos[0] + rng.uniform(0.09, 0.12) * np.array(
        [np.cos(t := rng.uniform(0, 7)), np.sin(t)]
    )
    pos[2] = pos[4] + rng.uniform(0.25, 0.28) * np.array(
        [np.cos(t := rng.uniform(0, 7)), np.sin(t)]
    )
    pos[3] = [rng.uniform(1.15, 1.32), rng.uniform(0.93, 1.07)] * rng.choice([-1, 1], 2)
    pos[3] = pos[3][::-1] if rng.random() < 0.5 else pos[3]
    vel = np.concatenate([rng.uniform(-1.2, 1.2, (4, 2)), np.zeros((2, 2))])
    return pos.astype(np.float32), vel.astype(np.float32), rng.integers(0, 5, 4)


def test_physics_matches_numpy_fork():
    rng = np.random.default_rng(0)
    cases = [random_contact_state(rng) for _ in range(64)]
    pos = jnp.asarray(np.stack([c[0] for c in cases]))
    vel = jnp.asarray(np.stack([c[1] for c in cases]))
    acts = jnp.asarray(np.stack([c[2] for c in cases]), jnp.int32)

    def rollout(p, v, a):  # three steps with the same joint action
        s = GAME.reset(KEY).replace(p_pos=p, p_vel=v)

        def body(s, _):
            s, _, _ = GAME.transition(KEY, s, a[3], a[:3])
            return s, (s.p_pos, s.p_vel)

        return jax.lax.scan(body, s, None, length=3)[1]

    got_pos, got_vel = jax.jit(jax.vmap(rollout))(pos, vel, acts)
    moved_by_walls = 0
    for n, (p, v, a) in enumerate(cases):
        for t in range(3):
            p_next, v_next = np_fork_step(p, v, a)
            np.testing.assert_allclose(got_pos[n, t], p_next, atol=2e-5, err_msg=f"case {n}")
            np.testing.assert_allclose(got_vel[n, t], v_next, atol=2e-4, err_msg=f"case {n}")
            if t == 0:
                moved_by_walls += not np.allclose(np_fork_step(p, v, a, walls=False)[1], v_next)
            p, v = p_next, v_next
    assert moved_by_walls >= 10  # the sample really exercises the wall force


# --- heuristics --------------------------------------------------------------------------------


def pred_obs(a=(0.5, 0.5), b=(-0.4, 0.3), prey=(0.3, -0.1)):
    obs = np.zeros(16, np.float32)
    obs[8:10], obs[10:12], obs[12:14] = a, b, prey
    return jnp.asarray(obs)


@pytest.mark.parametrize(
    ("policy", "obs", "expected"),
    [
        (after_prey, pred_obs(prey=(0.3, -0.1)), RIGHT),
        (after_prey, pred_obs(prey=(-0.3, 0.1)), LEFT),
        (after_prey, pred_obs(prey=(0.1, -0.3)), DOWN),
        (after_prey, pred_obs(prey=(-0.2, 0.2)), UP),  # tie -> y axis (strict >)
        (after_prey, pred_obs(prey=(0.2, -0.2)), DOWN),
        (after_agent_far, pred_obs(a=(0.1, -0.2), b=(0.05, 0.6), prey=(-0.7, 0.0)), LEFT),
        (after_agent_far, pred_obs(a=(0.1, -0.9), b=(0.05, 0.6), prey=(-0.7, 0.0)), DOWN),
        (after_agent_far, pred_obs(a=(0.1, 0.2), b=(0.8, 0.6), prey=(-0.7, 0.0)), RIGHT),
        (after_agent_far, pred_obs(a=(0.1, 0.2), b=(0.3, 0.95), prey=(-0.7, 0.0)), UP),
        (after_agent_close, pred_obs(a=(0.5, 0.5), b=(-0.1, 0.05), prey=(0.3, 0.0)), LEFT),
        (after_agent_close, pred_obs(a=(0.05, -0.1), b=(0.5, 0.2), prey=(0.3, 0.0)), DOWN),
        (after_agent_close, pred_obs(a=(0.5, 0.5), b=(0.4, 0.4), prey=(0.2, 0.2)), RIGHT),  # tie
        (after_agent_close, pred_obs(a=(0.5, 0.5), b=(0.4, 0.4), prey=(-0.1, 0.2)), UP),
    ],
)
def test_heuristic_moves(policy, obs, expected):
    assert int(policy(KEY, obs)) == expected


def test_after_pred_redraws_from_key():
    obs = pred_obs(a=(0.5, 0.1), b=(0.1, -0.5))  # A is +x, B is -y
    acts = np.asarray(jax.vmap(after_pred, in_axes=(0, None))(jax.random.split(KEY, 2000), obs))
    counts = Counter(acts.tolist())
    assert set(counts) == {RIGHT, DOWN}
    assert 900 < counts[RIGHT] < 1100
    assert int(after_pred(KEY, obs)) == int(after_pred(KEY, obs))


def test_population_follows_liam_table():
    pop = heuristic_population(Config())
    assert pop.size == 10 and pop.num_others == 3
    teams = [tuple(sorted(pop.members[m].name for m in row)) for row in pop.table]
    assert len(set(teams)) == 10  # distinguishable even as multisets
    assert pop.teams[2].slots == ("after_pred", "after_prey", "after_agent_far")  # no RL slot
    # a learned member takes its slot wherever LIAM's table uses it, and nowhere else
    spinner = Member("ippo_seed0", lambda key, obs: jnp.int32(NOOP), kind="ippo")
    swapped = liam_population({"rl_b1": spinner})
    assert [t.slots.count("ippo_seed0") for t in swapped.teams] == [1, 1, 0, 2, 0, 0, 0, 0, 0, 0]
    assert swapped.team_names == pop.team_names
    with pytest.raises(ValueError, match="unknown learned slot"):
        liam_population({"ia2c0": spinner})
    assert set(LEARNED_SLOTS) == {"rl_a0", "rl_a1", "rl_a2", "rl_b0", "rl_b1", "rl_b2"}


# --- batching and determinism -------------------------------------------------------------------


def test_jit_vmap_1024_envs_deterministic():
    env = make("tag", partners="heuristic")
    n, steps = 1024, 60

    @jax.jit
    def run(key):
        k_reset, k_run = jax.random.split(key)
        state, obs0 = jax.vmap(env.reset)(jax.random.split(k_reset, n))

        def body(state, key):
            k_act, k_step = jax.random.split(key)
            action = jax.random.randint(k_act, (n,), 0, 5, jnp.int32)
            state, ts = jax.vmap(env.step)(jax.random.split(k_step, n), state, action)
            return state, (ts.obs, ts.reward, ts.done, ts.record.t, ts.record.other_actions)

        return obs0, jax.lax.scan(body, state, jax.random.split(k_run, steps))[1]

    first = run(KEY)
    obs0, (obs, rew, done, t, other_actions) = first
    assert obs0.shape == (n, 14) and obs.shape == (steps, n, 14)
    assert bool(jnp.all(jnp.isfinite(obs))) and bool(jnp.all(jnp.isfinite(rew)))
    assert bool(jnp.all(done[49])) and not bool(jnp.any(done[:49])) and not bool(jnp.any(done[50:]))
    np.testing.assert_array_equal(t[:, 0], np.r_[np.arange(50), np.arange(10)])
    assert bool(jnp.all((other_actions >= 1) & (other_actions <= 4)))  # heuristics never no-op
    assert set(np.unique(np.asarray(rew)).tolist()) <= {-11.0, -10.0, -9.0, -1.0, 0.0, 1.0}
    jax.tree.map(np.testing.assert_array_equal, run(KEY), first)  # same key, same trajectory
    other = run(jax.random.PRNGKey(1))
    assert not np.array_equal(obs, other[1][0])
