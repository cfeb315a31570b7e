"""Named sets of settings: ``transam train --preset NAME`` starts from them, and any other flag
still overrides a single setting (``--preset authors --a2c.time-feature`` is the authors' loop
with our clock), so each deviation can be measured on its own.

``2026-11``: our defaults until 2026-12-01, which every earlier result under docs/ ran with.

``authors``: the first author's TransAM training loop on Spread as their public script runs it
(conor-wallace/agent-transformer @ 62f58f7, ``a2c_lstm_transformer_spread.py`` with the
``opponent_models.BERTRAOOpponentTransformer`` it builds), setting by setting. Each entry
names where in that script the value comes from. The preset does not choose the partner
population or the run length: the parity runs pass the authors' population (``--partners``)
and ``--total-steps``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from transam.train.config import ConfigError, TrainConfig


@dataclass(frozen=True)
class Setting:
    """One preset value: the setting (``group.name``, or ``name`` at the top), its value, and
    where the reference has it."""

    name: str
    value: Any
    source: str


AUTHORS: tuple[Setting, ...] = (
    # --- the update scheme
    Setting("a2c.num_envs", 10, "Args.num_envs = 10"),
    Setting("a2c.n_steps", 5, "Args.episode_length // Args.num_minibatches = 25 // 5 (batch_size)"),
    Setting(
        "a2c.rollouts_per_collect",
        5,
        "the loop over idx in range(num_minibatches) collects a whole 25-step episode as 5 "
        "chunks of 5 steps with the same parameters (LSTM state and transformer window carried "
        "across chunks, reset at the episode start), then 'for idx in range(num_minibatches)' "
        "does one optimiser step per chunk, in order, from the LSTM state stored at its start",
    ),
    # --- returns, advantages, losses
    Setting("a2c.gamma", 0.99, "Args.gamma"),
    Setting("a2c.gae_lambda", 0.95, "Args.gae_lambda"),
    Setting(
        "a2c.normalize_returns",
        True,
        "RunningMeanStd over the GAE returns, updated chunk by chunk; returns standardised",
    ),
    Setting(
        "a2c.end_bootstrap",
        "return_mean",
        "at the episode end next_value = 0 is set before 'values * sqrt(var) + mean' "
        "de-normalises the row, and dones stored per step are never 1: the last step "
        "bootstraps from the running mean of returns",
    ),
    Setting(
        "a2c.advantage",
        "recomputed",
        "mb_advantages = mb_returns - new_values.detach(): normalised return minus the value "
        "recomputed in the update",
    ),
    Setting("a2c.normalize_advantages", False, "Args.norm_adv is never used"),
    Setting("a2c.value_loss", "squared", "value_loss = (mb_returns - new_values).pow(2).mean()"),
    Setting("a2c.vf_coef", 1.0, "Args.vf_coef"),
    Setting("a2c.ent_coef", 0.01, "Args.ent_coef"),
    # --- optimisers
    Setting("a2c.lr", 3e-4, "Args.learning_rate, Adam"),
    Setting("a2c.adam_eps", 1e-5, "optim.Adam(agent.parameters(), eps=1e-5)"),
    Setting("a2c.anneal_lr", True, "Args.anneal_lr"),
    Setting(
        "a2c.anneal_steps",
        10_000_000,
        "frac = 1 - (iteration - 1) / num_iterations with num_iterations from "
        "Args.total_timesteps = 10M (the measured curve was stopped at 625k/2M of a 10M run)",
    ),
    Setting("a2c.model_lr", 3e-4, "Args.opponent_learning_rate, never annealed"),
    Setting("a2c.model_adam_eps", 1e-5, "optim.Adam(opponent_model.parameters(), eps=1e-5)"),
    Setting(
        "a2c.model_passes",
        1,
        "one opponent_optimizer.step() per chunk, in the same loop as the agent's step",
    ),
    Setting("a2c.max_grad_norm", 0.25, "Args.max_grad_norm, clip_grad_norm_ on each network"),
    # --- the policy
    Setting("a2c.hidden", 128, "Agent: nn.LSTM(obs + 128, 128), fc1 128"),
    Setting(
        "a2c.critic_z",
        True,
        "Agent: actor and critic heads on one LSTM + fc1 trunk that reads concat(o, E^o)",
    ),
    Setting("a2c.time_feature", False, "Agent input: concat(o_t, E^o_t), no clock"),
    Setting("a2c.z_scale", 1.0, "Agent input: E^o_t as the encoder puts it out, unscaled"),
    Setting(
        "a2c.init",
        "torch",
        "Agent's layers keep PyTorch's default init (layer_init is defined but never called)",
    ),
    Setting("a2c.backprop_encoder", False, "mb_embeddings = ...[:, :, -1].detach()"),
    Setting(
        "a2c.act_dropout",
        True,
        "opponent_model is never put in eval mode: dropout while acting, bootstrapping, "
        "in the update and in evaluate()",
    ),
    Setting(
        "a2c.recompute_z",
        True,
        "the update runs opponent_model on the stored windows again and feeds those "
        "embeddings (detached) to agent.evaluate",
    ),
    Setting(
        "a2c.z_pass",
        "shared",
        "one 'embeddings = opponent_model(...)' per update feeds predict_opponent (the "
        "reconstruction loss) and, as embeddings[..., -1].detach(), agent.evaluate",
    ),
    # --- the agent model
    Setting("model.context", 5, "Args.seq_length = 5"),
    Setting("model.width", 128, "hidden_dim=128"),
    Setting("model.layers", 4, "n_layer=4"),
    Setting("model.heads", 4, "n_head=4"),
    Setting("model.ff_width", 256, "n_inner=2*128"),
    Setting("model.dropout", 0.1, "resid_pdrop=0.1, attn_pdrop=0.1"),
    Setting("model.norm", "post", "BertModel (post-norm)"),
    Setting("model.causal", False, "BertModel: bidirectional attention"),
    Setting("model.tokens", "separate", "BERTRAO: (return, action, state) tokens per step"),
    Setting("model.pool", "last", "embeddings[:, -1]: the newest observation token's output"),
    Setting("model.decoder", "reconstruct", "predict_oppnt_states and predict_oppnt_actions"),
    Setting(
        "model.embed_ln",
        False,
        "BERTRAOOpponentTransformer.forward never applies self.embed_ln, and their BertModel "
        "has no embeddings module: the summed token embeddings go straight into the blocks",
    ),
    Setting(
        "model.init",
        "authors",
        "BertModel.init_weights: N(0, 0.02) Linear weights, zero biases in the blocks; "
        "embed_* and the heads are PyTorch Linear defaults, embed_timestep nn.Embedding N(0, 1)",
    ),
    Setting(
        "model.recon_at",
        "window",
        "losses over every position with mask > 0 of every stored window, including steps "
        "of the episode's earlier chunks (their targets are in opp_obs_seqs/opp_actions_seqs)",
    ),
    Setting(
        "model.action_loss",
        "authors",
        "F.cross_entropy(opp_actions_preds, mb_opp_actions_seq) on softmax outputs shaped "
        "(batch, 2 partners, 5 actions): a cross-entropy over the partner axis",
    ),
    # --- evaluation
    Setting(
        "eval.every_episodes",
        1000,
        "evaluate when episodes_passed % 100 == 0, counted per iteration of 10 parallel "
        "episodes: every 1000 episodes (25,000 steps)",
    ),
    Setting("eval.episodes", 100, "Args.num_eval_envs = 100, one episode each"),
    Setting("eval.greedy", False, "evaluate(): actions sampled (OneHotCategorical)"),
)
"""The authors' training loop (see the module docstring)."""

