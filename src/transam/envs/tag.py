"""Tag: LIAM's predator-prey, the TransAM paper's "modified predator-prey".

Source: the ``predator_prey`` scenario of LIAM (github uoe-agents/LIAM) running on the particle
environment fork it installs (github shariqiqbal2810/multiagent-particle-envs). Three predators
(agents 0-2) chase one prey (agent 3), which is the controlled agent. Two large immovable
landmarks block the way. Everything is reproduced from those sources:

* Physics of the fork: dt 0.1, damping 0.25, contact force 100, contact margin 1e-3, mass 1.
  The applied force is ``accel**2 * u`` (the fork scales the action by ``accel`` twice) and the
  velocity is updated before the position: damp, add force, clip to max speed, then move with
  the new velocity. Agents have size 0.07; predators accel 3 / max speed 1.0, the prey accel 4 /
  max speed 1.3. Landmarks have size 0.2, collide, never move. Every pair of entities collides.
* Walls: four soft walls at x, y = +-1.3 (width 0.1, endpoints +-1, so the corners are open),
  with the fork's contact force and its arcsin correction near the wall ends. They are LEAKY: an
  agent that keeps pushing outward passes through, as in the original (the wall force never
  balances ``accel**2``). ``Config.hard_walls`` adds what the original lacks: after each step an
  agent's centre is clamped to the wall's inner face (``1.3 - 0.05 - 0.07 = 1.18`` on every
  side, corners included) and its outward velocity is zeroed.
* Reset: agent and landmark positions U(-0.9, 0.9)^2 independently (overlap allowed), all
  velocities zero. Episodes last 50 steps and have no other termination.
* Prey observation (14): [vel, pos, landmark 0 and 1 rel, predator 0, 1, 2 rel]. Partial view
  is LIAM's axis-aligned box: an entity with ``|dx| > 0.5`` or ``|dy| > 0.5`` reads (-5, -5).
* Predator observation (16, full view): [vel, pos, landmark 0 and 1 rel, the two other
  predators rel (index order), prey rel, prey velocity]; the decoder target is the three stacked.
* Prey reward, on the state after the step: n = number of predators closer than 0.28
  (= 2 * (0.07 + 0.07), LIAM's "capture" test, twice the contact distance): 0 for n = 0, +1 for
  n = 1, -1 for n >= 2. Plus -10 on each step the prey is outside ``|x|, |y| <= 0.99``
  (``Config.boundary_penalty``, on by default, as in LIAM's final commit).

Choices made here where the sources leave one open:

* Actions use the MPE/JaxMARL convention for every agent: 0 no-op, 1 -x, 2 +x, 3 -y, 4 +y
  (the fork's mirrored indices, 1 = +x ..., are not used; heuristics are defined by meaning).
* Built on JaxMARL's ``SimpleTagMPE`` (whose observation layouts already match LIAM's): the
  subclass resizes the agents, scales the decoded action by ``accel`` a second time, replaces
  the integrator by the fork's velocity-first one and adds the wall force to the environment
  force. The entity-contact force, action decoding and observation code are JaxMARL's; only the
  box masking is added here. That is smaller than writing the physics out again.
* Evaluation without the boundary penalty: ``strip_boundary_penalty(reward)`` adds the 10 back
  to any step reward below -2, exactly LIAM's (and the TransAM authors') evaluation rule; it is
  exact because the capture part lies in {-1, 0, 1}. ``boundary_penalty(state)`` gives the
  same term from a game state. Report returns both with and without it.
* Float32 throughout (the fork uses float64). Where two entities sit on exactly the same point
  the contact direction is 0/0; the fork would produce NaN, here that step's contact force on
  them is dropped (only reachable from constructed states, or with hard walls when two agents
  with identical coordinates are pressed into a wall).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from transam._quiet import jaxmarl_modules
from transam.envs.core import MPE_ACTION_NAMES, ControlledEnv, EnvError, ForkIntegrator, GameSpec
from transam.envs.joint import JointView
from transam.envs.population import PolicyFn, Population

with jaxmarl_modules():
    from jaxmarl.environments.mpe.simple import State
    from jaxmarl.environments.mpe.simple_tag import SimpleTagMPE

NUM_PREDATORS = 3
PREY = NUM_PREDATORS  # agent index of the prey (the controlled agent)
NUM_LANDMARKS = 2
AGENT_SIZE = 0.07
LANDMARK_SIZE = 0.2
CONTACT_FORCE = 100.0  # the fork's contact_force (also JaxMARL's default)
CONTACT_MARGIN = 1e-3  # the fork's contact_margin (softplus width of penetration)
WALL_POS = 1.3  # walls at x = +-1.3 and y = +-1.3
WALL_WIDTH = 0.1
WALL_END = 1.0  # wall segments span [-1, 1] along their length (the fork's default)
SPAWN = 0.9  # reset positions ~ U(-0.9, 0.9)^2
CAPTURE_DIST = 2 * AGENT_SIZE + 2 * AGENT_SIZE  # 0.28, LIAM's is_collision
VIEW_BOX = 0.5  # the prey sees entities with |dx| <= 0.5 and |dy| <= 0.5
HIDDEN = -5.0  # what the prey reads for an entity outside its view box
BOUNDARY = 0.99  # the -10 applies when |x| > 0.99 or |y| > 0.99
BOUNDARY_PENALTY = -10.0


@dataclass(frozen=True)
class Config:
    """Tag settings; the defaults reproduce LIAM's predator-prey."""

    episode_len: int = 50  # steps per episode (LIAM: 50)
    boundary_penalty: bool = True  # charge the prey -10 per step outside |x|,|y| <= 0.99
    hard_walls: bool = False  # clamp agents inside the walls (the original walls leak)

    def __post_init__(self) -> None:
        if self.episode_len < 1:
            raise EnvError(f"tag episode_len must be >= 1; got {self.episode_len!r}")


