"""The JaxMARL adapter (transam.envs.jaxmarl) on constructed states, and the example that
trains TransAM on JaxMARL's simple_adversary from user code."""

from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct
from jaxmarl.environments.mpe.simple_adversary import SimpleAdversaryMPE
from jaxmarl.environments.spaces import Box, Discrete

from transam import registry
from transam.envs import EnvError
from transam.envs import jaxmarl as jm
from transam.envs.population import Member, Population, Team
from transam.models import TransAMConfig

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "jaxmarl_adversary.py"


# ------------------------------------------------------------ a JaxMARL-style toy env


@struct.dataclass
class CountState:
    x: jax.Array
    step: jax.Array


class Count:
    """Three agents with observations of different sizes (1, 2 and a [3, 1] array) and
    action spaces (2, 3, 4); each action adds to a shared counter; ``__all__`` at ``end_at``
    (an "early" terminal) and JaxMARL's own clock at ``max_steps``."""

    agents = ("a", "b", "c")
    sizes: ClassVar[dict[str, int]] = {"a": 2, "b": 3, "c": 4}

    def __init__(self, max_steps: int = 6, end_at: int = 100) -> None:
        self.max_steps, self.end_at = max_steps, end_at

    def action_space(self, agent: str) -> Discrete:
        return Discrete(self.sizes[agent])

    def get_obs(self, s: CountState) -> dict[str, jax.Array]:
        return {
            "a": s.x[None],
            "b": jnp.stack([s.x, s.step.astype(jnp.float32)]),
            "c": jnp.full((3, 1), -s.x),
            "world_state": jnp.zeros(7),
        }

    def reset(self, key: jax.Array) -> tuple[dict[str, jax.Array], CountState]:
        s = CountState(jax.random.uniform(key), jnp.zeros((), jnp.int32))
        return self.get_obs(s), s

    def step_env(self, key: jax.Array, s: CountState, actions: dict[str, jax.Array]) -> Any:
        x = s.x + sum(actions[a] * 10.0**i for i, a in enumerate(self.agents))
        s = CountState(x, s.step + 1)
        rewards = {a: jnp.float32(i + 1) * actions[a] for i, a in enumerate(self.agents)}
        end = (s.step >= self.end_at) | (s.step >= self.max_steps)
        dones = {**{a: end for a in self.agents}, "__all__": end}
        return self.get_obs(s), s, rewards, dones, {}