EARLIER = (
    "defaults before 2026-12-01 (docs/results/parity/README.md: replaced by the authors' loop)"
)

BEFORE_PARITY: tuple[Setting, ...] = (
    Setting("a2c.rollouts_per_collect", 1, EARLIER + "; plain A2C: rollout, update"),
    Setting("a2c.advantage", "gae", EARLIER),
    Setting("a2c.value_loss", "half_squared", EARLIER),
    Setting("a2c.end_bootstrap", "zero", EARLIER),
    Setting("a2c.critic_z", False, EARLIER + "; docs/notes/2026-11-encoder-collapse-critic-z.md"),
    Setting(
        "a2c.time_feature", True, EARLIER + "; docs/notes/2026-11-critic-end-of-episode-bias.md"
    ),
    Setting("a2c.init", "orthogonal", EARLIER),
    Setting("a2c.act_dropout", False, EARLIER),
    Setting("a2c.recompute_z", False, EARLIER),
    Setting("a2c.z_pass", "separate", EARLIER + "; no effect without recompute_z"),
    Setting("model.embed_ln", True, EARLIER),
    Setting("model.init", "default", EARLIER),
    Setting("model.recon_at", "all", EARLIER),
)
"""Our own training settings until the parity study (every result under docs/ dated before
2026-12-01 ran with them): the authors' loop with the deviations the deviation table measures."""

