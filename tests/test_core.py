"""The controlled-agent wrapper and the population mechanism, on a tiny deterministic game."""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from transam.envs.core import ControlledEnv, EnvError, GameSpec
from transam.envs.population import Member, Population, Team
from transam.envs.rollout import episode_stats

LEN = 4


@dataclass(frozen=True)
class CounterGame:
    """pos counts the controlled agent's actions; others see pos*10 + slot; terminal at pos>=9."""

    spec: GameSpec = GameSpec(  # noqa: RUF009 (frozen, so sharing the default is safe)
        name="counter",
        obs_dim=2,
        num_actions=3,
        num_others=2,
        other_obs_dim=1,
        other_num_actions=4,
        episode_len=LEN,
        action_names=("zero", "one", "two"),
    )

    def reset(self, key: jax.Array) -> jax.Array:
        return jax.random.randint(key, (), 0, 2)

    def observe(self, state: jax.Array) -> tuple[jax.Array, jax.Array]:
        obs = jnp.stack([state, 1]).astype(jnp.float32)
        others = (state * 10 + jnp.arange(2))[:, None].astype(jnp.float32)
        return obs, others

    def transition(self, key, state, action, other_actions):  # type: ignore[no-untyped-def]
        nxt = state + action
        reward = action.astype(jnp.float32) + 0.5 * other_actions.sum()
        return nxt, reward, nxt >= 9


def _const(a: int) -> Member:
    return Member(f"const{a}", lambda key, obs: jnp.int32(a))


MEMBERS = [
    _const(0),
    _const(1),
    _const(3),
    Member("parity", lambda key, obs: obs[0].astype(jnp.int32) % 2),
    Member("random", lambda key, obs: jax.random.randint(key, (), 0, 4)),
]
TEAMS = [
    Team("a", ("const0", "const1")),
    Team("b", ("const3", "parity")),
    Team("c", ("random", "const0")),
]


@pytest.fixture(scope="module")
def env() -> ControlledEnv:
    return ControlledEnv(CounterGame(), Population("toy", MEMBERS, TEAMS))


def _scan(env: ControlledEnv, actions: np.ndarray, partner: int | None = None):  # type: ignore[no-untyped-def]
    def run(key):  # type: ignore[no-untyped-def]
        k0, k1 = jax.random.split(key)
        state, _ = env.reset(k0, partner)

        def body(state, xs):  # type: ignore[no-untyped-def]
            key, action = xs
            before = state
            state, ts = env.step(key, state, action)
            return state, (before, ts)

        keys = jax.random.split(k1, len(actions))
        return jax.lax.scan(body, state, (keys, jnp.asarray(actions, jnp.int32)))

    return jax.jit(run)(jax.random.key(0))


def test_episode_boundary_resets_clock_partner_and_lines_up_record(env: ControlledEnv) -> None:
    _, (before, ts) = _scan(env, np.zeros(10, np.int32))
    t = np.asarray(ts.record.t)
    np.testing.assert_array_equal(t, [0, 1, 2, 3, 0, 1, 2, 3, 0, 1])
    np.testing.assert_array_equal(np.asarray(ts.done), t == LEN - 1)
    np.testing.assert_array_equal(np.asarray(ts.truncated), t == LEN - 1)
    # The state right after a boundary is a fresh episode: clock at zero.
    np.testing.assert_array_equal(np.asarray(before.t), t)
    # The partner never changes inside an episode.
    partner = np.asarray(ts.record.partner)
    for start in (0, 4, 8):
        assert len(set(partner[start : start + LEN].tolist())) == 1
    # The record describes the state the agent acted on (o^{-1}_t beside o_t) ...
    np.testing.assert_array_equal(np.asarray(ts.record.other_obs), np.asarray(before.other_obs))
    np.testing.assert_array_equal(np.asarray(ts.record.partner), np.asarray(before.partner))
    # ... and the returned obs is the next state's (the new episode's first after a boundary).
    np.testing.assert_array_equal(np.asarray(ts.obs[:-1]), np.asarray(before.obs[1:]))


def test_terminal_before_time_limit_is_not_truncation(env: ControlledEnv) -> None:
    spec = GameSpec(**{**CounterGame.spec.__dict__, "episode_len": 50})
    long_env = ControlledEnv(CounterGame(spec=spec), env.population)
    _, (before, ts) = _scan(long_env, np.full(12, 2, np.int32))
    done, trunc = np.asarray(ts.done), np.asarray(ts.truncated)
    first = int(np.flatnonzero(done)[0])
    # pos starts at 0 or 1 and grows by 2: the game ends at the first step reaching pos >= 9.
    assert int(before.game[0]) + 2 * (first + 1) >= 9 > int(before.game[0]) + 2 * first
    assert not trunc[first] and int(before.t[first + 1]) == 0


