"""Accuracy levels of a partner population (``transam partners diversity``): the ceiling
E[max_a pi(a|o)] and the memoryless team-agnostic level, on constructed populations."""

from __future__ import annotations

import shutil
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from transam.compose import make_env
from transam.envs.population import Member, Population, Team
from transam.partners import diversity, learned
from transam.partners.diversity import (
    LevelsConfig,
    action_ceiling,
    collect_partner_steps,
    memoryless_accuracy,
    own_window,
)
from transam.partners.train import select, select_probs
from transam.reproduce.report.results import partner_levels

FIXED = jnp.array([0.7, 0.1, 0.1, 0.05, 0.05])


def fixed_act(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Ignores its observation; draws from FIXED."""
    return jax.random.categorical(key, jnp.log(FIXED)).astype(jnp.int32)


def uniform_act(key: jax.Array, obs: jax.Array) -> jax.Array:
    return jax.random.randint(key, (), 0, 5, dtype=jnp.int32)


def sign_rule(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Deterministic in the observation: +x when its own x position is negative, else -x."""
    return jnp.where(obs[2] < 0, 1, 2).astype(jnp.int32)


def brake_rule(key: jax.Array, obs: jax.Array) -> jax.Array:
    """Deterministic in its own x velocity, which the controlled agent does not observe:
    pushes against it (+x when moving -x), so it oscillates."""
    return jnp.where(obs[0] < 0, 2, 1).astype(jnp.int32)


MEMBERS = [
    Member("rule", sign_rule),  # no declared probabilities: sampled
    Member("brake", brake_rule),
    Member("fixed", fixed_act, probs=lambda obs: FIXED),  # declared: exact
    Member("fixed_sampled", fixed_act),
    Member("uniform", uniform_act),
]


def spread_with(teams: list[tuple[str, str]]) -> object:
    pop = Population("test", MEMBERS, [Team(f"{a}+{b}", (a, b)) for a, b in teams])
    return make_env("spread", population=pop)


def test_ceiling_of_known_members() -> None:
    env = spread_with([("rule", "rule"), ("fixed", "fixed_sampled"), ("uniform", "uniform")])
    steps = collect_partner_steps(env, episodes_per_team=4, seed=0)  # type: ignore[arg-type]
    assert steps.obs.shape == (12, 25, 2, 18) and steps.live.all()
    got = action_ceiling(env.population, steps, num_actions=5, samples=64)  # type: ignore[attr-defined]
    members = got["members"]
    assert members["rule"] == 1.0  # deterministic: both halves agree at every observation
    assert members["fixed"] == pytest.approx(0.7, abs=1e-6)  # from its probabilities
    assert members["fixed_sampled"] == pytest.approx(0.7, abs=0.03)  # by sampling
    assert members["uniform"] == pytest.approx(0.2, abs=0.03)  # no inflation from the max
    assert sorted(got["sampled"]) == ["fixed_sampled", "rule", "uniform"]
    # pooled over teams, slots and steps, teams weighing the same
    want = (2 * 1.0 + 0.7 + members["fixed_sampled"] + 2 * members["uniform"]) / 6
    assert got["ceiling"] == pytest.approx(want, abs=1e-6)


def test_learned_member_probabilities_match_its_action_selection() -> None:
    logits = lambda obs: jnp.array([0.0, 2.0, 0.0, 1.0, 0.0])
    np.testing.assert_allclose(select_probs(logits, "argmax")(None), [0, 1, 0, 0, 0])
    np.testing.assert_allclose(select_probs(logits, "sample")(None), jax.nn.softmax(logits(None)))
    act = select(logits, "argmax")
    assert int(act(jax.random.key(0), None)) == 1
    with pytest.raises(ValueError, match="valid choices: sample, argmax"):
        select_probs(logits, "greedy")


def test_memoryless_level_of_constructed_populations() -> None:
    cfg = LevelsConfig(train_steps=600)
    # Two teams whose members play the same rule of their own observation: ~1.0.
    env = spread_with([("rule", "rule"), ("rule", "rule")])
    steps = collect_partner_steps(env, episodes_per_team=16, seed=1)  # type: ignore[arg-type]
    got = memoryless_accuracy(steps, 5, cfg)
    assert got["accuracy"] > 0.95
    assert got["majority"] < 0.85  # the rule is not one constant action
    # The controlled agent's view holds the partners' positions relative to its own absolute
    # one, so the same rule is readable from it too (a sum of two inputs).
    own = memoryless_accuracy(steps, 5, cfg, view="own")
    assert own["accuracy"] > 0.85 and own["majority"] == got["majority"]
    # Per step: one value per timestep; every episode runs to the time limit, so each step
    # holds the same test samples and the steps' mean is the pooled accuracy.
    assert len(own["by_step"]) == env.spec.episode_len
    assert np.mean(own["by_step"]) == pytest.approx(own["accuracy"], abs=1e-9)
    assert np.median(own["by_step"]) > 0.8  # 16 test samples a step: single steps vary
    with pytest.raises(ValueError, match="view 'theirs'; valid choices: partner, own, own2"):
        memoryless_accuracy(steps, 5, cfg, view="theirs")
    for bad in ("own1", "own0", "own02", "ownx"):  # own1 is "own"; no leading zero
        with pytest.raises(ValueError, match=f"view '{bad}'; valid choices"):
            memoryless_accuracy(steps, 5, cfg, view=bad)
    # A member that ignores its observation and acts uniformly: about 1/5.
    env = spread_with([("uniform", "uniform"), ("uniform", "uniform")])
    steps = collect_partner_steps(env, episodes_per_team=16, seed=2)  # type: ignore[arg-type]
    got = memoryless_accuracy(steps, 5, cfg)
    assert 0.12 < got["accuracy"] < 0.3 and 0.12 < got["majority"] < 0.3
    with pytest.raises(ValueError, match="episodes_per_team"):
        collect_partner_steps(env, episodes_per_team=0, seed=0)  # type: ignore[arg-type]


def test_report_puts_accuracy_beside_recorded_levels(monkeypatch: pytest.MonkeyPatch) -> None:
    from transam.partners import learned
    from transam.reproduce.report import markdown, results

    recorded = {"action_ceiling": 0.84, "memoryless_accuracy": 0.53, "majority_rate": 0.26}
    manifests = {"spread": {"default": {"diversity": {**recorded, "population_digest": "abc"}}}}

    def load(env: str, root: object = None) -> dict:
        if env not in manifests:
            raise FileNotFoundError(env)
        return manifests[env]

    monkeypatch.setattr(learned, "load_manifest", load)
    levels = results.partner_levels(["spread", "tag"])
    assert levels["spread"] is not None and levels["spread"]["action_ceiling"] == 0.84
    assert levels["tag"] is None
    stat = {"mean": 0.41}
    table = {
        e: {"transam": {"metrics": {"action_accuracy_newest": stat}, "seeds": [0]}}
        for e in ("spread", "tag")
    }
    md = "\n".join(markdown._levels_md(table, levels))
    assert "| *ceiling E[max π(a|o)]* | 84.0 | not recorded |" in md
    assert "| *memoryless, team-agnostic* | 53.0 | not recorded |" in md
    assert "| **TransAM** (newest) | 41.0 | 41.0 |" in md and "spread abc" in md


def test_two_step_view_reads_the_partners_velocity() -> None:
    """A rule of the partner's own velocity: readable from its observation and, through the
    change of its relative position, from two of the controlled agent's; not from one."""
    cfg = LevelsConfig(train_steps=1500)
    env = spread_with([("brake", "brake"), ("brake", "brake")])
    steps = collect_partner_steps(env, episodes_per_team=16, seed=3)  # type: ignore[arg-type]
    partner = memoryless_accuracy(steps, 5, cfg)["accuracy"]
    own = memoryless_accuracy(steps, 5, cfg, view="own")["accuracy"]
    own2 = memoryless_accuracy(steps, 5, cfg, view="own2")["accuracy"]
    assert partner > 0.9 and own2 > 0.85
    assert own2 > own + 0.1, (own, own2)


def test_partner_steps_with_a_controlled_policy() -> None:
    """``controlled`` replaces the random controlled agent: one that never moves keeps its
    own velocity (the first two entries of its observation) at zero; a random one does not."""
    env = spread_with([("rule", "rule")])
    still = lambda key, obs: jnp.zeros((), jnp.int32)
    steps = collect_partner_steps(env, 2, seed=0, controlled=still)  # type: ignore[arg-type]
    assert not np.abs(steps.own_obs[:, :, :2]).any()
    steps = collect_partner_steps(env, 2, seed=0)  # type: ignore[arg-type]
    assert np.abs(steps.own_obs[:, :, :2]).any()


def test_own_window_is_the_observation_and_its_successive_changes() -> None:
    """K observations: o_t, then o_t - o_{t-1}, o_{t-1} - o_{t-2}, ..., zero before the
    episode's start; K=1 is the observation alone, K=2 the "own2" view's features."""
    own = (np.arange(8, dtype=np.float64).reshape(2, 4, 1)) ** 2  # [E=2, T=4, D=1]
    np.testing.assert_array_equal(
        own_window(own, 3)[0], [[0, 0, 0], [1, 1, 0], [4, 3, 1], [9, 5, 3]]
    )
    np.testing.assert_array_equal(own_window(own, 3)[1, 0], [16, 0, 0])  # its own episode
    np.testing.assert_array_equal(own_window(own, 1), own)
    assert own_window(np.zeros((3, 5, 7)), 5).shape == (3, 5, 35)


def test_measure_and_record_what_the_diversity_command_prints(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """``transam partners diversity`` is argument checks and printing around
    :func:`diversity.measure` (no cross-play for a population that is not a shipped learned
    split) and :func:`diversity.record` (what --record stores)."""
    levels = diversity.levels_config(episodes_per_team=4, train_steps=50)
    assert levels == LevelsConfig(episodes_per_team=4, train_steps=50)
    assert diversity.levels_config() == LevelsConfig()
    env = make_env("spread", partners="heuristic")
    found = diversity.measure(env, None, window=3, levels=levels)
    assert found.cross_play is None and found.members == [] and found.window == 3
    assert {"others", "local", "chance", "teams"} <= set(found.accuracy)
    assert found.levels["episodes_per_team"] == 4 and found.levels_config == levels
    stored: dict = {}
    monkeypatch.setattr(learned, "record_diversity", lambda *a: stored.update(args=a))
    diversity.record("spread", False, found)
    env_name, split, entry, into = stored["args"]
    assert (env_name, split, entry["window"], into) == ("spread", "default", 3, None)
    assert entry["levels_settings"]["train_steps"] == 50
    # A population directory keeps its own record, where `transam report` finds a grid's
    # levels; the shipped manifest is untouched.
    shipped = (learned.data_dir("spread") / "manifest.json").read_bytes()
    root = tmp_path / "pop"
    shutil.copytree(learned.data_dir("spread"), root)
    monkeypatch.undo()
    assert diversity.record("spread", False, found, root) == root / "manifest.json"
    kept = partner_levels(["spread"], "default", root)["spread"]
    assert kept is not None and kept["memoryless_accuracy"] == entry["memoryless_accuracy"]
    assert kept["memoryless_window_accuracy"] == entry["memoryless_window_accuracy"]
    assert kept["measured_by"].endswith(f"--population {root}")
    assert kept["population_digest"] == learned.population_digest("spread", str(root))
    assert (learned.data_dir("spread") / "manifest.json").read_bytes() == shipped
    # the window level: the MLP on the agent's last `window` observations (TransAM's context)
    assert levels.window == 5 and entry["levels_settings"]["window"] == 5
    window = found.levels["memoryless_window"]
    assert entry["memoryless_window_accuracy"] == round(window, 4)
    assert len(entry["memoryless_window_accuracy_by_step"]) == env.spec.episode_len
