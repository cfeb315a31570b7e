"""Spread: MPE cooperative navigation (3 agents, 3 landmarks) with one controlled agent.

Two variants of the dynamics (``Config.dynamics``), both on JaxMARL 0.2.0's
:class:`~jaxmarl.environments.mpe.simple_spread.SimpleSpreadMPE` (its physics step, contact
forces and observations are used as they are):

* ``"authors"`` (default): the experiment that produced the paper's numbers. The TransAM
  authors ran the "on-policy" ``simple_spread.py`` on the particle-environment fork: landmarks
  spawn in **0.8**·U(-1, 1)^2 (agents in U(-1, 1)^2) and the integrator updates **velocity
  before position** (v <- 0.75 v + 0.1 F; p <- p + 0.1 v_new). Random play scores about -59
  per episode against the authors' population in their loop; the paper's TransAM -48.76.
* ``"mpe2"``: PettingZoo/mpe2 ``simple_spread_v3`` (landmarks in U(-1, 1)^2, position updated
  before velocity, as JaxMARL); a test checks every observation and reward against mpe2.

Common to both:

* Agents: radius 0.15, colliding (soft contact force 100, margin 1e-3), accel 5, no speed cap;
  landmarks: radius 0.05, not colliding. dt 0.1, damping 0.25. Velocities start at 0. No walls.
* Actions (all agents): Discrete(5) = 0 no-op, 1 -x, 2 +x, 3 -y, 4 +y (mpe2's numbering; the
  fork's 1 +x, 2 -x, 3 +y, 4 -y is converted where fork-trained policies are imported).
* Observation (18, every agent): [own vel (2), own pos (2), the 3 landmarks relative to self (6),
  the 2 other agents relative to self in index order (4), their communication (4, always 0)].
* Controlled agent: index 2 (as the TransAM authors' code); the partners are agents 0 and 1, and
  ``other_obs`` rows are their observations in that order.
* Episode: exactly ``episode_len`` = 25 transitions, counted by :class:`ControlledEnv` (JaxMARL's
  own ``done`` would come one step late and is ignored); there is no early termination.
* Reward (``Config.reward``):
  - ``"mpe"`` (default): the original MPE cooperative-navigation reward of the controlled agent
    (openai multiagent-particle-envs ``simple_spread.Scenario.reward``, as the authors ran it):
    minus the sum over landmarks of the distance to the closest agent, minus 1 for every agent
    within 0.3 (sum of radii) of the controlled agent, the controlled agent itself included as
    the openai code does (a constant -1 per step; ``self_collision=False`` drops it). It is the
    controlled agent's own reward, not openai's ``collaborative`` sum over the three agents.
  - ``"pettingzoo"``: mpe2 simple_spread_v3's reward, ``local_ratio * (-collisions with the other
    agents) + (1 - local_ratio) * (-sum of closest distances)`` with local_ratio 0.5 (JaxMARL's
    ``rewards``). With 0.5 it is exactly ``0.5 * (mpe + 1)`` per step.
* Precision: float32 here, float64 in mpe2; observations agree to about 3e-6 over 25 steps.
* Partners: :func:`transam.make_env` joins the game with a population (default: the shipped
  learned one); the heuristic one of :mod:`transam.partners.spread` with
  ``partners="heuristic"``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Literal

import jax
import jax.numpy as jnp

from transam._quiet import jaxmarl_modules
from transam.envs.core import MPE_ACTION_NAMES, ControlledEnv, EnvError, ForkIntegrator, GameSpec
from transam.envs.joint import JointView
from transam.envs.population import Population

with jaxmarl_modules():
    from jaxmarl.environments.mpe.simple import State
    from jaxmarl.environments.mpe.simple_spread import SimpleSpreadMPE

NUM_AGENTS = 3
NUM_LANDMARKS = 3
OBS_DIM = 18
CONTROLLED = 2  # the controlled agent's index; the partners are the others in index order

# Observation layout (every agent).
VEL, POS, LANDMARKS, OTHERS, COMM = (
    slice(0, 2),
    slice(2, 4),
    slice(4, 10),
    slice(10, 14),
    slice(14, 18),
)


DYNAMICS = ("authors", "mpe2")
AUTHORS_LANDMARK_RANGE = 0.8  # landmarks spawn in 0.8 * U(-1, 1)^2 in the authors' scenario


@dataclass(frozen=True)
class Config:
    """Spread options."""

    dynamics: Literal["authors", "mpe2"] = "authors"  # the authors' fork variant, or mpe2 v3's
    reward: Literal["mpe", "pettingzoo"] = "mpe"  # original MPE per-agent reward, or mpe2 v3's
    self_collision: bool = True  # "mpe" reward: the agent counts as colliding with itself (-1/step)
    local_ratio: float = 0.5  # "pettingzoo" reward: weight of the local collision term
    episode_len: int = 25  # transitions per episode (no early termination)

    def __post_init__(self) -> None:
        if self.dynamics not in DYNAMICS:
            raise EnvError(
                f"spread dynamics must be one of {', '.join(DYNAMICS)}; got {self.dynamics!r}"
            )
        if self.reward not in ("mpe", "pettingzoo"):
            raise EnvError(f"spread reward must be 'mpe' or 'pettingzoo'; got {self.reward!r}")
        if not 0.0 <= self.local_ratio <= 1.0:
            raise EnvError(f"spread local_ratio must be in [0, 1]; got {self.local_ratio!r}")
        if self.episode_len < 1:
            raise EnvError(f"spread episode_len must be >= 1; got {self.episode_len!r}")


class AuthorsSpreadMPE(ForkIntegrator, SimpleSpreadMPE):
    """JaxMARL's simple_spread with the authors' scenario: 0.8 landmark range, fork integrator."""

    @partial(jax.jit, static_argnums=[0])
    def reset(self, key: jax.Array) -> tuple[dict, State]:
        key_a, key_l = jax.random.split(key)
        p_pos = jnp.concatenate(
            [
                jax.random.uniform(key_a, (self.num_agents, 2), minval=-1.0, maxval=1.0),
                AUTHORS_LANDMARK_RANGE
                * jax.random.uniform(key_l, (self.num_landmarks, 2), minval=-1.0, maxval=1.0),
            ]
        )
        state = State(
            p_pos=p_pos,
            p_vel=jnp.zeros((self.num_entities, self.dim_p)),
            c=jnp.zeros((self.num_agents, self.dim_c)),
            done=jnp.array(False),
            step=jnp.array(0),
        )
        return self.get_obs(state), state


class SpreadGame:
    """Spread seen from agent 2; the state is JaxMARL's MPE ``State``."""

    def __init__(self, config: Config) -> None:
        self.config = config
        mpe_class = AuthorsSpreadMPE if config.dynamics == "authors" else SimpleSpreadMPE
        self.mpe = mpe_class(
            num_agents=NUM_AGENTS, num_landmarks=NUM_LANDMARKS, local_ratio=config.local_ratio
        )
        self.spec = GameSpec(
            name="spread",
            obs_dim=OBS_DIM,
            num_actions=5,
            num_others=NUM_AGENTS - 1,
            other_obs_dim=OBS_DIM,
            other_num_actions=5,
            episode_len=config.episode_len,
            action_names=MPE_ACTION_NAMES,
            description=(
                "MPE cooperative navigation ("
                + (
                    "the authors' variant: landmarks 0.8·U(-1,1)², velocity-first integration"
                    if config.dynamics == "authors"
                    else "mpe2 simple_spread_v3"
                )
                + "), controlled agent 2"
            ),
        )

    def reset(self, key: jax.Array) -> State:
        _, state = self.mpe.reset(key)
        return state

    def observe(self, state: State) -> tuple[jax.Array, jax.Array]:
        obs = self.mpe.get_obs(state)
        rows = [obs[a].astype(jnp.float32) for a in self.mpe.agents]
        others = jnp.stack([r for i, r in enumerate(rows) if i != CONTROLLED])
        return rows[CONTROLLED], others

    def transition(
        self, key: jax.Array, state: State, action: jax.Array, other_actions: jax.Array
    ) -> tuple[State, jax.Array, jax.Array]:
        others = jnp.asarray(other_actions, jnp.int32)
        mine = jnp.asarray(action, jnp.int32)[None]
        joint = jnp.concatenate([others[:CONTROLLED], mine, others[CONTROLLED:]])
        actions = {a: joint[i] for i, a in enumerate(self.mpe.agents)}
        _, next_state, _, _, _ = self.mpe.step_env(key, state, actions)
        return next_state, self.reward(next_state), jnp.zeros((), bool)

    def reward(self, state: State) -> jax.Array:
        """The controlled agent's reward in ``state`` (the state after the joint move)."""
        if self.config.reward == "pettingzoo":
            r = self.mpe.rewards(state)[self.mpe.agents[CONTROLLED]]
            return jnp.asarray(r, jnp.float32)
        return self.mpe_reward(state)

    def mpe_reward(self, state: State, agent: int = CONTROLLED) -> jax.Array:
        """Original MPE cooperative-navigation reward of ``agent`` (module doc)."""
        agents = state.p_pos[:NUM_AGENTS]
        landmarks = state.p_pos[NUM_AGENTS:]
        dists = jnp.linalg.norm(agents[None, :, :] - landmarks[:, None, :], axis=-1)  # [L, A]
        cover = -jnp.sum(jnp.min(dists, axis=1))
        radius = self.mpe.rad[:NUM_AGENTS]
        touching = jnp.linalg.norm(agents - agents[agent], axis=-1) < (radius + radius[agent])
        counted = jnp.arange(NUM_AGENTS) != agent
        if self.config.self_collision:
            counted = jnp.ones(NUM_AGENTS, bool)
        return (cover - jnp.sum(touching & counted)).astype(jnp.float32)

    def agent_rewards(self, state: State) -> jax.Array:
        """[3] every agent's own reward under ``config.reward`` (for training partners)."""
        if self.config.reward == "pettingzoo":
            r = self.mpe.rewards(state)
            return jnp.stack([r[a] for a in self.mpe.agents]).astype(jnp.float32)
        return jnp.stack([self.mpe_reward(state, i) for i in range(NUM_AGENTS)])

    def joint_view(self) -> JointView:
        """All three agents as learners (self-play); agent 2 stands in for the controlled one."""

        def observe(state: State) -> jax.Array:
            obs = self.mpe.get_obs(state)
            return jnp.stack([obs[a] for a in self.mpe.agents]).astype(jnp.float32)

        def step(
            key: jax.Array, state: State, actions: jax.Array, weights: jax.Array
        ) -> tuple[State, jax.Array, jax.Array, jax.Array]:
            del weights
            acts = {a: actions[i] for i, a in enumerate(self.mpe.agents)}
            _, nxt, _, _, _ = self.mpe.step_env(key, state, acts)
            r = self.agent_rewards(nxt)
            return nxt, r, r, jnp.zeros((), bool)

        return JointView(
            name="spread",
            num_agents=NUM_AGENTS,
            obs_dim=OBS_DIM,
            num_actions=5,
            episode_len=self.config.episode_len,
            reset=self.reset,
            observe=observe,
            step=step,
            partner_slots=tuple(i for i in range(NUM_AGENTS) if i != CONTROLLED),
            controlled=CONTROLLED,
        )


def make_env(config: Config, population: Population) -> ControlledEnv:
    """Spread with ``config`` and ``population``; :func:`transam.make_env` builds the
    population from a ``partners`` choice (default: the shipped learned one)."""
    return ControlledEnv(SpreadGame(config), population)