def test_partners_act_by_their_team_and_own_obs(env: ControlledEnv) -> None:
    _, (before, ts) = _scan(env, np.ones(3, np.int32), partner=1)
    acts = np.asarray(ts.record.other_actions)
    pos = np.asarray(before.game)
    np.testing.assert_array_equal(acts[:, 0], 3)
    np.testing.assert_array_equal(acts[:, 1], (pos * 10 + 1) % 2)
    _, (_, ts) = _scan(env, np.ones(3, np.int32), partner=0)
    np.testing.assert_array_equal(np.asarray(ts.record.other_actions), [[0, 1]] * 3)
    assert np.asarray(ts.reward).tolist() == [1.5, 1.5, 1.5]


def test_partner_drawn_uniformly_at_reset(env: ControlledEnv) -> None:
    keys = jax.random.split(jax.random.key(1), 3000)
    partners = np.asarray(jax.vmap(lambda k: env.reset(k)[0].partner)(keys))
    counts = np.bincount(partners, minlength=3)
    assert counts.sum() == 3000 and np.all(np.abs(counts - 1000) < 120), counts


def test_bad_partner_and_action_errors_name_value_and_choices(env: ControlledEnv) -> None:
    with pytest.raises(EnvError, match=r"partner_id 3 out of range.*0\.\.2.*a, b, c"):
        env.reset(jax.random.key(0), 3)
    with pytest.raises(EnvError, match="partner_id"):
        env.reset(jax.random.key(0), 1.5)
    state, _ = env.reset(jax.random.key(0), 0)
    with pytest.raises(EnvError, match=r"action 7 out of range.*0=zero, 1=one, 2=two"):
        env.step(jax.random.key(0), state, 7)
    with pytest.raises(EnvError, match=r"shape \(2,\)"):
        env.step(jax.random.key(0), state, jnp.array([0, 1]))
    with pytest.raises(EnvError, match="dtype float32"):
        env.step(jax.random.key(0), state, jnp.float32(1))
    # Shape errors are raised at trace time under jit too.
    with pytest.raises(EnvError, match=r"shape \(2,\)"):
        jax.jit(env.step)(jax.random.key(0), state, jnp.array([0, 1]))


def test_population_validation() -> None:
    with pytest.raises(ValueError, match="unknown member"):
        Population("p", MEMBERS, [Team("x", ("const0", "nope"))])
    with pytest.raises(ValueError, match="slot count"):
        Population("p", MEMBERS, [Team("x", ("const0",)), Team("y", ("const0", "const1"))])
    pop = Population("p", MEMBERS, TEAMS).subset(["c", "a"])
    assert pop.team_names == ("c", "a") and pop.size == 2
    with pytest.raises(EnvError, match="controls 1 agents"):
        ControlledEnv(CounterGame(), Population("p", MEMBERS, [Team("x", ("const0",))]))


def test_episode_stats_sums_each_finished_episode() -> None:
    from transam.envs.core import PartnerRecord, Timestep

    reward = np.array([[1.0, 2.0], [1.0, 2.0], [1.0, 2.0], [5.0, 2.0]])
    done = np.array([[False, True], [True, False], [False, True], [False, False]])
    partner = np.array([[0, 1], [0, 2], [1, 2], [1, 0]])
    z = np.zeros_like(reward)
    ts = Timestep(reward, reward, done, done, PartnerRecord(z, z, partner, z))  # type: ignore[arg-type]
    stats = episode_stats(ts)
    np.testing.assert_allclose(sorted(stats.returns), [2.0, 2.0, 4.0])
    assert sorted(stats.partners.tolist()) == [0, 1, 2]


def test_population_mixes_heuristic_and_neural_members() -> None:
    """A learned member is a function closing over fixed parameters; it mixes with heuristics."""
    import flax.linen as nn

    net = nn.Dense(4)
    params = net.init(jax.random.key(0), jnp.zeros(1))

    def neural(key: jax.Array, obs: jax.Array) -> jax.Array:
        return jnp.argmax(net.apply(params, obs)).astype(jnp.int32)

    members = [*MEMBERS, Member("mlp", neural, kind="a2c")]
    pop = Population("mixed", members, [Team("h", ("const1", "const0")), Team("n", ("mlp", "mlp"))])
    env = ControlledEnv(CounterGame(), pop)
    _, (before, ts) = _scan(env, np.ones(3, np.int32), partner=1)
    expected = jax.vmap(jax.vmap(neural, (None, 0)), (None, 0))(jax.random.key(0), before.other_obs)
    np.testing.assert_array_equal(np.asarray(ts.record.other_actions), np.asarray(expected))
