"""Typed training configuration (defaults: the authors' training loop, setting by setting, with
their action-loss bug fixed and the policy's clock added; each of our alternatives is one flag
away, docs/methods.md).

Every setting is a field with a docstring, so ``transam train --help`` lists it. :meth:`validate`
checks everything up front and raises one :class:`ConfigError` naming the bad value and the
valid choices, before anything is written to disk.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Literal

from transam import registry
from transam.compose import PartnerChoice, check_partners
from transam.envs import EnvError
from transam.models import BaselineConfig, TransAMConfig
from transam.registry import EnvName, MethodName

SeedMode = Literal["vmap", "sequential"]
AdvantageForm = Literal["gae", "recomputed"]
ValueLossForm = Literal["half_squared", "squared"]
EndBootstrap = Literal["zero", "return_mean"]
PolicyInit = Literal["orthogonal", "torch"]
ZPass = Literal["shared", "separate"]


def _methods_with(flag: str) -> list[str]:
    """The registered methods whose entry sets ``flag`` (a boolean :class:`MethodEntry` field)."""
    return [n for n in registry.method_names() if getattr(registry.method_entry(n), flag)]


class ConfigError(EnvError):
    """A bad training setting: the message names the field, the value and the valid range."""


@dataclass(frozen=True)
class A2CConfig:
    """A2C and optimiser settings (reference: the authors' Spread/Tag code)."""

    num_envs: int = 10
    """parallel training environments"""
    n_steps: int = 5
    """rollout length per update (n-step returns)"""
    gamma: float = 0.99
    """discount factor"""
    gae_lambda: float = 0.95
    """GAE lambda"""
    ent_coef: float = 0.01
    """entropy bonus coefficient (beta)"""
    vf_coef: float = 1.0
    """value-loss coefficient (on the value loss of ``value_loss``)"""
    normalize_advantages: bool = False
    """standardise advantages per rollout (the reference A2C does not)"""
    lr: float = 3e-4
    """policy Adam learning rate"""
    adam_eps: float = 1e-5
    """policy Adam epsilon"""
    anneal_lr: bool = True
    """anneal the policy learning rate linearly to 0 over the run (or over anneal_steps)"""
    model_lr: float = 3e-4
    """agent-model Adam learning rate (its own optimiser, never annealed)"""
    model_adam_eps: float = 1e-5
    """agent-model Adam epsilon"""
    model_passes: int = 1
    """agent-model gradient steps per collected rollout: the first is the joint update
    (default, the reference: one opponent-model step per update); each further pass is a
    model-only step over the collection's rollouts again, in order, after its updates (a
    deviation from the reference; docs/methods.md). No effect for methods without an
    agent-model loss"""
    max_grad_norm: float = 0.25
    """global gradient-norm clip, applied to each network (policy, agent model) separately"""
    normalize_returns: bool = True
    """value regresses returns standardised by a running mean/std of returns; advantages are
    divided by the same std"""
    backprop_encoder: bool = False
    """let the RL loss back-propagate into the agent model (reference: it does not)"""
    hidden: int = 128
    """LSTM and linear-layer width of the policy"""
    critic_z: bool = True
    """the critic reads the embedding z through the trunk it shares with the actor (default:
    the reference, the paper's V(o, E^o)). Off: the critic is its own LSTM on o_t (and the
    clock) only; the actor still conditions on z (why it exists: docs/methods.md)"""
    time_feature: bool = True
    """append the agent's own clock t / episode_len to the policy input (actor and critic;
    default, our one deviation from the reference's policy). The reference has no clock, so
    its critic cannot tell the last steps of an episode from the first (docs/methods.md)"""
    rollouts_per_collect: int = 5
    """rollouts collected with the same parameters before learning from them; then one update
    per rollout, in order, each starting from the LSTM state and window acting had (default,
    the reference: 5, a whole 25-step Spread episode as five 5-step rollouts, then five
    updates; 1 is plain A2C: rollout, update)"""
    advantage: AdvantageForm = "recomputed"
    """the policy-gradient advantage: the value target minus the critic's value recomputed in
    the update ('recomputed', default, the reference: normalised return minus V), or the GAE
    advantage of acting's values ('gae')"""
    value_loss: ValueLossForm = "squared"
    """value loss per step: (R - V)^2 (default, the reference) or 0.5 (R - V)^2 (the paper's
    notation)"""
    end_bootstrap: EndBootstrap = "return_mean"
    """what the return bootstraps from where an episode ends by its time limit: the running
    mean of returns ('return_mean', default, the reference: its zero bootstrap is in
    normalised units and is de-normalised with the rest; needs normalize_returns) or nothing
    ('zero': the end is terminal)"""
    anneal_steps: int = 0
    """with anneal_lr, the steps over which the policy learning rate falls to 0 (0: the
    run's total_steps; the reference anneals over its total_timesteps, 10M by default, also
    when stopped earlier)"""
    init: PolicyInit = "torch"
    """policy initialisation: PyTorch's defaults (default, the reference: uniform
    +-1/sqrt(fan_in) everywhere, two LSTM biases) or orthogonal (gain sqrt 2, actor 0.01,
    critic 1; flax LSTM defaults)"""
    act_dropout: bool = True
    """keep the agent model's dropout on wherever z is computed: acting, bootstrapping,
    evaluation (default: the reference never switches its encoder to eval mode). Only the
    TransAM family has dropout; for the other methods this changes nothing"""
    recompute_z: bool = True
    """the policy loss recomputes z with the agent model's current parameters (with dropout
    under act_dropout) instead of reusing the z acting saw (default: the reference
    recomputes)"""
    z_pass: ZPass = "shared"
    """with recompute_z, which encoder pass gives the policy loss its z: the agent-model
    loss's own forward pass, dropout mask included ('shared', default, the reference: one
    opponent_model pass feeds the reconstruction and, detached, agent.evaluate; it saves a
    forward pass per update), or a second pass with a fresh dropout mask ('separate'). Only
    the TransAM family has such a pass; the other methods always make their own (the same
    numbers either way: they have no dropout)"""
    z_scale: float = 1.0
    """the factor on z in the policy's input, concat(o_t, z_scale * z_t) (default 1, the
    reference's raw z). TransAM's post-norm encoder puts out |z| = sqrt(width), about 11,
    whatever the window, beside observations of norm 3-38 and LIAM's z of 1-3: a diagnostic of
    whether the embedding's size drowns the observation (0: the policy ignores z)"""


@dataclass(frozen=True)
class EvalConfig:
    """Evaluation during training (partners drawn uniformly, one episode per env copy)."""

    every_episodes: int = 100
    """evaluate every this many training episodes' worth of steps (episodes x episode length,
    summed over parallel envs; equals completed episodes where episodes have a fixed length)"""
    episodes: int = 100
    """evaluation episodes (run in parallel)"""
    greedy: bool = False
    """act by argmax instead of sampling (the trained A2C policy is stochastic, so the default
    samples, as the policy is meant to be used)"""


@dataclass(frozen=True)
class TrainConfig:
    """Train one controlled agent with A2C and an agent model, online, against the partner
    population (partners resampled every episode)."""

    env: EnvName = "spread"
    """environment"""
    method: MethodName = "transam"
    """agent-modeling method"""
    partners: PartnerChoice = "default"
    """partner population: the shipped learned one, its held-out split, the scripted one, or a
    population directory (manifest.json + default.safetensors, e.g. from `transam partners
    import-authors`)"""
    total_steps: int = 10_000_000
    """controlled-agent environment steps, summed over parallel envs (rounded up to whole
    collections of num_envs x n_steps x rollouts_per_collect steps: 250 by default)"""
    seed: int = 0
    """PRNG seed (with --num-seeds n: seeds seed .. seed+n-1)"""
    num_seeds: int = 1
    """independent runs (seeds) in this process"""
    seed_mode: SeedMode = "vmap"
    """with several seeds: one vmapped program over all seeds (faster for the small models;
    docs/performance.md), or the seeds one after another"""
    out: str = ""
    """run directory (default: runs/ENV-METHOD-sSEED)"""
    resume: bool = False
    """continue the interrupted run in --out from its last checkpoint"""
    force: bool = False
    """start over, deleting a finished or unfinished run in --out"""
    checkpoint_every: int = 1
    """write a checkpoint every this many chunks (one chunk = one evaluation interval); the
    last chunk always writes one"""
    keep_checkpoints: int = 2
    """keep the newest this many checkpoints of each seed; 0 keeps every one (to evaluate a run
    along its curve: ``transam evaluate RUN --checkpoint N``). Not part of the run's identity:
    ``--resume`` may change it"""
    progress: bool = True
    """show a progress bar"""
    a2c: A2CConfig = field(default_factory=A2CConfig)
    """A2C settings"""
    model: TransAMConfig = field(default_factory=TransAMConfig)
    """transformer encoder settings (TransAM, its ablations, PEL; ignored by other methods)"""
    baseline: BaselineConfig = field(default_factory=BaselineConfig)
    """recurrent-encoder and contrastive-loss settings of the baselines"""
    eval: EvalConfig = field(default_factory=EvalConfig)
    """evaluation settings"""

    @property
    def acting_dropout(self) -> bool:
        """Whether z is computed with dropout on outside the model's own loss: ``act_dropout``
        and a method whose model has dropout (the registry's ``dropout`` flag) at a rate > 0."""
        return self.a2c.act_dropout and self.model_has_dropout

    @property
    def model_has_dropout(self) -> bool:
        """The method's agent model applies dropout: a TransAM-family model, rate > 0."""
        return registry.method_entry(self.method).dropout and self.model.dropout > 0.0

    @property
    def z_from_loss_pass(self) -> bool:
        """Whether the policy loss's z is to come from the agent-model loss's own pass
        (``z_pass="shared"`` with ``recompute_z`` and without ``backprop_encoder``); the trainer
        does so for the models whose loss has such a pass (``loss_and_embed`` returns its z)."""
        a = self.a2c
        return a.recompute_z and not a.backprop_encoder and a.z_pass == "shared"

    @property
    def schedule_by_run(self) -> bool:
        """Whether the learning-rate schedule depends on the run length (annealed over
        ``total_steps``). When it does not, a longer run is a shorter one continued, so
        ``--resume`` may raise ``total_steps``."""
        return self.a2c.anneal_lr and not self.a2c.anneal_steps

    @property
    def run_dir(self) -> str:
        return self.out or f"runs/{self.env}-{self.method}-s{self.seed}"

    def validate(self) -> TrainConfig:
        """Raise :class:`ConfigError` for the first bad value; return ``self`` when all is well."""
        _choice("env", self.env, registry.env_names())
        _choice("method", self.method, registry.method_names())
        try:
            check_partners(self.partners, self.env)
        except EnvError as err:
            raise ConfigError(str(err)) from None
        _choice("seed_mode", self.seed_mode, ("vmap", "sequential"))
        _at_least("total_steps", self.total_steps, 1)
        _at_least("seed", self.seed, 0)
        _at_least("num_seeds", self.num_seeds, 1)
        _at_least("checkpoint_every", self.checkpoint_every, 1)
        _at_least("keep_checkpoints", self.keep_checkpoints, 0)
        a = self.a2c
        _at_least("a2c.num_envs", a.num_envs, 1)
        _at_least("a2c.n_steps", a.n_steps, 1)
        _at_least("a2c.hidden", a.hidden, 1)
        _in_range("a2c.gamma", a.gamma, 0.0, 1.0)
        _in_range("a2c.gae_lambda", a.gae_lambda, 0.0, 1.0)
        _in_range("a2c.ent_coef", a.ent_coef, 0.0, math.inf)
        _in_range("a2c.vf_coef", a.vf_coef, 0.0, math.inf)
        _in_range("a2c.z_scale", a.z_scale, 0.0, math.inf)
        _in_range("a2c.model_lr", a.model_lr, 0.0, math.inf)
        for name in ("lr", "adam_eps", "model_adam_eps", "max_grad_norm"):
            _positive(f"a2c.{name}", getattr(a, name))
        _at_least("a2c.rollouts_per_collect", a.rollouts_per_collect, 1)
        _at_least("a2c.model_passes", a.model_passes, 1)
        _at_least("a2c.anneal_steps", a.anneal_steps, 0)
        _choice("a2c.advantage", a.advantage, ("gae", "recomputed"))
        _choice("a2c.value_loss", a.value_loss, ("half_squared", "squared"))
        _choice("a2c.end_bootstrap", a.end_bootstrap, ("zero", "return_mean"))
        _choice("a2c.init", a.init, ("orthogonal", "torch"))
        _choice("a2c.z_pass", a.z_pass, ("shared", "separate"))
        if self.z_from_loss_pass and self.model_has_dropout and not a.act_dropout:
            raise ConfigError(
                "a2c.z_pass 'shared' gives the policy the z of the agent-model loss's pass, "
                "which has dropout, but a2c.act_dropout is off (z without dropout); use "
                "--a2c.z-pass separate with --a2c.no-act-dropout"
            )
        if a.end_bootstrap == "return_mean" and not a.normalize_returns:
            raise ConfigError(
                "a2c.end_bootstrap 'return_mean' needs a2c.normalize_returns (the running "
                "mean it bootstraps from)"
            )
        m = self.model
        _at_least("model.context (K)", m.context, 1)
        for name in ("width", "layers", "heads", "ff_width"):
            _at_least(f"model.{name}", getattr(m, name), 1)
        if m.width % m.heads:
            raise ConfigError(
                f"model.width ({m.width}) must be a multiple of model.heads ({m.heads})"
            )
        if not 0.0 <= m.dropout < 1.0:
            raise ConfigError(f"model.dropout must be in [0, 1), got {m.dropout!r}")
        _choice("model.norm", m.norm, ("post", "pre"))
        _choice("model.recon_at", m.recon_at, ("all", "window", "last"))
        _choice("model.init", m.init, ("default", "authors"))
        _choice("model.action_loss", m.action_loss, ("ce", "authors"))
        _choice("model.tokens", m.tokens, ("separate", "fuse"))
        _choice("model.pool", m.pool, ("last", "mean"))
        _choice("model.decoder", m.decoder, ("reconstruct", "imitate"))
        _choice("model.attention", m.attention, ("window", "stream"))
        if m.memory is not None:
            _at_least("model.memory", m.memory, 1)
        if m.dropout_masks is not None:
            _choice("model.dropout_masks", m.dropout_masks, ("flax", "packed"))
        stream = _methods_with("stream")
        if m.attention == "stream" and self.method not in stream:
            raise ConfigError(
                f"model.attention 'stream' applies to the methods {', '.join(stream)}; "
                f"got method {self.method!r}"
            )
        b = self.baseline
        for name in ("hidden", "embed_dim", "decoder_hidden"):
            _at_least(f"baseline.{name}", getattr(b, name), 1)
        _positive("baseline.temperature", b.temperature)
        _in_range("baseline.pel_alpha", b.pel_alpha, 0.0, math.inf)
        _choice("baseline.carl_positives", b.carl_positives, ("episode", "partner"))
        _at_least("eval.every_episodes", self.eval.every_episodes, 1)
        _at_least("eval.episodes", self.eval.episodes, 1)
        return self

    def identity(self) -> dict[str, Any]:
        """The settings that define the run (what ``--resume`` must match): all but where it is
        written and how it is driven."""
        d = dataclasses.asdict(self)
        for key in ("out", "resume", "force", "progress", "keep_checkpoints"):
            d.pop(key)
        return d


ADDED_SETTINGS: dict[tuple[str, str], Any] = {
    ("a2c", "time_feature"): False,
    ("a2c", "critic_z"): True,
    ("a2c", "rollouts_per_collect"): 1,
    ("a2c", "advantage"): "gae",
    ("a2c", "value_loss"): "half_squared",
    ("a2c", "end_bootstrap"): "zero",
    ("a2c", "anneal_steps"): 0,
    ("a2c", "init"): "orthogonal",
    ("a2c", "act_dropout"): False,
    ("a2c", "recompute_z"): False,
    ("a2c", "z_pass"): "separate",
    ("a2c", "model_passes"): 1,
    ("a2c", "z_scale"): 1.0,
    ("model", "embed_ln"): True,
    ("model", "init"): "default",
    ("model", "action_loss"): "ce",
    ("model", "attention"): "window",
    ("model", "memory"): None,
    ("model", "dropout_masks"): "flax",
}
"""Settings added after runs were first written, with the value that reproduces those runs."""
PRESET_FREE = (("model", "attention"), ("model", "memory"), ("model", "dropout_masks"))
"""Added settings that the authors' preset leaves at their defaults (the streaming encoder
and its masks are not part of the authors' loop; every other added setting is one of the
preset's)."""


def with_added_settings(saved: dict[str, Any]) -> dict[str, Any]:
    """A saved config.json as today's settings: each setting the run predates gets the value
    the run was trained with (so its checkpoints load and ``--resume`` compares like with like)."""
    saved = {k: dict(v) if isinstance(v, dict) else v for k, v in saved.items()}
    for (group, name), value in ADDED_SETTINGS.items():
        if isinstance(saved.get(group), dict):
            saved[group].setdefault(name, value)
    return saved


def comparable(identity: dict[str, Any]) -> dict[str, Any]:
    """A run's settings (``identity()``, or a saved config.json through
    :func:`with_added_settings`) with each default that depends on another setting resolved,
    so that a run started on the default and a command naming the value it resolves to are the
    same run: ``model.dropout_masks`` None is the masks the model draws (flax's for the window
    model, packed for the streaming one)."""
    model = identity.get("model")
    if not isinstance(model, dict) or model.get("dropout_masks") is not None:
        return identity
    attention = model.get("attention", "window")
    masks = TransAMConfig(attention=attention).masks if attention in ("window", "stream") else None
    return {**identity, "model": {**model, "dropout_masks": masks}}


def _choice(name: str, value: Any, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ConfigError(f"unknown {name} {value!r}; valid choices: {', '.join(choices)}")


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    return float(value)


def _at_least(name: str, value: Any, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{name} must be an integer >= {low}, got {value!r}")
    if value < low:
        raise ConfigError(f"{name} must be >= {low}, got {value}")


def _in_range(name: str, value: Any, low: float, high: float) -> None:
    if not low <= _number(name, value) <= high:
        raise ConfigError(f"{name} must be in [{low}, {high}], got {value!r}")


def _positive(name: str, value: Any) -> None:
    if not _number(name, value) > 0.0 or math.isinf(float(value)):
        raise ConfigError(f"{name} must be a positive finite number, got {value!r}")
