"""Level-based foraging: lbforaging rules, observations, heuristics, episode ends."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from transam.compose import make_env as make_default_env
from transam.envs.core import EnvError, EnvState
from transam.envs.lbf import (
    EAST,
    LOAD,
    NONE,
    NORTH,
    SOUTH,
    WEST,
    Config,
    LBFGame,
    State,
    make_env,
    make_state,
    observe_agent,
    spawn,
    step_state,
)
from transam.envs.rollout import episode_stats, make_random_rollout
from transam.partners.lbf import heuristic_members, heuristic_population

CFG = Config()
FAR = [[18, 18], [18, 15], [15, 18]]  # spare food cells far from the scenes below
jit_step = jax.jit(step_state, static_argnums=2)
jit_observe = jax.jit(observe_agent, static_argnums=(1, 2))


def step(s: State, actions, config: Config = CFG):  # type: ignore[no-untyped-def]
    return jit_step(s, jnp.asarray(actions, jnp.int32), config)


def state(agents, levels, foods, food_levels) -> State:  # type: ignore[no-untyped-def]
    return make_state(
        jnp.array(agents), jnp.array(levels), jnp.array(foods), jnp.array(food_levels)
    )


def moved(agents, actions, foods=((12, 12),)) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Agent positions after one step with level-1 agents and level-1 foods at ``foods``."""
    foods = list(foods) + FAR[: 4 - len(foods)]
    nxt, _, _ = step(state(agents, [1, 1], foods, [1] * 4), actions)
    return np.asarray(nxt.agent_pos)


def test_paper_worked_example() -> None:
    """Foods 1, 2, 3, 4 (total 10): agent 0 takes food 1 alone (1/10); agent 1, level 4,
    takes 2, 3, 4 alone over three steps (2/10, 3/10, 4/10: 9/10 in all). Agent 1 has foods
    north, south and west of it and loads them in that order (lbforaging's N, S, W, E)."""
    s = state([[10, 10], [5, 5]], [1, 4], [[5, 4], [6, 5], [10, 11], [4, 5]], [4, 3, 1, 2])
    rewards, terminal = [], []
    for actions in ([LOAD, LOAD], [NONE, LOAD], [NONE, LOAD]):
        s, r, t = step(s, actions)
        rewards.append(np.asarray(r))
        terminal.append(bool(t))
    np.testing.assert_allclose(rewards, [[0.1, 0.2], [0.0, 0.3], [0.0, 0.4]], atol=1e-6)
    np.testing.assert_allclose(np.sum(rewards, axis=0), [0.1, 0.9], atol=1e-6)
    assert terminal == [False, False, True]
    np.testing.assert_array_equal(np.asarray(s.food_level), [0, 0, 0, 0])


def test_level_rules() -> None:
    foods = [[5, 6], *FAR]
    # Alone, a level-1 agent cannot load a level-2 food; a level-2 agent can (>=, not >).
    for level, ok in ((1, False), (2, True)):
        nxt, r, _ = step(state([[5, 5], [0, 0]], [level, 1], foods, [2, 1, 1, 1]), [LOAD, NONE])
        assert (int(nxt.food_level[0]) == 0) == ok
        np.testing.assert_allclose(np.asarray(r), [0.4 if ok else 0.0, 0.0], atol=1e-6)
    # Two adjacent loaders (levels 1 + 2) collect a level-3 food together, shares 1:2 of 3/5.
    pair = state([[5, 5], [5, 7]], [1, 2], foods[:2], [3, 2])
    nxt, r, _ = step(pair, [LOAD, LOAD])
    assert int(nxt.food_level[0]) == 0
    np.testing.assert_allclose(np.asarray(r), [1 * 3 / (3 * 5), 2 * 3 / (3 * 5)], atol=1e-6)
    # An adjacent partner that does not load does not count.
    nxt, r, _ = step(pair, [LOAD, NONE])
    assert int(nxt.food_level[0]) == 3 and np.all(np.asarray(r) == 0)
    # A failed pool costs every member the penalty.
    cfg = Config(penalty=0.5)
    nxt, r, _ = step(state([[5, 5], [5, 7]], [1, 1], foods[:2], [3, 2]), [LOAD, LOAD], cfg)
    np.testing.assert_allclose(np.asarray(r), [-0.5, -0.5])
    # Pools form per food, loaders in index order: agent 0, next to foods north (level 1) and
    # east (level 3), takes the north one alone; agent 1 then fails on the east one alone.
    s = state([[5, 5], [5, 7]], [1, 2], [[4, 5], [5, 6], *FAR[:2]], [1, 3, 1, 1])
    nxt, r, _ = step(s, [LOAD, LOAD])
    np.testing.assert_array_equal(np.asarray(nxt.food_level), [0, 3, 1, 1])
    np.testing.assert_allclose(np.asarray(r), [1 / 6, 0.0], atol=1e-6)