PRESETS: dict[str, tuple[Setting, ...]] = {"authors": AUTHORS, "2026-11": BEFORE_PARITY}
PRESET_NAMES: tuple[str, ...] = ("none", *PRESETS)


def apply(config: TrainConfig, preset: str) -> TrainConfig:
    """``config`` with every setting of ``preset`` ('none': unchanged)."""
    if preset == "none":
        return config
    if preset not in PRESETS:
        raise ConfigError(f"unknown preset {preset!r}; valid choices: {', '.join(PRESET_NAMES)}")
    return apply_settings(config, {s.name: s.value for s in PRESETS[preset]})


def _set(config: Any, name: str, value: Any) -> Any:
    head, _, rest = name.partition(".")
    if not rest:
        return dataclasses.replace(config, **{head: value})
    return dataclasses.replace(config, **{head: _set(getattr(config, head), rest, value)})


def get(config: Any, name: str) -> Any:
    """The value of setting ``name`` (``group.name``) in ``config``."""
    for part in name.split("."):
        config = getattr(config, part)
    return config


SETTING_GROUPS = ("a2c", "model", "baseline")
"""The groups a grid may set (``transam reproduce --set``): the method and its training; the
run's identity (env, method, seed, partners, length, evaluation) is the grid's own."""


def parse_settings(assignments: tuple[str, ...] | list[str]) -> dict[str, Any]:
    """``("a2c.z_scale=0.088", ...)`` -> ``{"a2c.z_scale": 0.088}``, each value read as JSON
    (``true``, ``3``, ``0.1``, ``null``; anything else a string) and checked against the
    setting's type; :class:`ConfigError` names a bad one and the valid choices."""
    import json

    defaults = TrainConfig()
    settings: dict[str, Any] = {}
    for item in assignments:
        name, eq, text = item.partition("=")
        name = name.strip().replace("-", "_")
        group, _, field_name = name.partition(".")
        if not eq or group not in SETTING_GROUPS or not field_name:
            raise ConfigError(
                f"bad setting {item!r}: write GROUP.NAME=VALUE with GROUP one of "
                f"{', '.join(SETTING_GROUPS)} (e.g. a2c.z_scale=0.088)"
            )
        fields = [f.name for f in dataclasses.fields(getattr(defaults, group))]
        if field_name not in fields:
            raise ConfigError(
                f"unknown setting {name!r}; valid {group} settings: {', '.join(fields)}"
            )
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            value = text
        current = get(defaults, name)
        if isinstance(current, float) and type(value) is int:
            value = float(value)
        if current is not None and type(value) is not type(current):
            raise ConfigError(
                f"setting {name!r} takes a {type(current).__name__} (default {current!r}), "
                f"got {text!r}"
            )
        settings[name] = value
    apply_settings(defaults, settings).validate()  # a bad value fails before anything is written
    return settings


def apply_settings(config: TrainConfig, settings: dict[str, Any]) -> TrainConfig:
    """``config`` with each setting (``group.name`` -> value) replaced."""
    for name, value in settings.items():
        config = _set(config, name, value)
    return config
