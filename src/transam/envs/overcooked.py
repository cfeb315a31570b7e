"""Overcooked, cramped room: JaxMARL 0.2.0's v1 ``Overcooked`` seen by one controlled cook.

Source: ``jaxmarl.environments.overcooked.Overcooked`` (v1) with layout ``cramped_room``,
wrapped, not copied: ``reset``, ``step_env`` and ``get_obs`` are JaxMARL's. Its rules are the
"old" automatic-cook dynamics the TransAM paper describes: the third onion put into the pot
starts a 20-step cook by itself, a plated soup on the serving cell gives +20 to BOTH agents,
and an episode lasts 400 steps. The kitchen is 4 rows x 5 columns; the cooks start at (x=1, y=1)
(agent_0) and (x=3, y=1) (agent_1); onion piles at (0,1) and (4,1), pot at (2,0), plate pile
at (1,3), serving cell at (3,3).

Choices where the spec leaves one open (all configurable in :class:`Config`):

* Controlled agent = JaxMARL ``agent_0`` (starts left, its interactions resolve first within a
  step); the single partner slot = ``agent_1``. ``controlled_slot=1`` swaps them.
* Observation: JaxMARL's 26-channel grid of the agent's own view (own layers first), which
  is (H, W, C) = (4, 5, 26) although JaxMARL declares (5, 4, 26); flattened row-major to a
  520-vector of float32 with the raw values (0/1 masks, onion counts up to 3, cook timer 19..1,
  urgency layer in the last 40 steps). The partner sees its own view the same way.
* Actions (6): 0 up, 1 down, 2 right, 3 left, 4 stay, 5 interact. A move into a blocked cell
  only turns the cook; interact acts on the faced cell.
* Start orientations are random (JaxMARL's behaviour, drawn from the reset key);
  ``random_start_dir=False`` makes both face north, as overcooked-ai does. Start positions are
  fixed (``random_reset=False``).
* Cook timing: if the third onion goes in during transition t (state s_t -> s_{t+1}), the pot
  shows 19 steps left in s_{t+1} and is ready in s_{t+20}: 20 transitions, counting the one that
  filled it.
* Reward of the controlled agent: the sparse team reward only (20 per delivered soup). The
  game never terminates early; the 400-step limit is the wrapper's time limit.
* Shaped rewards (:func:`shaped_rewards`) are computed here from (state, joint action, next
  state), per agent, for training partners only: onion into a pot that is not yet full (3),
  plate taken from the plate pile while useful (3: some pot is non-empty, no loose plate lies
  on a counter, and the cooks hold fewer plates than there are non-empty pots, all judged on
  the state before the step, as overcooked-ai judges pot states), soup taken from a ready pot
  (5). JaxMARL's own ``info["shaped_reward"]`` is not used: in 0.2.0 it agrees except when
  agent_0 puts the first onion in during the same step agent_1 takes a plate (JaxMARL pays
  that plate, having already applied agent_0's onion).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np
from flax.core.frozen_dict import FrozenDict

from transam._quiet import jaxmarl_modules
from transam.envs.core import ControlledEnv, EnvError, GameSpec

with jaxmarl_modules():
    from jaxmarl.environments.overcooked import Overcooked, overcooked_layouts
    from jaxmarl.environments.overcooked.common import OBJECT_TO_INDEX
    from jaxmarl.environments.overcooked.overcooked import State

from transam.envs.joint import JointView

if TYPE_CHECKING:
    from transam.envs.population import Population

LAYOUT = "cramped_room"
HEIGHT, WIDTH, CHANNELS = 4, 5, 26
OBS_DIM = HEIGHT * WIDTH * CHANNELS  # 520
ACTION_NAMES = ("up", "down", "right", "left", "stay", "interact")
UP, DOWN, RIGHT, LEFT, STAY, INTERACT = range(6)
DELIVERY_REWARD = 20.0  # JaxMARL's fixed per-soup team reward

# JaxMARL object codes (inventory and the maze map's object channel).
EMPTY = OBJECT_TO_INDEX["empty"]
ONION = OBJECT_TO_INDEX["onion"]
PLATE = OBJECT_TO_INDEX["plate"]
DISH = OBJECT_TO_INDEX["dish"]  # a plated soup
POT_EMPTY, POT_FULL, POT_READY = 23, 20, 0  # pot status: 23-n = n onions, 19..1 cooking, 0 ready

# Observation channels used by the heuristics (JaxMARL get_obs docstring).
CH_SELF, CH_OTHER, CH_SELF_DIR = 0, 1, 2  # CH_SELF_DIR..+3: own orientation N, S, E, W
CH_POT_ONIONS, CH_SOUP_ONIONS, CH_COOK_TIME, CH_SOUP_READY = 16, 18, 20, 21
CH_PLATE, CH_ONION = 22, 23


def _cell_indices(key: str) -> tuple[int, ...]:
    return tuple(int(i) for i in np.asarray(overcooked_layouts[LAYOUT][key]))


POT_CELLS = _cell_indices("pot_idx")  # flat index y * WIDTH + x
PLATE_PILE_CELLS = _cell_indices("plate_pile_idx")
ONION_PILE_CELLS = _cell_indices("onion_pile_idx")
GOAL_CELLS = _cell_indices("goal_idx")
WALL_CELLS = _cell_indices("wall_idx")  # every non-floor cell (counters, piles, pot, goal)


@dataclass(frozen=True)
class Config:
    """Overcooked cramped-room settings (defaults follow spec section 8)."""

    episode_len: int = 400  # steps per episode (JaxMARL max_steps; the paper's horizon)
    controlled_slot: int = 0  # JaxMARL agent index of the controlled cook; the partner is the other
    random_start_dir: bool = True  # random start orientations as JaxMARL; False: both face north
    random_reset: bool = False  # JaxMARL random_reset: random positions, items and pot at start
    onion_in_pot_reward: float = 3.0  # shaped reward (partners only): onion into a non-full pot
    plate_pickup_reward: float = 3.0  # shaped reward (partners only): useful plate from the pile
    soup_pickup_reward: float = 5.0  # shaped reward (partners only): soup from a ready pot


def _padding(state: State) -> int:
    """Border width JaxMARL adds around the maze map (static)."""
    return (state.maze_map.shape[0] - HEIGHT) // 2


def object_grid(state: State) -> jax.Array:
    """[H, W] object codes of the kitchen (agent cells show the agent, not what it holds)."""
    p = _padding(state)
    return state.maze_map[p : p + HEIGHT, p : p + WIDTH, 0]


def pot_status(state: State) -> jax.Array:
    """[num_pots] pot status (23 empty, 22/21 one/two onions, 19..1 cooking, 0 ready)."""
    p = _padding(state)
    ys = jnp.asarray([c // WIDTH for c in POT_CELLS])
    xs = jnp.asarray([c % WIDTH for c in POT_CELLS])
    return state.maze_map[p + ys, p + xs, 2].astype(jnp.int32)


def faced_cell(state: State) -> jax.Array:
    """[2] flat index of the cell each agent faces (what interact acts on)."""
    front = state.agent_pos.astype(jnp.int32) + state.agent_dir.astype(jnp.int32)
    x = jnp.clip(front[:, 0], 0, WIDTH - 1)
    y = jnp.clip(front[:, 1], 0, HEIGHT - 1)
    return y * WIDTH + x


def shaped_events(state: State, actions: jax.Array, next_state: State) -> jax.Array:
    """[2, 3] bool per agent: (onion into pot, useful plate from pile, soup from pot).

    Read off each agent's inventory change and the cell it faced before the step, so the
    events are exact whatever order JaxMARL resolves the two interactions in. "Useful" is the
    overcooked-ai rule, judged on the state before the step: some pot is non-empty, no loose
    plate lies on a counter, and the cooks hold fewer plates than there are non-empty pots.
    """
    inv, new_inv = state.agent_inv, next_state.agent_inv
    front = faced_cell(state)
    interact = jnp.asarray(actions) == INTERACT

    def facing(cells: tuple[int, ...]) -> jax.Array:
        return jnp.isin(front, jnp.asarray(cells))

    onion_in_pot = interact & facing(POT_CELLS) & (inv == ONION) & (new_inv == EMPTY)
    soup_pickup = interact & facing(POT_CELLS) & (inv == PLATE) & (new_inv == DISH)
    from_pile = interact & facing(PLATE_PILE_CELLS) & (inv == EMPTY) & (new_inv == PLATE)
    non_empty_pots = jnp.sum(pot_status(state) != POT_EMPTY)
    plates_held = jnp.sum(inv == PLATE)
    no_loose_plates = ~jnp.any(object_grid(state) == PLATE)
    useful = no_loose_plates & (plates_held < non_empty_pots)
    return jnp.stack([onion_in_pot, from_pile & useful, soup_pickup], axis=1)


def shaped_rewards(
    state: State,
    actions: jax.Array,
    next_state: State,
    weights: tuple[float, float, float] = (3.0, 3.0, 5.0),
) -> jax.Array:
    """[2] float32 shaped reward per agent (onion in pot, useful plate pickup, soup pickup)."""
    events = shaped_events(state, actions, next_state).astype(jnp.float32)
    return events @ jnp.asarray(weights, jnp.float32)


class OvercookedGame:
    """JaxMARL v1 Overcooked (cramped room) as a controlled-agent :class:`Game`."""

    def __init__(self, config: Config) -> None:
        if config.controlled_slot not in (0, 1):
            raise EnvError(f"controlled_slot must be 0 or 1; got {config.controlled_slot!r}")
        if config.episode_len < 1:
            raise EnvError(f"episode_len must be >= 1; got {config.episode_len!r}")
        self.config = config
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            self.env = Overcooked(
                FrozenDict(overcooked_layouts[LAYOUT]),
                random_reset=config.random_reset,
                max_steps=config.episode_len,
            )
        self.slot = config.controlled_slot
        self.weights = (
            config.onion_in_pot_reward,
            config.plate_pickup_reward,
            config.soup_pickup_reward,
        )
        self.spec = GameSpec(
            name="overcooked",
            obs_dim=OBS_DIM,
            num_actions=len(ACTION_NAMES),
            num_others=1,
            other_obs_dim=OBS_DIM,
            other_num_actions=len(ACTION_NAMES),
            episode_len=config.episode_len,
            action_names=ACTION_NAMES,
            description="JaxMARL v1 Overcooked, cramped room, 20-step auto cook, 20 per soup",
        )

    def reset(self, key: jax.Array) -> State:
        _, state = self.env.reset(key)
        if not self.config.random_start_dir:
            state = _face_north(state)
        return state

    def joint_observe(self, state: State) -> jax.Array:
        """[2, 520] float32 observations of agent_0 and agent_1 (each its own view)."""
        obs = self.env.get_obs(state)
        return jnp.stack([obs["agent_0"], obs["agent_1"]]).reshape(2, -1).astype(jnp.float32)

    def observe(self, state: State) -> tuple[jax.Array, jax.Array]:
        obs = self.joint_observe(state)
        return obs[self.slot], obs[1 - self.slot][None]

    def joint_step(
        self, key: jax.Array, state: State, actions: jax.Array
    ) -> tuple[State, jax.Array, jax.Array]:
        """Both act ([2] int32, JaxMARL agent order) -> (next state, sparse [2], shaped [2])."""
        actions = jnp.asarray(actions, jnp.int32)
        _, next_state, rewards, _, _ = self.env.step_env(
            key, state, {"agent_0": actions[0], "agent_1": actions[1]}
        )
        sparse = jnp.stack([rewards["agent_0"], rewards["agent_1"]]).astype(jnp.float32)
        shaped = shaped_rewards(state, actions, next_state, self.weights)
        return next_state, sparse, shaped

    def joint_actions(self, action: jax.Array, other_actions: jax.Array) -> jax.Array:
        """[2] actions in JaxMARL agent order from (controlled, [partner])."""
        pair = [jnp.asarray(action, jnp.int32), jnp.asarray(other_actions, jnp.int32)[0]]
        return jnp.stack(pair if self.slot == 0 else pair[::-1])

    def transition(
        self, key: jax.Array, state: State, action: jax.Array, other_actions: jax.Array
    ) -> tuple[State, jax.Array, jax.Array]:
        next_state, sparse, _ = self.joint_step(
            key, state, self.joint_actions(action, other_actions)
        )
        return next_state, sparse[self.slot], jnp.zeros((), jnp.bool_)

    def joint_view(self) -> JointView:
        """Both cooks as learners (self-play): the controlled slot's cook is the stand-in.

        Learner i is JaxMARL ``agent_i``. Its training reward is the sparse team reward plus
        its own shaped events weighted by row i of the recipe's ``weights`` (onion into pot,
        useful plate pickup, soup pickup); the score is the sparse reward alone.
        """

        def step(
            key: jax.Array, state: State, actions: jax.Array, weights: jax.Array
        ) -> tuple[State, jax.Array, jax.Array, jax.Array]:
            nxt, sparse, _ = self.joint_step(key, state, actions)
            events = shaped_events(state, actions, nxt).astype(jnp.float32)
            shaped = jnp.sum(events * weights, axis=-1)
            return nxt, sparse + shaped, sparse, jnp.zeros((), jnp.bool_)

        return JointView(
            name="overcooked",
            num_agents=2,
            obs_dim=OBS_DIM,
            num_actions=len(ACTION_NAMES),
            episode_len=self.config.episode_len,
            reset=self.reset,
            observe=self.joint_observe,
            step=step,
            partner_slots=(1 - self.slot,),
            controlled=self.slot,
        )


def _face_north(state: State) -> State:
    """Both cooks face north (overcooked-ai's start), in the state and in the maze map."""
    north = jnp.zeros((2,), jnp.int32)
    p = _padding(state)
    xs, ys = state.agent_pos[:, 0], state.agent_pos[:, 1]
    maze_map = state.maze_map.at[p + ys, p + xs, 2].set(0)
    return dataclasses.replace(
        state,
        agent_dir_idx=north,
        agent_dir=jnp.asarray([[0, -1], [0, -1]], state.agent_dir.dtype),
        maze_map=maze_map,
    )


def make_env(config: Config, population: Population) -> ControlledEnv:
    """Overcooked with ``config`` and ``population``; :func:`transam.make_env` builds the
    population from a ``partners`` choice (default: the shipped learned one)."""
    return ControlledEnv(OvercookedGame(config), population)