def test_movement_and_collisions() -> None:
    for action, to in ((NORTH, [4, 5]), (SOUTH, [6, 5]), (WEST, [5, 4]), (EAST, [5, 6])):
        assert moved([[5, 5], [9, 9]], [action, NONE])[0].tolist() == to
    for action in (NORTH, WEST):  # off the grid
        assert moved([[0, 0], [9, 9]], [action, NONE])[0].tolist() == [0, 0]
    assert moved([[19, 19], [9, 9]], [SOUTH, NONE])[0].tolist() == [19, 19]
    assert moved([[5, 5], [9, 9]], [EAST, NONE], foods=[[5, 6]])[0].tolist() == [5, 5]  # food
    assert moved([[5, 5], [5, 7]], [EAST, WEST]).tolist() == [[5, 5], [5, 7]]  # same target
    assert moved([[5, 5], [5, 6]], [EAST, NONE]).tolist() == [[5, 5], [5, 6]]  # occupant stays
    assert moved([[5, 5], [5, 6]], [EAST, LOAD]).tolist() == [[5, 5], [5, 6]]  # load w/o food
    assert moved([[5, 5], [5, 6]], [EAST, EAST]).tolist() == [[5, 6], [5, 7]]  # follow
    assert moved([[5, 5], [5, 6]], [EAST, WEST]).tolist() == [[5, 6], [5, 5]]  # swap


def test_observation_layout() -> None:
    s = state([[10, 10], [3, 4]], [1, 2], [[12, 3], [2, 15], [7, 7], [9, 11]], [1, 2, 0, 3])
    obs = np.asarray(jit_observe(s, 0, CFG))
    assert obs.dtype == np.float32 and obs.shape == (18,)
    # Foods packed row-major (the eaten one last), then self, then the other agent.
    expected = [2, 15, 2, 9, 11, 3, 12, 3, 1, -1, -1, 0, 10, 10, 1, 3, 4, 2]
    np.testing.assert_array_equal(obs, expected)
    np.testing.assert_array_equal(jit_observe(s, 1, CFG)[12:], [3, 4, 2, 10, 10, 1])
    # Limited sight: window coordinates pos - own + min(sight, own); food within the window,
    # the other agent when its window coordinates lie in [0, 2 * sight].
    near = Config(sight=2)
    obs = np.asarray(jit_observe(s, 0, near))
    np.testing.assert_array_equal(obs[:6], [1, 3, 3, -1, -1, 0])
    np.testing.assert_array_equal(obs[12:], [2, 2, 1, -1, -1, 0])
    edge = state([[1, 1], [3, 4]], [1, 2], [[2, 1], *FAR], [1, 1, 1, 1])
    obs = np.asarray(jit_observe(edge, 0, near))  # column offset 3 > sight, still seen
    np.testing.assert_array_equal(obs[:6], [2, 1, 1, -1, -1, 0])
    np.testing.assert_array_equal(obs[12:], [1, 1, 1, 3, 4, 2])


def test_relative_obs_changes_only_the_controlled_view() -> None:
    """``relative_obs``: foods and the partner as offsets from the controlled agent, unused
    slots zero, own position and all levels kept; the partner's view stays lbforaging's."""
    s = state([[10, 10], [3, 4]], [1, 2], [[12, 3], [2, 15], [7, 7], [9, 11]], [1, 2, 0, 3])
    rel = Config(relative_obs=True)
    obs, other = jax.jit(LBFGame(rel).observe)(s)
    expected = [-8, 5, 2, -1, 1, 3, 2, -7, 1, 0, 0, 0, 10, 10, 1, -7, -6, 2]
    np.testing.assert_array_equal(np.asarray(obs), expected)
    np.testing.assert_array_equal(np.asarray(other[0]), np.asarray(jit_observe(s, 1, CFG)))
    plain, _ = jax.jit(LBFGame(CFG).observe)(s)
    np.testing.assert_array_equal(np.asarray(plain), np.asarray(jit_observe(s, 0, CFG)))
    # The learned partners act on their own (unchanged) view, so they are offered here too.
    env = make_default_env("lbf", rel)
    assert env.spec.obs_dim == 18 and env.num_partners > 1


