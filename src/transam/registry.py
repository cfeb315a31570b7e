"""The one registry of environments and agent-modeling methods: every name, and what each
layer needs to know about it, is here (and nowhere else).

Why here, one module below envs/models/partners rather than a registry per layer: an env's
entry joins its game (envs/), its populations (partners/) and its report metadata, and a
registry split by layer would name each env once per layer. As a leaf module (stdlib only),
every layer (envs, partners, models, compose, train, report, cli) may look names up without
importing another layer, and ``import transam`` stays free of JAX. The paper's entries name
the code that implements them by import path (``"module"`` or ``"module:attribute"``),
imported on first use; an entry registered from user code (:func:`register_env`,
:func:`register_method`) may pass the objects themselves.

Adding a paper game = one game module, one partners module, one ``_paper_env`` entry below
(and its name in :data:`EnvName`); adding a method = one model module (its ``build_<name>`` in
:mod:`transam.models`), one ``_paper_method`` entry (and its name in :data:`MethodName`). The
Literals are the typed names the CLI and configs need; the import-time check below and
tests/test_registry.py keep them equal to the entries.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, get_args

EnvName = Literal["tag", "spread", "overcooked", "lbf"]
"""The paper's environments, in its order (the CLI's choices; typed for tyro and mypy)."""
MethodName = Literal[
    "transam",
    "nam",
    "oracle",
    "liam",
    "carl",
    "cail",
    "pel",
    "transam-fuse",
    "transam-pool",
    "transam-im",
]
"""The paper's methods in its order: TransAM, the baselines, the ablations."""
MethodKind = Literal["main", "reference", "baseline", "ablation"]
"""How the report groups a method: TransAM itself, the Oracle upper reference, a non-Oracle
baseline, an ablation of TransAM."""

Ref = Any
"""An implementation: an import path ``"module"`` / ``"module:attribute"`` (paper entries,
imported on first use) or the object itself (user entries)."""


class RegistryError(ValueError):
    """An unknown or clashing name: the message names it and the valid choices."""


def resolve(ref: Ref) -> Any:
    """The object an entry field names (imported when it is a path)."""
    if not isinstance(ref, str):
        return ref
    module, _, attr = ref.partition(":")
    obj = importlib.import_module(module)
    return getattr(obj, attr) if attr else obj


@dataclass(frozen=True)
class EnvEntry:
    """One environment: its game, its partner populations and its report metadata."""

    name: str
    title: str
    """display title (figures)"""
    game: Ref
    """the game: a module (or object) with ``Config`` (a frozen dataclass) and
    ``make_env(config, population) -> ControlledEnv``"""
    episode_len: int
    """the default config's episode length (a test checks it), for planning without JAX"""
    populations: Mapping[str, Ref] = field(default_factory=dict)
    """named partner choices built by code: ``loader(config) -> Population``"""
    learned: bool = False
    """ships learned ``default``/``heldout`` populations in ``transam/partners/data/<name>``"""
    blind_fields: frozenset[str] = frozenset()
    """config fields the learned partners may run with at any value (compose.py says why)"""
    partners: Ref = None
    """the partners module behind the learned populations: ``heuristic_pool()`` (heuristic
    members a manifest's teams may name) and ``joint_view(stand_in, score)`` (the training
    view of all agents, :mod:`transam.partners.learned`)"""
    partner_actions: int = 0
    """actions in a learned partner's own view (its actor's output size)"""
    features: Ref = None
    """a learned partner's observation features (default: the observation itself)"""
    recipe: Ref = None
    """``recipe(split) -> Recipe``: how the shipped learned population is trained
    (:mod:`transam.partners.recipes`)"""
    marl_eval: tuple[str, str] | None = None
    """(env, task) names in marl-eval exports (default: the name twice)"""

    def module(self) -> Any:
        return resolve(self.game)

    def config_class(self) -> type:
        cls: type = self.module().Config
        return cls

    def partner_choices(self) -> tuple[str, ...]:
        """The named ``partners`` choices (a population directory aside)."""
        shipped = ("default", "heldout") if self.learned else ()
        return (*shipped, *(p for p in self.populations if p not in shipped))


