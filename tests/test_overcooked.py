"""Overcooked (JaxMARL v1, cramped room): delivery, cook timing, shaped rewards, batching."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from transam import make_env as make
from transam._quiet import jaxmarl_modules
from transam.envs.overcooked import (
    DISH,
    EMPTY,
    INTERACT,
    OBS_DIM,
    ONION,
    PLATE,
    STAY,
    Config,
    OvercookedGame,
    pot_status,
    shaped_events,
    shaped_rewards,
)
from transam.envs.rollout import make_random_rollout
from transam.partners.overcooked import (
    DIST_NP,
    FLOOR,
    MOVE_VEC,
    NEXT_NP,
    dish_carrier_task,
    heuristic_population,
    onion_carrier_task,
    read_view,
    scripted,
)

with jaxmarl_modules():
    from jaxmarl.environments.overcooked.common import DIR_TO_VEC, make_overcooked_map

GAME = OvercookedGame(Config())
KEY = jax.random.key(0)
N, S, E, W = 0, 1, 2, 3  # orientation indices (= the move action that turns that way)
ONION_COOK = scripted(onion_carrier_task, eps=0.0)
DISH_COOK = scripted(dish_carrier_task, eps=0.0)
STEPS = GAME.spec.episode_len


def scripted_pair_rollout(key: jax.Array):  # type: ignore[no-untyped-def]
    """400 steps of onion carrier (agent_0) + dish carrier (agent_1), both scripted."""
    state = GAME.reset(key)

    def body(state, key):  # type: ignore[no-untyped-def]
        obs = GAME.joint_observe(state)
        actions = jnp.stack([ONION_COOK(key, obs[0]), DISH_COOK(key, obs[1])])
        _, nxt, rewards, _, info = GAME.env.step_env(
            key, state, {"agent_0": actions[0], "agent_1": actions[1]}
        )
        out = {
            "pot": pot_status(state)[0],
            "inv": state.agent_inv,
            "actions": actions,
            "sparse": jnp.stack([rewards["agent_0"], rewards["agent_1"]]),
            "shaped": shaped_rewards(state, actions, nxt),
            "events": shaped_events(state, actions, nxt),
            "jaxmarl_shaped": jnp.stack(
                [info["shaped_reward"]["agent_0"], info["shaped_reward"]["agent_1"]]
            ),
        }
        return nxt, out

    _, out = jax.lax.scan(body, state, jax.random.split(key, STEPS))
    return out


@pytest.fixture(scope="module")
def bases():  # type: ignore[no-untyped-def]
    """16 start states (one jitted, vmapped reset)."""
    return jax.jit(jax.vmap(GAME.reset))(jax.random.split(KEY, 16))


@pytest.fixture(scope="module")
def pair() -> dict[str, np.ndarray]:
    """Rollouts for 4 keys (the first two share a key, for the determinism check)."""
    keys = jnp.stack([jax.random.key(1), jax.random.key(1), jax.random.key(2), jax.random.key(3)])
    out = jax.jit(jax.vmap(scripted_pair_rollout))(keys)
    return {k: np.asarray(v) for k, v in out.items()}


# --- scripted play ------------------------------------------------------------------------------


def test_scripted_pair_delivers_and_both_get_20(pair: dict[str, np.ndarray]) -> None:
    for e in range(4):
        sparse = pair["sparse"][e]
        hits = np.flatnonzero(sparse[:, 0] > 0)
        assert len(hits) >= 5, "an onion+dish pair should serve several soups in 400 steps"
        first = hits[0]
        np.testing.assert_array_equal(sparse[first], [20.0, 20.0])
        assert np.all(sparse[:first] == 0)
        np.testing.assert_array_equal(sparse[:, 0], sparse[:, 1])  # team reward
        # The soup was delivered by the dish carrier (agent_1) holding a dish and interacting.
        assert pair["inv"][e, first, 1] == DISH and pair["actions"][e, first, 1] == INTERACT


def test_pot_cooks_exactly_20_steps(pair: dict[str, np.ndarray]) -> None:
    checked = 0
    for e in range(4):
        pot = pair["pot"][e]  # status in the state before each step
        # Third onion in during step t: status 21 (two onions) before, 19 after.
        for t in np.flatnonzero((pot[:-1] == 21) & (pot[1:] == 19)):
            if t + 20 >= STEPS:
                continue
            np.testing.assert_array_equal(pot[t + 1 : t + 20], np.arange(19, 0, -1))
            assert pot[t + 20] == 0  # ready 20 steps after the state the onion went in from
            checked += 1
    assert checked >= 8


def test_shaped_events_on_scripted_trajectory(pair: dict[str, np.ndarray]) -> None:
    for e in range(4):
        pot, inv, ev = pair["pot"][e], pair["inv"][e], pair["events"][e]
        onion_in = ev[:, :, 0].sum(1)
        plate, soup = ev[:, :, 1], ev[:, :, 2]
        # Every onion the pot gained (23->22, 22->21, 21->19) is one onion event, and vice versa.
        gained = ((pot[:-1] >= 21) & (pot[1:] == pot[:-1] - 1)) | (
            (pot[:-1] == 21) & (pot[1:] == 19)
        )
        np.testing.assert_array_equal(onion_in[:-1], gained.astype(int))
        # Every soup taken out of the pot (0 -> 23) is one soup event.
        np.testing.assert_array_equal(soup.sum(1)[:-1], ((pot[:-1] == 0) & (pot[1:] == 23)))
        # Roles: only the onion carrier puts onions in, only the dish carrier plates.
        assert ev[:, 1, 0].sum() == 0 and ev[:, 0, 1:].sum() == 0
        # The dish carrier takes one plate per soup, always while the pot is cooking: useful.
        took_plate = (inv[:-1, 1] == EMPTY) & (inv[1:, 1] == PLATE)
        np.testing.assert_array_equal(plate[:-1, 1], took_plate)
        assert plate[:, 1].sum() >= soup[:, 1].sum() >= 5
        assert np.all(pot[:-1][took_plate] != 23)
        shaped = pair["shaped"][e]
        np.testing.assert_allclose(shaped, ev @ np.array([3.0, 3.0, 5.0]))
        # JaxMARL's own onion and soup shaping (3 and 5) agree with ours on this trajectory.
        np.testing.assert_allclose(pair["jaxmarl_shaped"][e], shaped)


def test_same_key_same_trajectory(pair: dict[str, np.ndarray]) -> None:
    for k, v in pair.items():
        np.testing.assert_array_equal(v[0], v[1], err_msg=k)


# --- shaped rewards on hand-built states --------------------------------------------------------


def make_state(base, pos, dirs, inv, pot=23, plates=(), onions=()):  # type: ignore[no-untyped-def]
    """A cramped-room state: agent cells (x, y), orientations, held items, pot, loose items."""
    pos_arr = jnp.asarray(pos, jnp.uint32)
    dirs_arr = jnp.asarray(dirs, jnp.int32)

    def items(xs):  # type: ignore[no-untyped-def]
        return jnp.asarray(xs, jnp.uint32).reshape(-1, 2) if xs else jnp.array([])

    maze = make_overcooked_map(
        base.wall_map,
        base.goal_pos,
        pos_arr,
        dirs_arr,
        jnp.asarray([[1, 3]], jnp.uint32),
        jnp.asarray([[0, 1], [4, 1]], jnp.uint32),
        base.pot_pos,
        jnp.asarray([pot]),
        items(onions),
        items(plates),
        jnp.array([]),
        pad_obs=True,
        num_agents=2,
        agent_view_size=5,
    )
    return base.replace(
        agent_pos=pos_arr,
        agent_dir_idx=dirs_arr,
        agent_dir=DIR_TO_VEC[dirs_arr].astype(base.agent_dir.dtype),
        agent_inv=jnp.asarray(inv, jnp.int32),
        maze_map=maze.astype(base.maze_map.dtype),
    )


AT_POT, AT_PLATES, AT_GOAL = (2, 1), (1, 2), (3, 2)
CASES = [
    # (name, state kwargs, actions, expected shaped [2], expected sparse [2])
    ("onion into pot with 2", dict(inv=[ONION, EMPTY], pot=21), [5, 4], [3, 0], [0, 0]),
    ("onion into empty pot", dict(inv=[ONION, EMPTY], pot=23), [5, 4], [3, 0], [0, 0]),
    ("onion at cooking pot", dict(inv=[ONION, EMPTY], pot=10), [5, 4], [0, 0], [0, 0]),
    ("onion held, no interact", dict(inv=[ONION, EMPTY], pot=22), [4, 4], [0, 0], [0, 0]),
    ("plate, pot empty", dict(inv=[EMPTY, EMPTY], pot=23), [4, 5], [0, 0], [0, 0]),
    ("plate, pot has onion", dict(inv=[EMPTY, EMPTY], pot=22), [4, 5], [0, 3], [0, 0]),
    ("plate, pot cooking", dict(inv=[EMPTY, EMPTY], pot=7), [4, 5], [0, 3], [0, 0]),
    (
        "plate, plate on counter",
        dict(inv=[EMPTY, EMPTY], pot=7, plates=[(2, 3)]),
        [4, 5],
        [0, 0],
        [0, 0],
    ),
    ("plate, other holds plate", dict(inv=[PLATE, EMPTY], pot=7), [4, 5], [0, 0], [0, 0]),
    ("plate + first onion same step", dict(inv=[ONION, EMPTY], pot=23), [5, 5], [3, 0], [0, 0]),
    ("soup from ready pot", dict(inv=[PLATE, EMPTY], pot=0), [5, 4], [5, 0], [0, 0]),
    ("plate at cooking pot", dict(inv=[PLATE, EMPTY], pot=1), [5, 4], [0, 0], [0, 0]),
]
DELIVERY = (
    "deliver",
    dict(pos=[AT_GOAL, AT_PLATES], dirs=[S, S], inv=[DISH, EMPTY]),
    [5, 4],
    [0, 0],
    [20, 20],
)
JOINT_STEP = jax.jit(GAME.joint_step)


@pytest.mark.parametrize("case", [*CASES, DELIVERY], ids=lambda c: c[0])
def test_shaped_rewards_hand_built(case, bases) -> None:  # type: ignore[no-untyped-def]
    _, kwargs, actions, shaped, sparse = case
    kwargs = {"pos": [AT_POT, AT_PLATES], "dirs": [N, S], **kwargs}
    state = make_state(jax.tree.map(lambda x: x[0], bases), **kwargs)
    nxt, r_sparse, r_shaped = JOINT_STEP(KEY, state, jnp.asarray(actions, jnp.int32))
    np.testing.assert_array_equal(np.asarray(r_shaped), shaped)
    np.testing.assert_array_equal(np.asarray(r_sparse), sparse)
    if shaped[0] == 3:  # the onion really went in
        assert int(nxt.agent_inv[0]) == EMPTY
    if shaped[1] == 3:  # the plate really came from the pile
        assert int(nxt.agent_inv[1]) == PLATE


# --- observations and the wrapper ---------------------------------------------------------------


def test_observation_shape_dtype_and_layout(bases) -> None:  # type: ignore[no-untyped-def]
    obs, other = jax.jit(GAME.observe)(jax.tree.map(lambda x: x[0], bases))
    assert obs.shape == (OBS_DIM,) == (520,) and obs.dtype == jnp.float32
    assert other.shape == (1, 520) and other.dtype == jnp.float32
    # Row-major (H, W, C) = (4, 5, 26): JaxMARL's declared (5, 4, 26) would misplace these.
    grid = np.asarray(obs).reshape(4, 5, 26)
    assert grid[0, 2, 10] == 1 and grid[:, :, 10].sum() == 1  # pot at (x=2, y=0)
    assert grid[1, 0, 12] == grid[1, 4, 12] == 1  # onion piles at (0,1) and (4,1)
    assert grid[3, 1, 14] == 1 and grid[3, 3, 15] == 1  # plate pile (1,3), serving cell (3,3)
    assert grid[1, 1, 0] == 1 and grid[1, 3, 1] == 1  # self (agent_0) at (1,1), partner at (3,1)
    view, partner = read_view(obs), read_view(other[0])
    assert int(view.pos) == 6 and int(partner.pos) == 8 and int(partner.other) == 6
    assert int(view.held) == EMPTY and not bool(view.pot_full)


def test_controlled_slot_and_start_orientation(bases) -> None:  # type: ignore[no-untyped-def]
    dirs = np.asarray(bases.agent_dir_idx)
    assert len({tuple(d) for d in dirs}) > 1  # JaxMARL's random start orientations are kept
    swapped = OvercookedGame(Config(controlled_slot=1, random_start_dir=False))
    state, (obs, other) = jax.jit(lambda k: (s := swapped.reset(k), swapped.observe(s)))(KEY)
    np.testing.assert_array_equal(np.asarray(state.agent_dir_idx), [N, N])
    assert int(read_view(obs).pos) == 8 and int(read_view(other[0]).pos) == 6
    assert int(read_view(obs).facing) == N == int(read_view(other[0]).facing)
    np.testing.assert_array_equal(swapped.joint_actions(jnp.int32(5), jnp.asarray([2])), [2, 5])
    with pytest.raises(ValueError, match="controlled_slot"):
        OvercookedGame(Config(controlled_slot=2))


def test_population_jit_vmap_1024_same_key_same_trajectory() -> None:
    pop = heuristic_population()
    assert pop.team_names == ("onion", "dish", "cook", "idle", "random") and pop.num_others == 1
    env = make("overcooked", partners="heuristic")
    rollout = make_random_rollout(env, num_envs=1024, num_steps=8)  # as tests/test_envs.py
    _, a = rollout(jax.random.key(7))
    _, b = rollout(jax.random.key(7))
    _, c = rollout(jax.random.key(8))
    assert a.obs.shape == (8, 1024, 520) and a.reward.shape == (8, 1024)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert not np.array_equal(np.asarray(a.obs), np.asarray(c.obs))
    assert set(np.unique(np.asarray(a.record.partner))) == set(range(5))
    acts = np.asarray(a.record.other_actions)
    assert acts.min() >= 0 and acts.max() <= 5 and (acts == STAY).any()


def test_path_table_reaches_every_target_around_the_other_cook() -> None:
    floor = np.flatnonzero(FLOOR)
    assert floor.tolist() == [6, 7, 8, 11, 12, 13]

    def walk(pos: int, target: int, other: int) -> int:
        for steps in range(10):
            if pos == target:
                return steps
            dx, dy = MOVE_VEC[int(NEXT_NP[pos, target, other])]
            pos = pos + dy * 5 + dx
            assert FLOOR[pos] and pos != other
        raise AssertionError("no arrival")

    for pos in floor:
        for target in floor:
            assert walk(pos, target, other=0) == DIST_NP[pos, target]  # other off the floor
            for other in set(floor) - {pos, target}:
                walk(pos, target, other)
        # Target taken by the other cook: step toward it anyway (moves once it leaves).
        for other in set(floor) - {pos}:
            move = int(NEXT_NP[pos, other, other])
            dx, dy = MOVE_VEC[move]
            assert DIST_NP[pos + dy * 5 + dx, other] == DIST_NP[pos, other] - 1


def test_deprecation_warning_silenced() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        OvercookedGame(Config())