def test_spawn_rules() -> None:
    keys = jax.random.split(jax.random.key(0), 2000)
    s = jax.jit(jax.vmap(lambda k: spawn(k, CFG)))(keys)
    apos, alvl = np.asarray(s.agent_pos), np.asarray(s.agent_level)
    fpos, flvl = np.asarray(s.food_pos), np.asarray(s.food_level)
    assert np.all(np.any(apos[:, 0] != apos[:, 1], axis=-1))
    assert set(np.unique(alvl)) == {1, 2} and set(np.unique(flvl)) == {1, 2, 3, 4}
    assert np.all(flvl >= 1) and np.all(flvl <= alvl.sum(-1, keepdims=True))
    np.testing.assert_allclose(np.asarray(s.total_food), flvl.sum(-1))
    assert {0, 19} <= set(np.unique(apos)) and fpos.min() == 1 and fpos.max() == 18
    for i in range(4):
        assert np.all(np.any(fpos[:, i, None] != apos, axis=-1))
        for j in range(i):
            d = np.abs(fpos[:, i] - fpos[:, j])
            assert np.all(d.max(-1) >= 2) and np.all((d.min(-1) > 0) | (d.max(-1) >= 3))
    coop = jax.jit(jax.vmap(lambda k: spawn(k, Config(force_coop=True))))(keys[:200])
    assert np.all(np.asarray(coop.food_level) == np.asarray(coop.agent_level).sum(-1)[:, None])


def test_config_rejects_bad_values() -> None:
    with pytest.raises(EnvError, match="grid_size"):
        Config(grid_size=2)
    with pytest.raises(EnvError, match="sight"):
        Config(sight=0)


KEYS = jax.random.split(jax.random.key(1), 64)


@jax.jit
def all_members_act(s: State) -> dict[str, jax.Array]:
    """Each member's action (for each of 64 keys) from agent 1's observation of ``s``."""
    obs = observe_agent(s, 1, CFG)
    return {m.name: jax.vmap(m.act, (0, None))(KEYS, obs) for m in heuristic_members(CFG)}


def partner_actions(agents, levels, foods, food_levels) -> dict[str, set[int]]:  # type: ignore[no-untyped-def]
    acts = all_members_act(state(agents, levels, foods, food_levels))
    return {name: set(np.asarray(a).tolist()) for name, a in acts.items()}


def test_heuristics_choose_the_right_action() -> None:
    # Adjacent target: load.
    a = partner_actions([[2, 2], [5, 5]], [1, 1], [[5, 6], *FAR], [1, 1, 1, 1])
    assert all(a[h] == {LOAD} for h in ("H1", "H2", "H3", "H4", "lazy"))
    # H1 goes for its closest food (east); H2 for the one closest to the centroid (6, 6),
    # north-west of it: north before west.
    a = partner_actions([[2, 2], [10, 10]], [1, 1], [[10, 14], [4, 4], *FAR[:2]], [1, 1, 1, 1])
    assert a["H1"] == {EAST} and a["H2"] == {NORTH} and a["lazy"] == {NONE}
    # H3 skips foods above its own level.
    a = partner_actions([[2, 2], [10, 10]], [1, 1], [[10, 12], [13, 10], *FAR[:2]], [2, 1, 1, 1])
    assert a["H1"] == {EAST} and a["H3"] == {SOUTH}
    # H4 skips foods above the visible players' summed level (2); H2 does not.
    a = partner_actions([[10, 12], [10, 10]], [1, 1], [[8, 11], [14, 11], *FAR[:2]], [3, 2, 1, 1])
    assert a["H2"] == {NORTH} and a["H4"] == {SOUTH}
    # Ties go to the first food in row-major order: (10, 12) before (12, 10).
    a = partner_actions([[2, 2], [10, 10]], [1, 1], [[12, 10], [10, 12], *FAR[:2]], [1, 1, 1, 1])
    assert a["H1"] == {EAST}
    # H3's way north is blocked by a food it cannot load: it takes the next wanted move (east);
    # with no other wanted move it falls back to a random valid action (not north).
    a = partner_actions([[2, 2], [10, 10]], [1, 1], [[9, 10], [6, 12], *FAR[:2]], [2, 1, 1, 1])
    assert a["H3"] == {EAST}
    a = partner_actions([[2, 2], [10, 10]], [1, 1], [[9, 10], [6, 10], *FAR[:2]], [2, 1, 1, 1])
    assert a["H3"] == {NONE, SOUTH, WEST, EAST, LOAD}
    # No food left: random valid actions; in a corner that is none, south or east.
    a = partner_actions([[5, 5], [0, 0]], [1, 1], [[3, 3], *FAR], [0, 0, 0, 0])
    assert all(a[h] == {NONE, SOUTH, EAST} for h in ("H1", "H2", "H3", "H4", "random"))