@dataclass(frozen=True)
class MethodEntry:
    """One agent-modeling method: how to build it and how the report shows it."""

    name: str
    display: str
    """the paper's name"""
    factory: Ref
    """``factory(spec, transformer, baseline, **options) -> AgentModel``"""
    kind: MethodKind = "baseline"
    options: Mapping[str, Any] = field(default_factory=dict)
    """keyword arguments for ``factory`` (an ablation's settings)"""
    dropout: bool = False
    """its execution path can apply dropout (``a2c.act_dropout``)"""
    stream: bool = False
    """it has a streaming variant (``model.attention stream``); TransAM-pool and PEL pool a
    window and refuse it"""
    embedding: bool = True
    """its z is a learned representation, worth probing (NAM's is the one-hot previous action)"""


_ENVS: dict[str, EnvEntry] = {}
_METHODS: dict[str, MethodEntry] = {}


def register_env(
    entry: EnvEntry | None = None, /, *, replace: bool = False, **fields: Any
) -> EnvEntry:
    """Add an environment (an :class:`EnvEntry`, or its fields as keywords); a taken name is an
    error unless ``replace``. Returns the entry."""
    entry = entry or EnvEntry(**fields)
    _add(_ENVS, entry.name, entry, "environment", replace)
    return entry


def register_method(
    entry: MethodEntry | None = None, /, *, replace: bool = False, **fields: Any
) -> MethodEntry:
    """Add a method (a :class:`MethodEntry`, or its fields as keywords); a taken name is an
    error unless ``replace``. Returns the entry."""
    entry = entry or MethodEntry(**fields)
    _add(_METHODS, entry.name, entry, "method", replace)
    return entry


def unregister_env(name: str) -> None:
    """Remove a user-registered environment (a paper one stays)."""
    _remove(_ENVS, name, PAPER_ENVS, "environment")


def unregister_method(name: str) -> None:
    """Remove a user-registered method (a paper one stays)."""
    _remove(_METHODS, name, PAPER_METHODS, "method")


def _add(table: dict[str, Any], name: str, entry: Any, what: str, replace: bool) -> None:
    if not isinstance(name, str) or not name:
        raise RegistryError(f"a {what} name must be a non-empty string; got {name!r}")
    if name in table and not replace:
        raise RegistryError(f"{what} {name!r} is already registered (pass replace=True)")
    table[name] = entry


def _remove(table: dict[str, Any], name: str, paper: tuple[str, ...], what: str) -> None:
    if name in paper:
        raise RegistryError(f"{what} {name!r} is the paper's; it cannot be removed")
    if name not in table:
        raise RegistryError(f"unknown {what} {name!r}; registered: {', '.join(table)}")
    del table[name]


def env_names() -> tuple[str, ...]:
    """Every registered environment: the paper's in its order, then the user's."""
    return tuple(_ENVS)


def method_names() -> tuple[str, ...]:
    """Every registered method: the paper's in its order, then the user's."""
    return tuple(_METHODS)


def env_entry(name: str) -> EnvEntry:
    if name not in _ENVS:
        raise RegistryError(
            f"unknown environment {name!r}; valid choices: {', '.join(env_names())}"
        )
    return _ENVS[name]


def method_entry(name: str) -> MethodEntry:
    if name not in _METHODS:
        raise RegistryError(f"unknown method {name!r}; valid choices: {', '.join(method_names())}")
    return _METHODS[name]


def methods_of(kind: MethodKind, paper_only: bool = True) -> tuple[str, ...]:
    """The methods of one kind, in registry order (by default only the paper's)."""
    names = PAPER_METHODS if paper_only else method_names()
    return tuple(n for n in names if _METHODS[n].kind == kind)


def display(method: str) -> str:
    """A method's paper name (the name itself when unknown: old runs, foreign data)."""
    entry = _METHODS.get(method)
    return entry.display if entry else method