def obs_size(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Acts by the size of the observation it gets (checks it is its own, unpadded)."""
    return jnp.asarray(obs.shape[0] - 1, jnp.int32)


def constant(a: int) -> Any:
    return lambda key, obs: jnp.asarray(a, jnp.int32)


def count_population() -> Population:
    members = [Member("size", obs_size), Member("one", constant(1)), Member("two", constant(2))]
    teams = [Team("sizes", ("size", "size")), Team("one-two", ("one", "two"))]
    return Population("count", members, teams)


# ------------------------------------------------------------------------ the game


def test_spec_pads_partner_obs_and_counts_actions() -> None:
    env = jm.make_env(Count(), "b", count_population(), name="count")
    spec = env.spec
    assert (spec.name, spec.obs_dim, spec.num_actions, spec.episode_len) == ("count", 2, 3, 6)
    assert spec.num_others == 2 and spec.other_obs_dims == (3, 3)  # a: 1, c: 3 -> padded to 3
    assert spec.other_num_actions == 4 and spec.action_names == ("0", "1", "2")
    assert jm.partner_agents(Count(), "b") == ("a", "c")
    # the member used in slots of sizes 1 and 3 runs once per size
    assert [m.name for m in env.population.members] == ["size@1", "size@3", "one", "two"]
    assert env.population.team_names == ("sizes", "one-two")


def test_obs_reward_and_partner_view_are_the_jaxmarl_envs() -> None:
    raw = SimpleAdversaryMPE()
    game = jm.JaxMARLGame(raw, "agent_1")
    key = jax.random.key(3)
    state = game.reset(key)
    obs, env_state = raw.reset(key)
    own, others = game.observe(state)
    assert own.shape == (10,) and others.shape == (2, 10)
    np.testing.assert_array_equal(own, obs["agent_1"])
    np.testing.assert_array_equal(others[0, :8], obs["adversary_0"])  # adversary sees 8
    np.testing.assert_array_equal(others[0, 8:], 0.0)
    np.testing.assert_array_equal(others[1], obs["agent_0"])

    for i, (mine, theirs) in enumerate([(2, (1, 4)), (0, (3, 3)), (4, (0, 2))]):
        k = jax.random.key(10 + i)
        state, reward, terminal = game.transition(k, state, jnp.int32(mine), jnp.array(theirs))
        actions = {"agent_1": mine, "adversary_0": theirs[0], "agent_0": theirs[1]}
        obs, env_state, rewards, _, _ = raw.step_env(k, env_state, actions)
        own, others = game.observe(state)
        np.testing.assert_allclose(own, obs["agent_1"], rtol=1e-6)
        np.testing.assert_allclose(others[1], obs["agent_0"], rtol=1e-6)
        assert math.isclose(float(reward), float(rewards["agent_1"]), rel_tol=1e-6)
        assert not bool(terminal)


def test_partners_act_from_the_population_on_their_own_obs() -> None:
    env = jm.make_env(Count(), "b", count_population())
    state, _ = env.reset(jax.random.key(0), partner_id=0)
    seen = state.other_obs
    state, ts = env.step(jax.random.key(1), state, jnp.int32(2))
    # team "sizes": agent a (obs size 1) plays 0, agent c (size 3) plays 2 (padded: 2, 2)
    np.testing.assert_array_equal(ts.record.other_actions, [0, 2])
    np.testing.assert_array_equal(ts.record.other_obs, seen)  # o^{-1}_t alongside a_t
    assert int(ts.record.partner) == 0 and int(ts.record.t) == 0
    assert float(ts.reward) == 2.0 * 2  # b's own reward: 2 * its action

    state, _ = env.reset(jax.random.key(0), partner_id=1)
    x0 = float(state.game.env.x)
    state, ts = env.step(jax.random.key(1), state, jnp.int32(1))
    np.testing.assert_array_equal(ts.record.other_actions, [1, 2])
    assert math.isclose(float(state.game.env.x), x0 + 1 + 10 + 200, rel_tol=1e-6)
    # the partner view: a's obs padded with zeros, c's [3, 1] flattened
    np.testing.assert_allclose(state.other_obs[0], [x0 + 211, 0, 0], rtol=1e-6)
    np.testing.assert_allclose(state.other_obs[1], [-(x0 + 211)] * 3, rtol=1e-6)
    np.testing.assert_allclose(state.obs, [x0 + 211, 1], rtol=1e-6)


def run_episode(env: Any, steps: int) -> list[Any]:
    state, _ = env.reset(jax.random.key(0), partner_id=1)
    step = jax.jit(env.step)
    out = []
    for i in range(steps):
        state, ts = step(jax.random.key(i), state, jnp.int32(0))
        out.append((ts, state))
    return out


def test_episode_is_truncated_at_max_steps() -> None:
    env = jm.make_env(Count(max_steps=4), "a", count_population())
    assert env.spec.episode_len == 4
    out = run_episode(env, 9)
    done = [bool(ts.done) for ts, _ in out]
    assert done == [False, False, False, True] * 2 + [False]
    assert all(bool(ts.truncated) == d for (ts, _), d in zip(out, done, strict=True))
    state = out[3][1]
    assert int(state.t) == 0 and int(state.game.t) == 0 and int(state.game.env.step) == 0
    assert int(out[4][0].record.t) == 0  # the next step is the first of a new episode


def test_all_done_before_the_limit_is_terminal() -> None:
    env = jm.make_env(Count(max_steps=10, end_at=2), "c", count_population(), episode_len=5)
    out = run_episode(env, 4)
    assert [bool(ts.done) for ts, _ in out] == [False, True, False, True]
    assert not any(bool(ts.truncated) for ts, _ in out)


def test_clear_errors() -> None:
    with pytest.raises(EnvError, match=r"agent 'd' is not an agent of Count; valid choices: a, b"):
        jm.make_env(Count(), "d", count_population())
    one = Population("one", [Member("one", constant(1))], [Team("one", ("one",))])
    with pytest.raises(EnvError, match=r"controls 1 agents but 'Count' has 2 .*\(a, c, in"):
        jm.make_env(Count(), "b", one)
    with pytest.raises(EnvError, match="action_names has 2 names for 3 actions"):
        jm.JaxMARLGame(Count(), "b", action_names=("x", "y"))

    class NoLimit(Count):
        max_steps = None  # type: ignore[assignment]

        def __init__(self) -> None:
            pass

    with pytest.raises(EnvError, match=r"NoLimit has no max_steps .* pass episode_len"):
        jm.JaxMARLGame(NoLimit(), "a")

    class Continuous(Count):
        def action_space(self, agent: str) -> Any:
            return Box(0.0, 1.0, (5,))

    with pytest.raises(EnvError, match="only discrete spaces"):
        jm.JaxMARLGame(Continuous(), "a")


# ------------------------------------------------------------------------ the example


def load_example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("jaxmarl_adversary_example", EXAMPLE)
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass needs its module registered
    spec.loader.exec_module(module)
    return module


def test_a_population_directory_plays_through_the_adapter(tmp_path: Path) -> None:
    """A population directory of learned MLP members, one per partner's observation size
    (adversary 8, agent_0 10), loads through the existing loaders for the registered game."""
    from flax.traverse_util import flatten_dict
    from safetensors.numpy import save_file

    from transam import make_env
    from transam.partners.train import MLP

    example = load_example()
    example.register()
    try:
        tensors, members = {}, []
        for name, size in (("adv", 8), ("mate", 10)):
            params = MLP(8, 5).init(jax.random.key(size), jnp.zeros(size))
            flat = flatten_dict(jax.device_get(params), sep="/")
            tensors.update({f"{name}/{k}": np.asarray(v) for k, v in flat.items()})
            members.append(
                {"name": name, "kind": "test", "recipe": "none", "hidden": 8, "act": "argmax"}
            )
        manifest = {
            "env": example.NAME,
            "default": {"members": members, "teams": [{"name": "t", "slots": ["adv", "mate"]}]},
        }
        (tmp_path / "manifest.json").write_text(json.dumps(manifest))
        save_file(tensors, str(tmp_path / "default.safetensors"))

        env = make_env(example.NAME, partners=str(tmp_path))
        assert env.population.team_names == ("t",) and env.spec.other_obs_dims == (10, 10)
        state, _ = env.reset(jax.random.key(0))
        _, ts = env.step(jax.random.key(1), state, jnp.int32(0))
        acts = ts.record.other_actions
        assert acts.shape == (2,) and bool(jnp.all((acts >= 0) & (acts < 5)))
    finally:
        registry.unregister_env(example.NAME)
        sys.modules.pop("jaxmarl_adversary_example", None)


def test_example_trains_and_evaluates(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    example = load_example()
    out = tmp_path / "run"
    tiny = TransAMConfig(context=3, width=16, layers=1, heads=2, ff_width=32)
    try:
        # 50 steps: one collection of 5 rollouts x 5 steps x 2 envs
        argv = ["--steps", "50", "--num-envs", "2", "--episodes", "4", "--out", str(out)]
        found = example.main(argv, model=tiny)
        assert registry.env_title(example.NAME) == "simple_adversary (JaxMARL)"
    finally:
        registry.unregister_env(example.NAME)
        sys.modules.pop("jaxmarl_adversary_example", None)
    assert (out / "final.json").exists()
    assert json.loads((out / "metrics.jsonl").read_text().splitlines()[-1])["step"] == 50
    assert found["env"] == example.NAME and found["method"] == "transam"
    assert math.isfinite(found["return"]["mean"]) and math.isfinite(found["obs_mse"])
    assert set(found["per_partner_return"]) == {"covered", "decoyed", "alone", "lure"}
    printed = capsys.readouterr().out
    assert "vs lure" in printed and "partner probe accuracy" in printed


def test_our_games_import_only_the_jaxmarl_modules_they_use_and_jaxmarl_stays_whole() -> None:
    """Spread, Tag and Overcooked import jaxmarl's modules without its package ``__init__``s
    (which import every environment jaxmarl has: 5 s of each process's start); a later
    ``import jaxmarl`` is the whole package, with the same classes, and prints nothing."""
    code = """if True:
        import sys
        import transam.envs.overcooked, transam.envs.spread, transam.envs.tag
        loaded = [m for m in sys.modules if m.startswith("jaxmarl.environments.s")]
        assert loaded == ["jaxmarl.environments.spaces"], loaded  # not smax, storm...
        from jaxmarl.environments.mpe.simple_spread import SimpleSpreadMPE
        import jaxmarl
        assert type(jaxmarl.make("MPE_simple_spread_v3")) is SimpleSpreadMPE
        from jaxmarl.environments import SMAX, Overcooked
        assert Overcooked is transam.envs.overcooked.Overcooked
        assert jaxmarl.environments.mpe.SimpleSpreadMPE is SimpleSpreadMPE
        print("whole")
    """
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert (done.returncode, done.stdout) == (0, "whole\n"), done.stderr[-2000:]