def test_time_limit_and_terminal_through_the_wrapper() -> None:
    pop = heuristic_population(CFG)
    env = make_env(CFG, pop)
    lazy = pop.team_names.index("lazy")

    def run(state: EnvState, actions: jax.Array):  # type: ignore[no-untyped-def]
        keys = jax.random.split(jax.random.key(0), actions.shape[0])
        return jax.lax.scan(lambda s, x: env.step(x[0], s, x[1]), state, (keys, actions))

    run = jax.jit(run)
    # A do-nothing agent with the lazy partner can never clear the food: truncation at 50.
    start, _ = env.reset(jax.random.key(3), lazy)
    _, ts = run(start, jnp.zeros(60, jnp.int32))
    done = np.asarray(ts.done)
    assert np.flatnonzero(done).tolist() == [49] and bool(ts.truncated[49])
    # The worked example, with the lazy partner loading: all food gone at step 3 (terminal).
    game = LBFGame(CFG)
    g = state([[10, 10], [5, 5]], [1, 4], [[5, 4], [6, 5], [10, 11], [4, 5]], [4, 3, 1, 2])
    obs, other = game.observe(g)
    start = EnvState(
        game=g,
        partner=jnp.int32(lazy),
        t=jnp.int32(0),
        obs=obs,
        other_obs=other,
        other_prev_actions=jnp.full((1,), -1, jnp.int32),
    )
    _, ts = run(start, jnp.zeros(60, jnp.int32).at[0].set(LOAD))
    np.testing.assert_array_equal(np.asarray(ts.done[:4]), [False, False, True, False])
    assert not bool(ts.truncated[2]) and int(ts.record.t[3]) == 0
    np.testing.assert_allclose(np.asarray(ts.reward[:3]), [0.1, 0.0, 0.0], atol=1e-6)
    np.testing.assert_array_equal(np.asarray(ts.record.other_actions[:3, 0]), [LOAD] * 3)


def test_heuristic_partners_jit_vmap_and_same_key_same_trajectory() -> None:
    """Whole episodes against the scripted partners (test_envs: 1,024 copies, 8 steps, against
    the default population; 256 here, as the scripted partners' planning is slow unoptimised)."""
    env = make_env(CFG, heuristic_population(CFG))
    rollout = make_random_rollout(env, num_envs=256, num_steps=60)
    _, a = rollout(jax.random.key(7))
    _, b = rollout(jax.random.key(7))
    _, c = rollout(jax.random.key(8))
    assert a.obs.shape == (60, 256, 18) and a.record.other_obs.shape == (60, 256, 1, 18)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert not np.array_equal(np.asarray(a.obs), np.asarray(c.obs))
    stats = episode_stats(a)
    assert len(stats.returns) >= 256 and np.all(stats.returns <= 1 + 1e-5)
    assert np.all(np.asarray(a.reward) >= 0) and stats.returns.max() > 0
    assert all(len(r) > 0 for r in stats.by_partner(env.num_partners))