class LiamTagMPE(ForkIntegrator, SimpleTagMPE):
    """JaxMARL's simple_tag with the LIAM fork's sizes, force scaling, integrator and walls."""

    def __init__(self, hard_walls: bool = False) -> None:
        super().__init__(num_good_agents=1, num_adversaries=NUM_PREDATORS, num_obs=NUM_LANDMARKS)
        self.rad = jnp.array([AGENT_SIZE] * self.num_agents + [LANDMARK_SIZE] * NUM_LANDMARKS)
        self.hard_walls = hard_walls

    def _decode_discrete_action(self, a_idx: jax.Array, action: jax.Array) -> tuple:
        """JaxMARL's decoding (force = accel * u), times accel again: the fork's accel^2 * u."""
        u, c = SimpleTagMPE._decode_discrete_action(self, a_idx, action)
        return u * self.accel[a_idx][:, None], c

    def _apply_environment_force(self, p_force_all: jax.Array, state: State) -> jax.Array:
        """Entity contacts (JaxMARL) plus the fork's soft wall force on movable entities."""
        p_force = super()._apply_environment_force(p_force_all, state)
        # Two entities on exactly one point give a 0/0 contact direction (NaN, in the fork
        # too); drop that step's force rather than poison a whole batch.
        p_force = jnp.where(jnp.isnan(p_force), 0.0, p_force)
        walls = jax.vmap(wall_force, in_axes=(0, 0))(state.p_pos, self.rad)
        return p_force + walls * self.moveable[:, None]

    def _world_step(self, key: jax.Array, state: State, u: jax.Array) -> tuple:
        p_pos, p_vel = super()._world_step(key, state, u)
        if self.hard_walls:
            p_pos, p_vel = clamp_inside(p_pos, p_vel, self.rad, self.moveable)
        return p_pos, p_vel


