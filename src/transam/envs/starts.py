"""Given start states: play episodes that begin where another codebase's episodes began.

A paired comparison with another implementation (the authors' loop, say) is far less noisy on
the same episodes than on fresh draws: a set of 100 MPE episodes varies by about one reward
point in mean return from draw to draw (docs/results/parity). A *starts file* fixes each
episode's start and partner team, so our agent plays exactly the episodes another program
logged.

The file is an ``.npz`` for the MPE games (Spread, Tag), whose start is all positions with
velocities and communication at zero:

* ``positions`` [N, E, 2] float: every entity's position, in the game's entity order (agents
  by index, the controlled one included, then landmarks);
* ``team`` [N] int: the partner team of each episode, an index into the population's teams
  (``env.population.team_names``);
* ``group`` [N] int, optional: a label to report means by (e.g. which evaluation of the
  other program the episode belongs to).

Leading axes beyond the first are flattened (``positions`` [G, N, E, 2] with ``team`` [G, N]
is G·N episodes, and then ``group`` defaults to the leading index).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from transam.envs.core import ControlledEnv, EnvError

MPE_GAMES = ("spread", "tag")


@dataclass(frozen=True)
class Starts:
    """The episodes of a starts file: game states batched over episodes, and their teams."""

    game: Any  # the game's state pytree, leading axis N
    team: np.ndarray  # [N] int32
    group: np.ndarray  # [N] int64
    source: str

    @property
    def episodes(self) -> int:
        return len(self.team)


def load_starts(path: str | Path, env: ControlledEnv) -> Starts:
    """Read a starts file (module docstring) for ``env``; a clear :class:`EnvError` names a
    missing array, a wrong shape, or a team out of the population's range."""
    name = env.spec.name
    if name not in MPE_GAMES:
        raise EnvError(
            f"start files are for the MPE games ({', '.join(MPE_GAMES)}); env {name!r} has none"
        )
    path = Path(path)
    try:
        data = np.load(path)
    except (OSError, ValueError) as err:
        raise EnvError(f"cannot read starts file {str(path)!r}: {err}") from err
    missing = [k for k in ("positions", "team") if k not in data.files]
    if missing:
        raise EnvError(
            f"starts file {str(path)!r} lacks {', '.join(missing)} (has {', '.join(data.files)})"
        )
    positions, team = np.asarray(data["positions"]), np.asarray(data["team"])
    mpe = env.game.mpe  # type: ignore[attr-defined]
    entities = mpe.num_entities
    if positions.shape[-2:] != (entities, 2) or positions.shape[:-2] != team.shape:
        raise EnvError(
            f"starts file {str(path)!r}: positions must be [..., {entities}, 2] ({name}'s "
            f"{mpe.num_agents} agents then {entities - mpe.num_agents} landmarks) and team "
            f"the same leading shape; got positions {positions.shape}, team {team.shape}"
        )
    if "group" in data.files:
        group = np.asarray(data["group"]).reshape(-1)
    elif team.ndim > 1:
        group = np.repeat(np.arange(team.shape[0]), team[0].size)
    else:
        group = np.zeros(team.size, np.int64)
    team = team.reshape(-1)
    m = env.num_partners
    if not np.issubdtype(team.dtype, np.integer) or team.min() < 0 or team.max() >= m:
        raise EnvError(
            f"starts file {str(path)!r}: team must be integers in [0, {m}) "
            f"({', '.join(env.population.team_names)}); got {team.min()}..{team.max()} "
            f"({team.dtype})"
        )
    if len(group) != len(team):
        raise EnvError(
            f"starts file {str(path)!r}: group has {len(group)} entries, team {len(team)}"
        )
    p_pos = jnp.asarray(positions.reshape(-1, entities, 2), jnp.float32)
    fresh = env.game.reset(jax.random.key(0))  # velocities, communication and clock at zero
    game = jax.vmap(lambda p: fresh.replace(p_pos=p))(p_pos)
    return Starts(game=game, team=team.astype(np.int32), group=group, source=str(path))