def env_title(name: str) -> str:
    """An environment's display title (the name itself when unknown)."""
    entry = _ENVS.get(name)
    return entry.title if entry else name


PAPER_ENVS: tuple[EnvName, ...] = get_args(EnvName)
PAPER_METHODS: tuple[MethodName, ...] = get_args(MethodName)


def _paper_env(name: EnvName, features: str | None = None, **fields: Any) -> None:
    """A paper environment: game ``transam.envs.<name>``, partners ``transam.partners.<name>``
    (shipped learned populations plus the scripted ``"heuristic"`` one)."""
    register_env(
        name=name,
        game=f"transam.envs.{name}",
        populations={"heuristic": f"transam.partners.{name}:heuristic_population"},
        learned=True,
        partners=f"transam.partners.{name}",
        features=features and f"transam.partners.train:{features}",
        recipe=f"transam.partners.recipes:{name}_recipe",
        **fields,
    )


_paper_env(
    "tag",
    title="Tag (predator-prey)",
    episode_len=50,
    blind_fields=frozenset({"episode_len", "boundary_penalty"}),
    partner_actions=5,
    marl_eval=("mpe", "simple_tag"),
)
_paper_env(
    "spread",
    title="Spread (cooperative navigation)",
    episode_len=25,
    blind_fields=frozenset({"reward", "self_collision", "local_ratio", "episode_len"}),
    partner_actions=5,
    marl_eval=("mpe", "simple_spread"),
)
_paper_env(
    "overcooked",
    "overcooked_features",
    title="Overcooked (cramped room)",
    episode_len=400,
    blind_fields=frozenset(
        {"episode_len", "onion_in_pot_reward", "plate_pickup_reward", "soup_pickup_reward"}
    ),
    partner_actions=6,
    marl_eval=("overcooked", "cramped_room"),
)
_paper_env(
    "lbf",
    "lbf_features",
    title="LBF (level-based foraging)",
    episode_len=50,
    blind_fields=frozenset({"penalty", "episode_len", "relative_obs"}),
    partner_actions=6,
    marl_eval=("lbf", "20x20-2p-4f"),
)


def _paper_method(name: MethodName, display: str, kind: MethodKind, **options: str) -> None:
    """A paper method, built by ``transam.models.build_<name>`` (an ablation: TransAM's
    builder with ``options``)."""
    ablation = kind == "ablation"
    transformer = kind == "main" or ablation
    register_method(
        name=name,
        display=display,
        factory=f"transam.models:build_{'transam' if ablation else name}",
        kind=kind,
        options=options,
        dropout=transformer,
        stream=transformer and "pool" not in options,
        embedding=name != "nam",
    )


_paper_method("transam", "TransAM", "main")
_paper_method("nam", "NAM", "baseline")
_paper_method("oracle", "Oracle", "reference")
_paper_method("liam", "LIAM", "baseline")
_paper_method("carl", "CARL", "baseline")
_paper_method("cail", "CAIL", "baseline")
_paper_method("pel", "PEL", "baseline")
_paper_method("transam-fuse", "TransAM-fuse", "ablation", tokens="fuse")
_paper_method("transam-pool", "TransAM-pool", "ablation", pool="mean")
_paper_method("transam-im", "TransAM-im", "ablation", decoder="imitate")
if env_names() != PAPER_ENVS or method_names() != PAPER_METHODS:  # pragma: no cover
    raise RegistryError("the paper's entries and the EnvName/MethodName Literals disagree")

__all__ = [
    "PAPER_ENVS",
    "PAPER_METHODS",
    "EnvEntry",
    "EnvName",
    "MethodEntry",
    "MethodKind",
    "MethodName",
    "RegistryError",
    "display",
    "env_entry",
    "env_names",
    "env_title",
    "method_entry",
    "method_names",
    "methods_of",
    "register_env",
    "register_method",
    "resolve",
    "unregister_env",
    "unregister_method",
]
