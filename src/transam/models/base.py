"""The agent-model protocol every method (TransAM, its ablations, the baselines) implements.

An agent model turns the controlled agent's own trajectory into an embedding z_t that the
policy conditions on. It has these parts, and the types keep execution honest:

* ``step`` (execution path): one step of *local* data (:class:`LocalStep`) and a carry (context
  window, recurrent state) -> new carry and z_t. It never receives partner data: its input type
  has no field for it and its signature no argument for it. Only a :class:`PrivilegedModel`
  (``privileged = True``: the Oracle baseline) takes a :class:`PartnerView` as well, and only
  :func:`run_step` / :func:`run_embed` hand it one.
* ``embed_rollout`` (training path): the same z for a whole rollout of T steps, recomputed with
  gradients from the carry at the rollout's start. It must equal ``step`` applied in sequence.
* ``loss``: the auxiliary agent-modeling loss over a *batch* of rollouts (contrastive losses
  compare environments), which may use the training-only
  :class:`~transam.envs.core.PartnerRecord` targets; ``loss_and_embed`` is the same loss with
  the z of its own encoder pass, where the policy may read that z.
* ``decode``: the training-only decoder on one embedding, for evaluation metrics.

Every model has every member, so the trainer calls the same methods whatever it holds (no
``hasattr`` or class checks): what only some methods use has a neutral value in the others,
``key`` (dropout; ignored without dropout), ``prior_steps`` (0: the loss wants no targets from
before the rollout) and ``loss_and_embed``'s z (None: the trainer makes its own pass).

``step``, ``embed_rollout`` and ``decode`` act on ONE environment (no batch axis); the trainer
vmaps them. ``loss`` takes the trainer's time-major batch.
Episode boundaries: a step with ``first = True`` starts a new episode, and the model must not
let anything from before it influence z (the carry is reset inside ``step`` itself, so no caller
can forget to).
"""

from __future__ import annotations

from typing import Any, Protocol, cast

import jax
import jax.numpy as jnp
from flax import struct

from transam.envs.core import EnvState, GameSpec, PartnerRecord

Params = Any
Carry = Any


@struct.dataclass
class LocalStep:
    """What the controlled agent itself knows when it acts at step t (execution-time input)."""

    obs: jax.Array  # o_t [obs_dim] float32
    prev_action: jax.Array  # a_{t-1} int32 (0 and meaningless when ``first``)
    prev_reward: jax.Array  # r_{t-1} float32 (0 when ``first``)
    t: jax.Array  # int32 index of o_t within its episode
    first: jax.Array  # bool: o_t is the first observation of an episode


@struct.dataclass
class PartnerView:
    """Privileged execution-time input of the Oracle: the other agents' data at step t."""

    other_obs: jax.Array  # o^{-1}_t [num_others, other_obs_dim]
    other_prev_actions: jax.Array  # a^{-1}_{t-1} [num_others] int32, -1 at an episode's start


ACC_NEWEST = "action_accuracy_newest"
"""Accuracy of the prediction at the newest window position (what execution uses: z_t against
a^{-1}_t). Every method with an action decoder logs it; comparable across methods."""
ACC_ALL = "action_accuracy_all_positions"
"""Accuracy over every valid position of every window (the authors' training chart). Only
methods that decode each window position log it (TransAM, -fuse, -im): the window is
bidirectional, so at older positions later observations reveal the answer. A method with one
decoded embedding per step (LIAM, CAIL, PEL, TransAM-pool) has no such metric: absent, not
equal to the newest (an equal number would read as a look-ahead it does not have)."""
MSE_ALL = "obs_mse_all_positions"
"""The observation-MSE analogue of :data:`ACC_ALL`; plain ``obs_mse`` is the newest position's."""
LEGACY_METRICS = {"action_accuracy": ACC_NEWEST}
"""Metric names of older runs -> today's: ``action_accuracy`` was always the newest
position's (in training and in evaluation)."""


