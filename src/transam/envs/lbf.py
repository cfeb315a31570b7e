"""LBF: level-based foraging, 20x20 grid, 2 agents, 4 foods, with one controlled agent.

Source: the rules of lbforaging 2.0.0 (``ForagingEnv``, the package the TransAM/LIAM LBF is
built on), reimplemented compactly in JAX. Why not jumanji 1.1.2's ``LevelBasedForaging``: its
rules differ from lbforaging's in ways that matter here (an agent may not step into a cell that
another agent is leaving, so following and swapping are impossible; one agent may help load two
foods in one step; foods sit in fixed observation slots; foods spawn before agents, with
different spacing, and agents never spawn in rows equal to a food coordinate). Using it would
take a custom generator, an observation adapter and still leave those differences; the whole
lbforaging rule set is about as much code as those adapters.

* Grid ``grid_size`` x ``grid_size`` (20). Agent 0 is the controlled agent, agent 1 the partner
  (``other_obs`` row 0 is agent 1's observation).
* Reset (lbforaging order): agents first, each uniform over the free cells, level
  ~ U{1..max_agent_level} (2); then foods one by one, each uniform over the cells that are not
  on the border, not occupied, with no food in the 3x3 neighbourhood and none within distance 2
  along the same row or column (the distribution of lbforaging's rejection sampling, drawn
  directly from the valid cells instead of by up to 1000 tries; modulo bias < 1e-7). Food level
  ~ U{1..L} with L = the sum of the (up to 3) lowest agent levels; ``force_coop`` sets every
  food to L. A food that finds no valid cell (only possible on tiny grids) is simply absent.
  The spacing means an agent is never next to two foods in a spawned episode.
* Actions: 0 none, 1 north (row-1), 2 south (row+1), 3 west (col-1), 4 east (col+1), 5 load.
  Invalid actions (off the grid, into a food, load with no 4-adjacent food) become none.
* Movement (lbforaging): each agent claims its target cell (staying or loading agents claim
  their own cell); an agent moves only if no other agent claims the same cell. So an agent
  cannot enter a cell whose occupant stays, can follow an agent that leaves, and two agents can
  swap. (With 2 agents this never puts two agents on one cell.)
* Loading (lbforaging): loading agents are taken in agent-index order (lbforaging pops them from
  a set, in no defined order); each not-yet-pooled one picks its first adjacent food in the
  order north, south, west, east, and pools with every not-yet-pooled loading agent adjacent to
  that food. The food is collected iff the pool's summed level >= the food level; then each pool
  member gets ``level_i * food_level / (pool level * total food level spawned this episode)``,
  so a solo collector gets ``food_level / total`` and both agents' rewards of an episode sum to
  <= 1 (the paper's "exceeds" is lbforaging's >=; its 1/10 vs 9/10 example needs an agent of
  level 4, beyond the default levels 1-2, and is reproduced in the tests on a constructed
  state). A failed pool gets ``-penalty`` each (lbforaging's ``penalty``, default 0).
* Termination: all food collected (``terminal``). The 50-step time limit (``episode_len``) is
  the :class:`ControlledEnv` clock (a truncation).
* Observation (lbforaging's vector observation, float32, 3*num_foods + 6 = 18 dims; the same
  layout for both agents, from the observer's point of view): ``num_foods`` food slots
  (row, col, level) holding the visible uneaten foods packed in row-major order of position,
  unused slots (-1, -1, 0); then self (row, col, level); then the other agent (row, col, level),
  or (-1, -1, 0) when not visible. Coordinates are lbforaging's window coordinates
  ``pos - own + min(sight, own)``: with the default full view (``sight=None``, or any sight >=
  grid_size - 1) these are absolute grid coordinates. With a smaller sight a food is visible
  inside the (2*sight+1)^2 window and the other agent when its window coordinates lie in
  [0, 2*sight] (lbforaging's quirk, kept).
* ``relative_obs`` (off by default, not in lbforaging): the *controlled* agent's observation
  gives each visible food's and the other agent's (row, col) as offsets from its own position
  (entity minus self), unused and unseen slots (0, 0, 0); its own (row, col) stays as above,
  and the slots keep their order. The partners' observations (``other_obs``, what the learned
  partners act on and agent models reconstruct) stay lbforaging's. An issue-36 diagnostic:
  "the nearest food I can load" is then a lookup rather than a subtraction the policy learns.
* Partners: the shipped learned population by default (:func:`transam.make_env`); the
  heuristic one of :mod:`transam.partners.lbf` with ``partners="heuristic"``.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
from flax import struct

from transam.envs.core import ControlledEnv, EnvError, GameSpec
from transam.envs.joint import JointView
from transam.envs.population import Population

NUM_AGENTS = 2
CONTROLLED = 0  # the controlled agent's index; the partner is agent 1

NONE, NORTH, SOUTH, WEST, EAST, LOAD = range(6)
ACTION_NAMES = ("none", "north", "south", "west", "east", "load")
# (d_row, d_col) of each action; none and load stay in place.
MOVES = jnp.array([[0, 0], [-1, 0], [1, 0], [0, -1], [0, 1], [0, 0]], jnp.int32)
# Order in which a loading agent looks for its food: north, south, west, east.
LOAD_ORDER = MOVES[1:5]


@dataclass(frozen=True)
class Config:
    """LBF options (defaults: the paper's 20x20, 2 agents, 4 foods, levels 1-2, 50 steps)."""

    grid_size: int = 20  # side of the square grid
    num_foods: int = 4  # foods spawned per episode (= food slots in the observation)
    max_agent_level: int = 2  # agent levels ~ U{1..max_agent_level}
    sight: int | None = None  # view radius; None = whole grid (absolute coordinates)
    force_coop: bool = False  # every food at the maximum level (needs both agents)
    penalty: float = 0.0  # reward subtracted from each agent of a failed load
    episode_len: int = 50  # time limit in steps (a truncation, counted by ControlledEnv)
    relative_obs: bool = False  # the controlled agent sees foods and partner relative to itself

    def __post_init__(self) -> None:
        if self.grid_size < 3:
            raise EnvError(
                f"lbf grid_size must be >= 3 (foods avoid the border); got {self.grid_size!r}"
            )
        for name in ("num_foods", "max_agent_level", "episode_len"):
            if getattr(self, name) < 1:
                raise EnvError(f"lbf {name} must be >= 1; got {getattr(self, name)!r}")
        if self.sight is not None and self.sight < 1:
            raise EnvError(f"lbf sight must be >= 1 or None (whole grid); got {self.sight!r}")

    @property
    def view(self) -> int:
        """The effective sight radius (the whole grid when ``sight`` is None)."""
        return self.grid_size if self.sight is None else self.sight

    @property
    def full_view(self) -> bool:
        """Every agent sees the whole grid, in absolute coordinates."""
        return self.view >= self.grid_size - 1

    @property
    def obs_dim(self) -> int:
        return 3 * self.num_foods + 3 * NUM_AGENTS


@struct.dataclass
class State:
    """Positions are (row, col) int32; a food level of 0 means eaten (or never spawned)."""

    agent_pos: jax.Array  # [NUM_AGENTS, 2]
    agent_level: jax.Array  # [NUM_AGENTS]
    food_pos: jax.Array  # [num_foods, 2]
    food_level: jax.Array  # [num_foods]
    total_food: jax.Array  # float32: summed level of the foods spawned this episode


def make_state(
    agent_pos: jax.Array, agent_level: jax.Array, food_pos: jax.Array, food_level: jax.Array
) -> State:
    """A state with the given positions and levels (for tests and scripted scenarios)."""
    food_level = jnp.asarray(food_level, jnp.int32)
    return State(
        agent_pos=jnp.asarray(agent_pos, jnp.int32),
        agent_level=jnp.asarray(agent_level, jnp.int32),
        food_pos=jnp.asarray(food_pos, jnp.int32),
        food_level=food_level,
        total_food=jnp.sum(food_level).astype(jnp.float32),
    )


def _uniform(draw: jax.Array, count: jax.Array) -> jax.Array:
    """An integer in [0, count) from a raw 32-bit draw (modulo bias < count / 2**32)."""
    return (draw % jnp.maximum(count, 1).astype(jnp.uint32)).astype(jnp.int32)


def _sample_cell(draw: jax.Array, allowed: jax.Array) -> tuple[jax.Array, jax.Array]:
    """A uniform cell (row, col) among ``allowed`` [n, n], and whether there was one.

    The draw picks the k-th allowed cell in row-major order: first its row from the running
    row counts, then its column (two short cumsums; one over all n*n cells is slow on CPU).
    """
    per_row = jnp.sum(allowed, axis=1)
    upto = jnp.cumsum(per_row)
    k = _uniform(draw, upto[-1])
    row = jnp.argmax(upto > k)
    in_row = jnp.sum(jnp.where(jnp.arange(allowed.shape[0])[:, None] == row, allowed, False), 0)
    col = jnp.argmax(jnp.cumsum(in_row) > k - (upto[row] - per_row[row]))
    return jnp.stack([row, col]).astype(jnp.int32), upto[-1] > 0


def spawn(key: jax.Array, config: Config) -> State:
    """lbforaging's reset: agents, then spaced-out foods (see the module docstring).

    All randomness comes from one call for 32-bit draws (cheap to compile and to run).
    """
    n, num_foods = config.grid_size, config.num_foods
    rows, cols = jnp.meshgrid(jnp.arange(n), jnp.arange(n), indexing="ij")
    draws = jax.random.bits(key, (2, NUM_AGENTS + num_foods), jnp.uint32)
    cell_draws, level_draws = draws[0], draws[1]

    def place_agent(taken: jax.Array, draw: jax.Array) -> tuple[jax.Array, jax.Array]:
        pos, _ = _sample_cell(draw, ~taken)
        return taken | ((rows == pos[0]) & (cols == pos[1])), pos

    taken, agent_pos = jax.lax.scan(place_agent, jnp.zeros((n, n), bool), cell_draws[:NUM_AGENTS])
    agent_level = 1 + _uniform(level_draws[:NUM_AGENTS], jnp.int32(config.max_agent_level))
    max_food = jnp.sum(jnp.sort(agent_level)[:3])

    interior = (rows >= 1) & (rows <= n - 2) & (cols >= 1) & (cols <= n - 2)

    def place_food(
        carry: tuple[jax.Array, jax.Array], draw: jax.Array
    ) -> tuple[tuple[jax.Array, jax.Array], tuple[jax.Array, jax.Array]]:
        taken, crowded = carry  # crowded: too close to a food already placed
        pos, ok = _sample_cell(draw, interior & ~taken & ~crowded)
        dr, dc = jnp.abs(rows - pos[0]), jnp.abs(cols - pos[1])
        near = ((dr <= 1) & (dc <= 1)) | ((dr == 0) & (dc <= 2)) | ((dc == 0) & (dr <= 2))
        taken = taken | ((rows == pos[0]) & (cols == pos[1]) & ok)
        return (taken, crowded | (near & ok)), (pos, ok)

    _, (food_pos, placed) = jax.lax.scan(
        place_food, (taken, jnp.zeros((n, n), bool)), cell_draws[NUM_AGENTS:]
    )
    food_level = 1 + _uniform(level_draws[NUM_AGENTS:], max_food)
    if config.force_coop:
        food_level = jnp.full((num_foods,), max_food)
    return make_state(agent_pos, agent_level, food_pos, jnp.where(placed, food_level, 0))


def valid_actions(state: State, grid_size: int) -> jax.Array:
    """[NUM_AGENTS, 6] bool: lbforaging's valid actions of each agent in ``state``."""
    alive = state.food_level > 0
    target = state.agent_pos[:, None, :] + MOVES[None]  # [A, 6, 2]
    in_grid = jnp.all((target >= 0) & (target < grid_size), axis=-1)
    on_food = jnp.any(
        jnp.all(target[:, :, None, :] == state.food_pos[None, None], axis=-1) & alive, axis=-1
    )
    dist = jnp.sum(jnp.abs(state.agent_pos[:, None, :] - state.food_pos[None]), axis=-1)
    can_load = jnp.any((dist == 1) & alive, axis=-1)
    valid = in_grid & ~on_food
    return valid.at[:, NONE].set(True).at[:, LOAD].set(can_load)


def step_state(
    state: State, actions: jax.Array, config: Config
) -> tuple[State, jax.Array, jax.Array]:
    """One lbforaging step for all agents: (next state, rewards [NUM_AGENTS], all food gone)."""
    actions = jnp.asarray(actions, jnp.int32)
    valid = jnp.take_along_axis(valid_actions(state, config.grid_size), actions[:, None], 1)
    actions = jnp.where(valid[:, 0], actions, NONE)

    # Moves: an agent moves unless another agent claims the same target cell.
    target = state.agent_pos + MOVES[actions]
    same = jnp.all(target[:, None, :] == target[None, :, :], axis=-1)
    clash = jnp.any(same & ~jnp.eye(NUM_AGENTS, dtype=bool), axis=1)
    pos = jnp.where(clash[:, None], state.agent_pos, target)

    # Loads, pooled per food, agents taken in index order.
    level = state.agent_level
    food_level = state.food_level
    unpooled = actions == LOAD
    rewards = jnp.zeros(NUM_AGENTS, jnp.float32)
    for i in range(NUM_AGENTS):
        alive = food_level > 0
        offset = state.food_pos[None, :, :] - pos[i][None, None, :]  # [1, F, 2]
        hit = jnp.all(offset == LOAD_ORDER[:, None, :], axis=-1) & alive  # [4, F]
        has_food = jnp.any(hit) & unpooled[i]
        food = jnp.argmax(hit[jnp.argmax(jnp.any(hit, axis=1))])  # first direction's food
        dist = jnp.sum(jnp.abs(pos - state.food_pos[food]), axis=-1)
        pool = unpooled & (dist == 1) & has_food
        pool_level = jnp.sum(jnp.where(pool, level, 0))
        fl = food_level[food]
        loaded = has_food & (pool_level >= fl)
        share = level * fl / jnp.maximum(pool_level * state.total_food, 1e-8)
        rewards += jnp.where(pool, jnp.where(loaded, share, -config.penalty), 0.0)
        food_level = food_level.at[food].set(jnp.where(loaded, 0, fl))
        unpooled = unpooled & ~pool

    next_state = State(pos, state.agent_level, state.food_pos, food_level, state.total_food)
    return next_state, rewards.astype(jnp.float32), jnp.all(food_level == 0)


def observe_agent(state: State, i: int, config: Config) -> jax.Array:
    """Agent ``i``'s lbforaging vector observation (layout in the module docstring)."""
    s, n = config.view, config.grid_size
    own = state.agent_pos[i]
    origin = own - jnp.minimum(s, own)  # window coordinates = pos - origin

    alive = state.food_level > 0
    seen = alive & jnp.all(jnp.abs(state.food_pos - own) <= s, axis=-1)
    order = jnp.argsort(jnp.where(seen, state.food_pos[:, 0] * n + state.food_pos[:, 1], n * n))
    foods = jnp.concatenate([state.food_pos - origin, state.food_level[:, None]], axis=-1)
    foods = jnp.where(seen[:, None], foods, jnp.array([-1, -1, 0]))[order]

    players = []
    for j in [i] + [j for j in range(NUM_AGENTS) if j != i]:
        rel = state.agent_pos[j] - origin
        visible = jnp.all((rel >= 0) & (rel <= 2 * s))
        row = jnp.concatenate([rel, state.agent_level[j][None]])
        players.append(jnp.where(visible, row, jnp.array([-1, -1, 0])))
    return jnp.concatenate([foods.ravel(), *players]).astype(jnp.float32)


def relative_view(obs: jax.Array, num_foods: int) -> jax.Array:
    """An observation (layout above) with foods and the other agent as offsets from self;
    slots of level 0 (unused, unseen) become (0, 0, 0). See ``Config.relative_obs``."""
    foods, players = split_obs(obs, num_foods)
    me = players[0, :2]
    rows = jnp.concatenate([foods, players[1:]])
    rel = jnp.where(rows[:, 2:] > 0, jnp.concatenate([rows[:, :2] - me, rows[:, 2:]], -1), 0.0)
    return jnp.concatenate([rel[:num_foods].ravel(), players[0], rel[num_foods:].ravel()])


def split_obs(obs: jax.Array, num_foods: int) -> tuple[jax.Array, jax.Array]:
    """(foods [num_foods, 3], players [NUM_AGENTS, 3], self first) rows of (row, col, level)."""
    return obs[: 3 * num_foods].reshape(num_foods, 3), obs[3 * num_foods :].reshape(-1, 3)


class LBFGame:
    """Level-based foraging seen from agent 0 (rules in the module docstring)."""

    def __init__(self, config: Config) -> None:
        self.config = config
        self.spec = GameSpec(
            name="lbf",
            obs_dim=config.obs_dim,
            num_actions=len(ACTION_NAMES),
            num_others=NUM_AGENTS - 1,
            other_obs_dim=config.obs_dim,
            other_num_actions=len(ACTION_NAMES),
            episode_len=config.episode_len,
            action_names=ACTION_NAMES,
            description=(
                f"level-based foraging (lbforaging 2.0.0 rules), {config.grid_size}x"
                f"{config.grid_size}, 2 agents, {config.num_foods} foods, controlled agent 0"
            ),
        )

    def reset(self, key: jax.Array) -> State:
        return spawn(key, self.config)

    def observe(self, state: State) -> tuple[jax.Array, jax.Array]:
        obs = [observe_agent(state, i, self.config) for i in range(NUM_AGENTS)]
        mine = obs[CONTROLLED]
        if self.config.relative_obs:
            mine = relative_view(mine, self.config.num_foods)
        return mine, jnp.stack([o for i, o in enumerate(obs) if i != CONTROLLED])

    def transition(
        self, key: jax.Array, state: State, action: jax.Array, other_actions: jax.Array
    ) -> tuple[State, jax.Array, jax.Array]:
        del key  # the dynamics are deterministic
        others = jnp.asarray(other_actions, jnp.int32)
        mine = jnp.asarray(action, jnp.int32)[None]
        joint = jnp.concatenate([others[:CONTROLLED], mine, others[CONTROLLED:]])
        next_state, rewards, terminal = step_state(state, joint, self.config)
        return next_state, rewards[CONTROLLED], terminal


def joint_view(config: Config) -> JointView:
    """Both agents as learners (self-play): agent 0 stands in for the controlled agent, and
    each agent is trained on, and scored by, its own share of the collected food."""

    def observe(state: State) -> jax.Array:
        return jnp.stack([observe_agent(state, i, config) for i in range(NUM_AGENTS)])

    def step(
        key: jax.Array, state: State, actions: jax.Array, weights: jax.Array
    ) -> tuple[State, jax.Array, jax.Array, jax.Array]:
        del key, weights
        nxt, rewards, terminal = step_state(state, actions, config)
        return nxt, rewards, rewards, terminal

    return JointView(
        name="lbf",
        num_agents=NUM_AGENTS,
        obs_dim=config.obs_dim,
        num_actions=len(ACTION_NAMES),
        episode_len=config.episode_len,
        reset=lambda key: spawn(key, config),
        observe=observe,
        step=step,
        partner_slots=tuple(i for i in range(NUM_AGENTS) if i != CONTROLLED),
        controlled=CONTROLLED,
    )


def make_env(config: Config, population: Population) -> ControlledEnv:
    """LBF with ``config`` and ``population``; :func:`transam.make_env` builds the
    population from a ``partners`` choice (default: the shipped learned one)."""
    return ControlledEnv(LBFGame(config), population)