def reference_step(pos, lvl, field, total, actions, penalty):  # type: ignore[no-untyped-def]
    """lbforaging 2.0.0's ``ForagingEnv.step`` on plain numpy data, loaders in index order."""
    size = field.shape[0]
    moves = [(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1), (0, 0)]
    near = [(-1, 0), (1, 0), (0, -1), (0, 1)]

    def inside(r, c):  # type: ignore[no-untyped-def]
        return 0 <= r < size and 0 <= c < size

    def valid(p, a):  # type: ignore[no-untyped-def]
        if a == LOAD:
            return any(
                inside(p[0] + dr, p[1] + dc) and field[p[0] + dr, p[1] + dc] for dr, dc in near
            )
        r, c = p[0] + moves[a][0], p[1] + moves[a][1]
        return inside(r, c) and field[r, c] == 0

    acts = [a if valid(p, a) else NONE for p, a in zip(pos, actions, strict=True)]
    claims: dict[tuple[int, int], list[int]] = {}
    for i, (p, a) in enumerate(zip(pos, acts, strict=True)):
        claims.setdefault((p[0] + moves[a][0], p[1] + moves[a][1]), []).append(i)
    new = [tuple(p) for p in pos]
    for cell, who in claims.items():
        if len(who) == 1:
            new[who[0]] = cell
    rewards = np.zeros(len(pos))
    loading = [i for i, a in enumerate(acts) if a == LOAD]
    while loading:
        i = loading.pop(0)
        fr, fc = next(
            (new[i][0] + dr, new[i][1] + dc)
            for dr, dc in near
            if inside(new[i][0] + dr, new[i][1] + dc) and field[new[i][0] + dr, new[i][1] + dc]
        )
        pool = [i] + [j for j in loading if abs(new[j][0] - fr) + abs(new[j][1] - fc) == 1]
        loading = [j for j in loading if j not in pool]
        pool_level = sum(lvl[j] for j in pool)
        if pool_level < field[fr, fc]:
            rewards[pool] -= penalty
            continue
        for j in pool:
            rewards[j] = lvl[j] * field[fr, fc] / (pool_level * total)
        field[fr, fc] = 0
    return np.array(new), rewards


def reference_obs(pos, lvl, field, i, sight, num_foods):  # type: ignore[no-untyped-def]
    """lbforaging 2.0.0's vector observation of agent ``i`` (``_make_obs`` + ``make_obs_array``)."""
    r0, c0 = pos[i]
    top, left = r0 - min(sight, r0), c0 - min(sight, c0)
    window = field[top : r0 + sight + 1, left : c0 + sight + 1]
    out = [-1.0, -1.0, 0.0] * (num_foods + 2)
    for k, (y, x) in enumerate(zip(*np.nonzero(window), strict=True)):
        out[3 * k : 3 * k + 3] = [y, x, window[y, x]]
    seen = [(pos[j][0] - top, pos[j][1] - left, lvl[j]) for j in (i, 1 - i)]
    seen = [p for p in seen if min(p[:2]) >= 0 and max(p[:2]) <= 2 * sight]
    for k, p in enumerate(seen):
        out[3 * (num_foods + k) : 3 * (num_foods + k) + 3] = p
    return np.array(out, np.float32)


def test_matches_an_lbforaging_reference_on_random_play() -> None:
    """Random play (many loads) on a small grid with limited sight, against the reference."""
    cfg = Config(grid_size=7, num_foods=3, sight=2, penalty=0.25)

    @jax.jit
    def play(key: jax.Array):  # type: ignore[no-untyped-def]
        k0, k1 = jax.random.split(key)
        actions = jax.random.choice(k1, 6, (120, 2), p=jnp.array([1, 1, 1, 1, 1, 4]) / 9)

        def body(s: State, a: jax.Array):  # type: ignore[no-untyped-def]
            obs = jnp.stack([observe_agent(s, 0, cfg), observe_agent(s, 1, cfg)])
            nxt, r, _ = step_state(s, a, cfg)
            return nxt, (s, obs, r)

        return actions, jax.lax.scan(body, spawn(k0, cfg), actions)[1]

    loads = 0
    for seed in range(4):
        actions, (states, obs, rewards) = jax.tree.map(np.asarray, play(jax.random.key(seed)))
        pos, lvl = states.agent_pos[0], states.agent_level[0]
        field = np.zeros((7, 7), np.int64)
        for p, level in zip(states.food_pos[0], states.food_level[0], strict=True):
            field[p[0], p[1]] = level
        total = float(field.sum())
        for t in range(len(actions)):
            np.testing.assert_array_equal(states.agent_pos[t], pos, err_msg=f"seed {seed} t {t}")
            for i in range(2):
                np.testing.assert_array_equal(obs[t, i], reference_obs(pos, lvl, field, i, 2, 3))
            before = field.sum()
            pos, r = reference_step(pos, lvl, field, total, actions[t].tolist(), 0.25)
            np.testing.assert_allclose(rewards[t], r, atol=1e-6, err_msg=f"seed {seed} t {t}")
            loads += int(field.sum() < before)
    assert loads >= 4