def position_metrics(
    logits: jax.Array,
    actions: jax.Array,
    valid: jax.Array,
    obs_err: jax.Array | None = None,
) -> dict[str, jax.Array]:
    """Action accuracy at the newest position and over all valid positions of each window.

    ``logits`` [..., P, N, A], ``actions`` [..., P, N] (targets of each position), ``valid``
    [..., P] (which positions count for the all-positions mean; the newest, P-1, always counts
    for the newest mean), ``obs_err`` [..., P] an optional per-position observation MSE.
    Returns :data:`ACC_NEWEST` and :data:`ACC_ALL` (and ``obs_mse`` / :data:`MSE_ALL`).
    """
    correct = jnp.mean((jnp.argmax(logits, -1) == actions).astype(jnp.float32), -1)  # [..., P]
    w = valid.astype(jnp.float32)
    count = jnp.maximum(jnp.sum(w), 1.0)
    out = {
        ACC_NEWEST: jnp.mean(correct[..., -1]),
        ACC_ALL: jnp.sum(correct * w) / count,
    }
    if obs_err is not None:
        out["obs_mse"] = jnp.mean(obs_err[..., -1])
        out[MSE_ALL] = jnp.sum(obs_err * w) / count
    return out


Decoded = tuple[jax.Array | None, jax.Array | None]
"""(predicted joint other-agent observation [num_others * other_obs_dim] or None, other agents'
action logits [num_others, other_num_actions] or None)."""


class AgentModel(Protocol):
    """One agent-modeling method. Implementations are frozen dataclasses (hashable, static)."""

    @property
    def name(self) -> str: ...

    @property
    def privileged(self) -> bool:
        """True only for the Oracle baseline (a :class:`PrivilegedModel`)."""
        ...

    @property
    def embed_dim(self) -> int:
        """Width of z."""
        ...

    @property
    def prior_steps(self) -> int:
        """How many steps before a rollout the loss also reconstructs, given their targets
        (``loss``'s ``prior``): TransAM's K-1 with ``recon_at="window"`` (the authors' loop
        supervises every window position); 0 for every other model."""
        ...

    def init(self, key: jax.Array, spec: GameSpec) -> Params:
        """Fresh parameters (an empty dict for a model with none)."""
        ...

    def init_carry(self, spec: GameSpec) -> Carry:
        """The carry before any step (a step with ``first=True`` resets it anyway)."""
        ...

    def step(
        self, params: Params, carry: Carry, x: LocalStep, key: jax.Array | None = None
    ) -> tuple[Carry, jax.Array]:
        """Execution path: (carry, z_t) from local data only. ``key`` turns on the model's
        dropout (acting with dropout, as the authors' code does; the registry's ``dropout``
        flag says which methods have any); a model without dropout ignores it."""
        ...

    def embed_rollout(
        self, params: Params, carry: Carry, xs: LocalStep, key: jax.Array | None = None
    ) -> jax.Array:
        """Training path: z [T, embed_dim] for the rollout ``xs`` (leading axis T), starting from
        the carry the execution path had before ``xs[0]``; equals ``step`` applied in order
        (with dropout under ``key``, as ``step``)."""
        ...

    def decode(self, params: Params, z: jax.Array, other_obs: jax.Array) -> Decoded:
        """The training-only decoder on one embedding z_t: what it predicts of the other agents
        (None for what it does not). ``other_obs`` [num_others, other_obs_dim] is o^{-1}_t, the
        input of a conditional-imitation decoder; a reconstruction head ignores it. Used for the
        evaluation metrics (action accuracy, observation MSE)."""
        ...

    def loss(
        self,
        params: Params,
        carry: Carry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
        prior: PartnerRecord | None = None,
        prior_ok: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        """Auxiliary loss and its scalar metrics (e.g. :data:`ACC_NEWEST`, ``obs_mse``) over a
        batch of rollouts: ``carry`` [N, ...] (before each rollout), ``xs`` and ``targets``
        time-major [T, N, ...], lined up in time. ``key`` enables dropout (None: deterministic).
        ``prior`` [``prior_steps``, N, ...] are the targets of the steps before the rollout,
        oldest first, and ``prior_ok`` [``prior_steps``, N] which of them exist (those from
        before the trainer's collection do not); None, and ignored, where ``prior_steps`` is 0.
        Zero and no metrics for models without a loss."""
        ...

    def loss_and_embed(
        self,
        params: Params,
        carry: Carry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
        prior: PartnerRecord | None = None,
        prior_ok: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array], jax.Array | None]:
        """:meth:`loss` and the z [T, N, embed_dim] of the loss's own encoder pass (its dropout
        mask included), which the policy loss reads with the trainer's ``z_pass="shared"`` (the
        authors' one forward pass per update; the TransAM family). None where the trainer is
        to make a pass of its own (a model without such a pass, or without dropout, where a
        second pass gives the same numbers)."""
        ...