def wall_force(pos: jax.Array, size: jax.Array) -> jax.Array:
    """Summed force of the four walls on one entity, as the fork's get_wall_collision_force.

    The force pushes along the sign of (position - wall line), so once an agent's centre is
    past a wall it is pushed further out: that, and a force too weak for accel^2, is the leak.
    """
    perp = jnp.array([1, 1, 0, 0])  # H walls act along y, V walls along x
    axis_pos = jnp.array([-WALL_POS, WALL_POS, -WALL_POS, WALL_POS])

    def one(perp_dim: jax.Array, line: jax.Array) -> jax.Array:
        along = pos[1 - perp_dim]
        beyond = (along < -WALL_END - size) | (along > WALL_END + size)
        past = jnp.where(along < -WALL_END, along + WALL_END, 0.0)
        past = jnp.where(along > WALL_END, along - WALL_END, past)
        theta = jnp.arcsin(jnp.clip(past / size, -1.0, 1.0))
        dist_min = jnp.cos(theta) * size + 0.5 * WALL_WIDTH
        delta = pos[perp_dim] - line
        dist = jnp.abs(delta)
        k = CONTACT_MARGIN
        pen = jnp.logaddexp(0.0, -(dist - dist_min) / k) * k
        mag = CONTACT_FORCE * jnp.sign(delta) * pen  # the fork's delta / |delta|
        force = jnp.zeros(2).at[perp_dim].set(jnp.cos(theta) * mag)
        force = force.at[1 - perp_dim].set(jnp.sin(theta) * jnp.abs(mag))
        return jnp.where(beyond, 0.0, force)

    return jnp.sum(jax.vmap(one)(perp, axis_pos), axis=0)


