"""Episodes from given start states (:mod:`transam.envs.starts`): the paired comparison with
another codebase's own evaluation episodes (docs/results/parity)."""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np
import pytest

from transam.compose import make_env
from transam.envs.core import ControlledEnv, EnvError
from transam.envs.rollout import make_random_rollout
from transam.envs.starts import load_starts


def reset_states(env: ControlledEnv, key: jax.Array, n: int) -> object:
    """The first episodes' states of ``make_random_rollout(env, n, ...)(key)``."""
    key_reset, _ = jax.random.split(key)
    return jax.vmap(env.reset)(jax.random.split(key_reset, n))[0]


@pytest.mark.parametrize("name", ["spread", "tag"])
def test_a_rollout_from_its_own_start_positions_is_the_same_rollout(
    name: str, tmp_path: Path
) -> None:
    env = make_env(name)
    n, key = 8, jax.random.key(3)
    states = reset_states(env, key, n)
    path = tmp_path / "starts.npz"
    positions = np.asarray(states.game.p_pos)  # type: ignore[attr-defined]
    team = np.asarray(states.partner)  # type: ignore[attr-defined]
    np.savez(path, positions=positions, team=team)
    steps = 2 * env.spec.episode_len  # the second episodes start from fresh resets
    _, ours = make_random_rollout(env, n, steps)(key)
    _, given = make_random_rollout(env, n, steps, starts=load_starts(path, env))(key)
    for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(given), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # Other positions, other episodes: the starts are used, not the key's resets.
    np.savez(path, positions=positions[::-1], team=team)
    _, moved = make_random_rollout(env, n, steps, starts=load_starts(path, env))(key)
    assert not np.array_equal(np.asarray(moved.reward), np.asarray(ours.reward))


def test_groups_come_from_leading_axes_or_the_file(tmp_path: Path) -> None:
    env = make_env("spread")
    positions = np.zeros((2, 3, 6, 2), np.float32)
    team = np.arange(6).reshape(2, 3)
    np.savez(tmp_path / "a.npz", positions=positions, team=team)
    st = load_starts(tmp_path / "a.npz", env)
    assert st.episodes == 6 and st.group.tolist() == [0, 0, 0, 1, 1, 1]
    assert st.team.tolist() == list(range(6))
    np.savez(tmp_path / "b.npz", positions=positions[0], team=team[0], group=[5, 5, 7])
    assert load_starts(tmp_path / "b.npz", env).group.tolist() == [5, 5, 7]


def test_bad_starts_files_name_what_is_wrong(tmp_path: Path) -> None:
    env = make_env("spread")
    path = tmp_path / "s.npz"
    np.savez(path, positions=np.zeros((4, 5, 2)), team=np.zeros(4, int))
    with pytest.raises(EnvError, match=r"positions must be \[\.\.\., 6, 2\].*got positions"):
        load_starts(path, env)
    np.savez(path, positions=np.zeros((4, 6, 2)), team=np.full(4, env.num_partners))
    with pytest.raises(EnvError, match=rf"team must be integers in \[0, {env.num_partners}\)"):
        load_starts(path, env)
    np.savez(path, positions=np.zeros((4, 6, 2)))
    with pytest.raises(EnvError, match=r"lacks team \(has positions\)"):
        load_starts(path, env)
    with pytest.raises(EnvError, match=r"cannot read starts file"):
        load_starts(tmp_path / "missing.npz", env)
    with pytest.raises(EnvError, match=r"MPE games \(spread, tag\); env 'lbf' has none"):
        load_starts(path, make_env("lbf"))