class PrivilegedModel(AgentModel, Protocol):
    """A model whose execution path also sees the other agents (the Oracle upper bound)."""

    def step(  # type: ignore[override]
        self,
        params: Params,
        carry: Carry,
        x: LocalStep,
        partner: PartnerView,
        key: jax.Array | None = None,
    ) -> tuple[Carry, jax.Array]: ...

    def embed_rollout(  # type: ignore[override]
        self,
        params: Params,
        carry: Carry,
        xs: LocalStep,
        partner: PartnerView,
        key: jax.Array | None = None,
    ) -> jax.Array: ...


class ModelDefaults:
    """The neutral values of the protocol's members that only some methods use, for a model to
    inherit (NAM, the Oracle, the recurrent baselines, PEL, a model of your own): its loss
    wants no targets from before a rollout, and gives no z of its own pass (the trainer makes
    its own: the same numbers for a model whose policy z has no dropout)."""

    @property
    def prior_steps(self) -> int:
        return 0

    def loss_and_embed(
        self: AgentModel,
        params: Params,
        carry: Carry,
        xs: LocalStep,
        targets: PartnerRecord,
        key: jax.Array | None = None,
        prior: PartnerRecord | None = None,
        prior_ok: jax.Array | None = None,
    ) -> tuple[jax.Array, dict[str, jax.Array], jax.Array | None]:
        return (*self.loss(params, carry, xs, targets, key, prior, prior_ok), None)


# The one place that hands partner data to a model: the trainer and the evaluation call these
# for every model, and only a privileged one gets (and needs) a PartnerView.


def partner_view(model: AgentModel, env_state: EnvState) -> PartnerView | None:
    """The other agents' data in ``env_state`` for a privileged model (the Oracle); None for
    every other model, so its execution path cannot be handed any."""
    if not model.privileged:
        return None
    return PartnerView(env_state.other_obs, env_state.other_prev_actions)


def run_step(
    model: AgentModel,
    params: Params,
    carry: Carry,
    x: LocalStep,
    partner: PartnerView | None,
    key: jax.Array | None = None,
) -> tuple[Carry, jax.Array]:
    """``model.step`` on one environment, with ``partner`` (from :func:`partner_view`) for a
    privileged model only."""
    if model.privileged:
        return cast(PrivilegedModel, model).step(params, carry, x, _view(partner), key)
    return model.step(params, carry, x, key)


def run_embed(
    model: AgentModel,
    params: Params,
    carry: Carry,
    xs: LocalStep,
    partner: PartnerView | None,
    key: jax.Array | None = None,
) -> jax.Array:
    """``model.embed_rollout`` of one environment's rollout, with the rollout's ``partner``
    views [T, ...] for a privileged model only."""
    if model.privileged:
        return cast(PrivilegedModel, model).embed_rollout(params, carry, xs, _view(partner), key)
    return model.embed_rollout(params, carry, xs, key)


def _view(partner: PartnerView | None) -> PartnerView:
    if partner is None:
        raise ValueError("a privileged model's execution path needs its PartnerView")
    return partner