def clamp_inside(
    p_pos: jax.Array, p_vel: jax.Array, rad: jax.Array, moveable: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Hard walls: keep movable centres within the walls' inner faces, no outward velocity."""
    limit = (WALL_POS - 0.5 * WALL_WIDTH - rad)[:, None]
    out_hi, out_lo = p_pos > limit, p_pos < -limit
    outward = (out_hi & (p_vel > 0)) | (out_lo & (p_vel < 0))
    m = moveable[:, None]
    p_pos = jnp.where(m, jnp.clip(p_pos, -limit, limit), p_pos)
    p_vel = jnp.where(m & outward, 0.0, p_vel)
    return p_pos, p_vel


def num_captures(state: State) -> jax.Array:
    """Number of predators within LIAM's capture distance (0.28) of the prey."""
    d = jnp.linalg.norm(state.p_pos[:NUM_PREDATORS] - state.p_pos[PREY], axis=-1)
    return jnp.sum(d < CAPTURE_DIST)


def capture_reward(state: State) -> jax.Array:
    """0 / +1 / -1 for 0 / 1 / >=2 predators within 0.28 of the prey."""
    n = num_captures(state)
    return jnp.where(n == 0, 0.0, jnp.where(n == 1, 1.0, -1.0)).astype(jnp.float32)


def boundary_penalty(state: State) -> jax.Array:
    """-10 when the prey is outside |x|, |y| <= 0.99, else 0 (charged every such step)."""
    out = jnp.any(jnp.abs(state.p_pos[PREY]) > BOUNDARY)
    return jnp.where(out, BOUNDARY_PENALTY, 0.0).astype(jnp.float32)


def strip_boundary_penalty(reward: jax.Array) -> jax.Array:
    """A prey step reward without the boundary penalty (LIAM's evaluation: +10 if below -2).

    Exact for rewards of this game with the penalty on, because the capture part is in
    {-1, 0, 1}; an evaluator sums this over an episode for the penalty-free return.
    """
    return jnp.where(reward < -2.0, reward - BOUNDARY_PENALTY, reward)


def mask_outside_box(rel: jax.Array) -> jax.Array:
    """Replace relative positions [n, 2] outside the 0.5 view box by (-5, -5)."""
    hidden = jnp.any(jnp.abs(rel) > VIEW_BOX, axis=-1, keepdims=True)
    return jnp.where(hidden, HIDDEN, rel)


class TagGame:
    """LIAM predator-prey seen from the prey; the three predators are the partners."""

    def __init__(self, config: Config) -> None:
        self.config = config
        self.mpe = LiamTagMPE(hard_walls=config.hard_walls)
        self.spec = GameSpec(
            name="tag",
            obs_dim=14,
            num_actions=5,
            num_others=NUM_PREDATORS,
            other_obs_dim=16,
            other_num_actions=5,
            episode_len=config.episode_len,
            action_names=MPE_ACTION_NAMES,
            description="LIAM predator-prey: 3 heuristic/learned predators, controlled prey",
        )

    def reset(self, key: jax.Array) -> State:
        n = self.mpe.num_entities
        p_pos = jax.random.uniform(key, (n, 2), minval=-SPAWN, maxval=SPAWN)
        return State(
            p_pos=p_pos,
            p_vel=jnp.zeros((n, 2)),
            c=jnp.zeros((self.mpe.num_agents, self.mpe.dim_c)),
            done=jnp.array(False),
            step=jnp.zeros((), jnp.int32),
        )

    def observe(self, state: State) -> tuple[jax.Array, jax.Array]:
        obs = self.mpe.get_obs(state)
        prey = obs[self.mpe.agents[PREY]]
        seen = mask_outside_box(prey[4:].reshape(-1, 2)).reshape(-1)
        prey = jnp.concatenate([prey[:4], seen])
        preds = jnp.stack([obs[a] for a in self.mpe.agents[:NUM_PREDATORS]])
        return prey.astype(jnp.float32), preds.astype(jnp.float32)

    def transition(
        self, key: jax.Array, state: State, action: jax.Array, other_actions: jax.Array
    ) -> tuple[State, jax.Array, jax.Array]:
        actions = jnp.concatenate([other_actions, action[None]]).astype(jnp.int32)
        u, _ = self.mpe.action_decoder(self.mpe.agent_range, actions)
        p_pos, p_vel = self.mpe._world_step(key, state, u)
        state = dataclasses.replace(state, p_pos=p_pos, p_vel=p_vel, step=state.step + 1)
        return state, self.reward(state), jnp.array(False)

    def reward(self, state: State) -> jax.Array:
        """The prey's reward for arriving in ``state``."""
        if self.config.boundary_penalty:
            return capture_reward(state) + boundary_penalty(state)
        return capture_reward(state)


def predator_capture_reward(state: State) -> jax.Array:
    """LIAM's predator team reward without shaping: c = 1 pair within 0.28 gives -1, c >= 2 +1."""
    c = num_captures(state)
    return jnp.where(c == 1, -1.0, jnp.where(c >= 2, 1.0, 0.0)).astype(jnp.float32)


def predator_reward(state: State) -> jax.Array:
    """LIAM's shared predator reward: the capture term minus 0.1 * summed distance to the prey."""
    d = jnp.linalg.norm(state.p_pos[:NUM_PREDATORS] - state.p_pos[PREY], axis=-1)
    return predator_capture_reward(state) - 0.1 * jnp.sum(d)


def joint_view(config: Config, prey: PolicyFn, score: str = "shaped") -> JointView:
    """The three predators as learners; ``prey`` (a stand-in) plays the controlled agent.

    Every predator gets LIAM's shared predator reward (with the distance shaping) to train on.
    ``score="shaped"`` scores them by it too: the capture term alone (-1 for a lone catch, +1 for
    a joint one) is too sparse to separate short-trained predators from random ones.
    ``score="touches"`` scores 1 per step with at least one predator within the capture
    distance of the prey: how often the team reaches the prey, whatever the shaping.
    """
    if score not in ("shaped", "touches"):
        raise ValueError(f"unknown Tag score {score!r}; valid choices: shaped, touches")
    game = TagGame(config)

    def observe(state: State) -> jax.Array:
        return game.observe(state)[1]

    def step(
        key: jax.Array, state: State, actions: jax.Array, weights: jax.Array
    ) -> tuple[State, jax.Array, jax.Array, jax.Array]:
        del weights
        k_prey, k_step = jax.random.split(key)
        prey_action = jnp.asarray(prey(k_prey, game.observe(state)[0]), jnp.int32)
        nxt, _, term = game.transition(k_step, state, prey_action, actions)
        ones = jnp.ones(NUM_PREDATORS, jnp.float32)
        r = ones * predator_reward(nxt)
        if score == "touches":
            return nxt, r, ones * (num_captures(nxt) >= 1), term
        return nxt, r, r, term

    return JointView(
        name="tag",
        num_agents=NUM_PREDATORS,
        obs_dim=16,
        num_actions=5,
        episode_len=config.episode_len,
        reset=game.reset,
        observe=observe,
        step=step,
        partner_slots=(0, 1, 2),
        controlled=None,
    )


def make_env(config: Config, population: Population) -> ControlledEnv:
    """Tag with ``config`` and ``population``; :func:`transam.make_env` builds the
    population from a ``partners`` choice (default: the shipped learned one)."""
    return ControlledEnv(TagGame(config), population)
