"""The registry of environments and methods: the typed names agree with it, the paper entries
with their code, and a game and a method registered from user code (this file) train and
evaluate through the Python API without touching the package."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any, get_args

import jax
import jax.numpy as jnp
import pytest

import transam
from transam import cli, registry
from transam.envs import EnvError, config_class
from transam.envs.core import ControlledEnv, GameSpec
from transam.envs.population import Member, Population, Team
from transam.train import config as train_config


def test_typed_names_are_the_registry_paper_entries() -> None:
    assert get_args(registry.EnvName) == registry.PAPER_ENVS == registry.env_names()[:4]
    assert get_args(registry.MethodName) == registry.PAPER_METHODS
    assert registry.method_names()[: len(registry.PAPER_METHODS)] == registry.PAPER_METHODS
    # the CLI and the configs use the registry's Literals, not copies
    hints = {f.name: f.type for f in dataclasses.fields(train_config.TrainConfig)}
    assert hints["env"] == "EnvName" and hints["method"] == "MethodName"
    assert train_config.EnvName is registry.EnvName is cli.EnvName
    assert cli.MethodName is registry.MethodName
    assert sorted(transam.__all__) == sorted(transam._EXPORTS)


@pytest.mark.parametrize("name", registry.PAPER_ENVS)
def test_paper_env_entries_match_their_games(name: str) -> None:
    entry = registry.env_entry(name)
    assert entry.episode_len == config_class(name)().episode_len
    env = transam.make_env(name, partners="heuristic")
    assert env.spec.name == name
    assert entry.partner_choices() == ("default", "heldout", "heuristic")


def test_unknown_names_and_clashes_are_clear_errors() -> None:
    with pytest.raises(EnvError, match=r"unknown environment 'pong'; valid choices: tag, spread"):
        config_class("pong")
    with pytest.raises(EnvError, match=r"unknown method 'lima'; valid choices: transam, nam"):
        transam.make_model("lima", transam.make_env("spread", partners="heuristic").spec)
    with pytest.raises(registry.RegistryError, match="'spread' is already registered"):
        registry.register_env(name="spread", title="x", game="x", episode_len=1)
    with pytest.raises(registry.RegistryError, match="'transam' is the paper's"):
        registry.unregister_method("transam")
    assert registry.display("transam-im") == "TransAM-im" and registry.display("old") == "old"
    assert registry.methods_of("baseline") == ("nam", "liam", "carl", "cail", "pel")


# ------------------------------------------------------------- a toy game from user code

TOY, TOY_METHOD = "toy-match", "toy-nam"


@dataclasses.dataclass(frozen=True)
class ToyConfig:
    episode_len: int = 4


class ToyGame:
    """Match the partner: reward 1 when the controlled agent plays the partner's action; the
    controlled agent sees the partner's previous action (state: that action)."""

    def __init__(self, config: ToyConfig) -> None:
        self.spec = GameSpec(TOY, 2, 2, 1, 1, 2, config.episode_len, ("left", "right"))

    def reset(self, key: jax.Array) -> jax.Array:
        return jnp.zeros((), jnp.int32)

    def observe(self, state: jax.Array) -> tuple[jax.Array, jax.Array]:
        return jax.nn.one_hot(state, 2), jnp.ones((1, 1), jnp.float32)

    def transition(
        self, key: jax.Array, state: jax.Array, action: jax.Array, other_actions: jax.Array
    ) -> tuple[jax.Array, jax.Array, jax.Array]:
        theirs = other_actions[0]
        return theirs, (action == theirs).astype(jnp.float32), jnp.zeros((), bool)


def toy_population(config: ToyConfig) -> Population:
    def always(a: int) -> Any:
        return lambda key, obs: jnp.asarray(a, jnp.int32)

    members = [Member("left", always(0)), Member("right", always(1))]
    return Population("toy", members, [Team("left", ("left",)), Team("right", ("right",))])


@pytest.fixture
def toy() -> Iterator[None]:
    game = SimpleNamespace(
        Config=ToyConfig, make_env=lambda config, pop: ControlledEnv(ToyGame(config), pop)
    )
    pops = {"default": toy_population}
    transam.register_env(name=TOY, title="Toy match", game=game, episode_len=4, populations=pops)
    from transam.models import build_nam

    transam.register_method(name=TOY_METHOD, display="Toy NAM", factory=build_nam, embedding=False)
    try:
        yield
    finally:
        registry.unregister_env(TOY)
        registry.unregister_method(TOY_METHOD)


def test_a_registered_game_trains_and_evaluates(toy: None, tmp_path: Path) -> None:
    env = transam.make_env(TOY)
    assert env.num_partners == 2 and registry.env_title(TOY) == "Toy match"
    with pytest.raises(EnvError, match=r"unknown partners 'heldout'; valid choices: default,"):
        transam.make_env(TOY, partners="heldout")

    config = transam.TrainConfig(
        env=TOY,  # type: ignore[arg-type]
        method=TOY_METHOD,  # type: ignore[arg-type]
        total_steps=200,  # two collections of 5 rollouts x 5 steps x 4 envs
        out=str(tmp_path / "run"),
        progress=False,
        a2c=train_config.A2CConfig(num_envs=4),
        eval=train_config.EvalConfig(every_episodes=10, episodes=4),
    )
    result = transam.train(config)
    assert result.finished and result.run_dir == tmp_path / "run"
    lines = (result.run_dir / "metrics.jsonl").read_text().splitlines()
    assert lines and json.loads(lines[-1])["step"] == 200
    found = transam.evaluate_run(result.run_dir, episodes=4)
    assert found["env"] == TOY and 0.0 <= found["return"]["mean"] <= 4.0
    # unregistered, the name is unknown again
    registry.unregister_env(TOY)
    with pytest.raises(EnvError, match="unknown environment 'toy-match'"):
        transam.make_env(TOY)
    registry.register_env(registry.EnvEntry(TOY, "Toy", "x", 4))  # for the fixture's removal
