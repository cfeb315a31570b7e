"""``transam evaluate``: the final evaluation JSON, figure and projection of a run, the linear
partner probe and the run-directory handling.

The runs are the smoke grid's (conftest.py): LIAM on Spread (a decoder and a recurrent
embedding) and NAM (neither), 1000 steps in two chunks; the evaluations here use the grid's
episode count, so their program is the one the grid compiled.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import jax
import numpy as np
import pytest

from transam.cli import Evaluate, Export, _print_showcase
from transam.compose import make_env
from transam.evaluation import final, showcase, weights
from transam.evaluation.final import (
    balanced_partners,
    evaluate_run,
    evaluate_starts,
    population_for,
)
from transam.evaluation.probe import linear_probe, pca_2d, stratified_split
from transam.evaluation.weights import export_run
from transam.models.base import ACC_NEWEST
from transam.partners import learned
from transam.reproduce import grid
from transam.reproduce.report.results import partner_levels
from transam.rundir import evaluation_path, load_run_config, read_metrics, write_json
from transam.train.config import ConfigError

EPISODES = grid.BUDGETS["smoke"].final_episodes  # 26: the grid's own size, compiled once


@pytest.fixture(scope="module")
def run_dir(smoke_grid: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the smoke grid's LIAM run (a decoder and a recurrent embedding)."""
    out = tmp_path_factory.mktemp("liam") / "run"
    shutil.copytree(smoke_grid / "runs/spread/liam/seed_0", out)
    return out


@pytest.fixture(scope="module")
def result(run_dir: Path) -> dict[str, Any]:
    return evaluate_run(run_dir, episodes=EPISODES)


# ------------------------------------------------------------------ probe, split, projection


def test_probe_recovers_a_planted_partner_signal_and_not_noise() -> None:
    rng = np.random.default_rng(0)
    t, n, d, m = 3, 120, 16, 6
    labels = balanced_partners(n, m)
    noise = rng.normal(size=(t, n, d))
    planted = noise * 0.2
    planted[..., :m] += np.eye(m)[labels]
    live = np.ones((t, n))
    good = linear_probe(planted, live, labels, seed=0)
    assert good["accuracy"] > 0.95 and len(good["per_step"]) == t
    assert good["chance"] == pytest.approx(1 / m) and good["train_episodes"] == 60
    bad = linear_probe(noise, live, labels, seed=0)
    assert bad["accuracy"] < 0.35  # chance 1/6; 180 test predictions
    # Dead episodes are left out; a step where every test episode is dead is not scored.
    live[2, :] = 0.0
    partial = linear_probe(planted, live, labels, seed=0)
    assert partial["per_step"][2] is None
    assert partial["accuracy"] == pytest.approx(np.mean(partial["per_step"][:2]))


def test_stratified_split_halves_every_class_deterministically() -> None:
    labels = np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 2, 2, 2, 2])
    train, test = stratified_split(labels, seed=3)
    assert set(train).isdisjoint(test) and len(train) + len(test) == len(labels)
    for c in range(3):
        assert abs((labels[train] == c).sum() - (labels[test] == c).sum()) <= 1
    again = stratified_split(labels, seed=3)
    assert np.array_equal(train, again[0]) and np.array_equal(test, again[1])


def test_pca_finds_the_planted_plane() -> None:
    rng = np.random.default_rng(1)
    plane = rng.normal(size=(50, 2)) * [5.0, 2.0]
    x = plane @ rng.normal(size=(2, 8)) + 0.01 * rng.normal(size=(50, 8))
    coords, ratio = pca_2d(x)
    assert coords.shape == (50, 2) and sum(ratio) > 0.999 and ratio[0] > ratio[1]


def test_population_mapping() -> None:
    assert population_for("default", "train") == "default"
    assert population_for("default", "heldout") == "heldout"
    assert population_for("heldout", "heldout") == "default"
    assert population_for("heuristic", "heldout") == "heldout"
    with pytest.raises(ConfigError, match="valid choices: train, heldout"):
        population_for("default", "test")


# ------------------------------------------------------------------ run directories


def test_config_round_trip_and_multi_seed_dirs(run_dir: Path, tmp_path: Path) -> None:
    saved = json.loads((run_dir / "config.json").read_text())
    cfg = load_run_config(run_dir)
    assert cfg.identity() == saved and cfg.out == str(run_dir)
    hash(cfg)  # rebuilt nested dataclasses, tuples for lists: usable as a cache key

    multi = tmp_path / "multi"
    multi.mkdir()
    write_json(multi / "config.json", {**saved, "seed": 3, "num_seeds": 2})
    with pytest.raises(ConfigError, match=r"seed_3.*seed_4"):
        load_run_config(multi)
    (multi / "seed_4").mkdir()
    one = load_run_config(multi / "seed_4")
    assert (one.seed, one.num_seeds, one.out) == (4, 1, str(multi / "seed_4"))
    with pytest.raises(ConfigError, match="its seeds: 3, 4"):
        load_run_config(multi / "seed_7")
    with pytest.raises(ConfigError, match=r"no config\.json"):
        load_run_config(tmp_path)
    write_json(multi / "config.json", {**saved, "colour": "red"})
    with pytest.raises(ConfigError, match="unknown setting"):
        load_run_config(multi)
    # A run written before the policy clock and the z-free critic existed loads without
    # either (its checkpoints hold the reference policy); one that names them keeps its values.
    old = tmp_path / "old"
    old.mkdir()
    a2c = {k: v for k, v in saved["a2c"].items() if k not in ("time_feature", "critic_z")}
    write_json(old / "config.json", {**saved, "a2c": a2c})
    assert load_run_config(old).a2c.time_feature is False
    assert load_run_config(old).a2c.critic_z is True
    assert (cfg.a2c.time_feature, cfg.a2c.critic_z) == (True, True)  # the defaults: with the clock


# ------------------------------------------------------------------ the evaluation of a run


def test_result_schema_and_files(run_dir: Path, result: dict[str, Any]) -> None:
    T = 25  # Spread's episode length
    assert (result["env"], result["method"], result["seed"]) == ("spread", "liam", 0)
    assert (result["partners"], result["population"]) == ("train", "default")
    assert result["checkpoint"] == "checkpoints/chunk_000001.msgpack"  # the newest
    assert result["step"] == read_metrics(run_dir / "metrics.jsonl")[-1]["step"] == 1000
    assert result["episodes"] == EPISODES
    assert np.isfinite(result["return"]["mean"]) and result["return"]["std"] > 0
    assert 0.0 <= result["action_accuracy_newest"] <= 1.0 and result["obs_mse"] > 0
    per = result["per_step"]
    assert {len(per[k]) for k in ("cum_return", "action_accuracy_newest", "obs_mse")} == {T}
    # The policy's entropy per step lies in (0, ln 5]; its mean is the mean of the curve.
    assert min(per["policy_entropy"]) > 0.0 and max(per["policy_entropy"]) <= np.log(5) + 1e-6
    assert result["policy_entropy"] == pytest.approx(np.mean(per["policy_entropy"]), rel=1e-6)
    assert per["cum_return"][-1] == pytest.approx(result["return"]["mean"], rel=1e-9)
    # Spread's rewards are negative every step: the cumulative reward falls.
    assert all(b < a for a, b in zip(per["cum_return"], per["cum_return"][1:], strict=False))
    freq = result["action_frequency"]
    assert len(freq) == 5 and sum(freq) == pytest.approx(1.0) and min(freq) > 0.0  # sampled
    teams = make_env("spread").population.team_names
    assert list(result["per_partner_return"]) == list(teams)  # balanced: every partner plays
    probe = result["probe"]
    assert 0.0 <= probe["accuracy"] <= 1.0 and len(probe["per_step"]) == T
    assert probe["chance"] == pytest.approx(1 / 13)
    assert probe["train_episodes"] == probe["test_episodes"] == 13
    assert probe["features"] == "embedding z_t (dim 128)"
    assert len(result["pca"]["explained_variance"]) == 2
    assert result["notes"] == []
    assert result["population_digest"] == result["trained_population_digest"]
    assert result["population_digest"] == learned.digest("spread")

    path = evaluation_path(run_dir, "train")
    assert json.loads(path.read_text()) == result
    assert path.with_suffix(".png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    pca = np.load(run_dir / "eval_train_pca.npz")
    assert pca["coords"].shape == (EPISODES, 2)
    assert np.array_equal(pca["partner"], balanced_partners(EPISODES, 13))
    assert list(pca["team_names"]) == list(teams) and set(pca["t"]) == {T - 1}


def test_same_seed_same_json_other_seed_other_episodes(
    run_dir: Path, result: dict[str, Any], tmp_path: Path
) -> None:
    assert evaluate_run(run_dir, episodes=EPISODES) == result
    shutil.copytree(run_dir, tmp_path / "run")  # keep the seed-0 files for the other tests
    other = evaluate_run(tmp_path / "run", episodes=EPISODES, seed=1)
    assert other["return"]["mean"] != result["return"]["mean"]


def test_heldout_partners(run_dir: Path, result: dict[str, Any]) -> None:
    held = evaluate_run(run_dir, episodes=EPISODES, partners="heldout")
    assert (held["partners"], held["population"], held["trained_partners"]) == (
        "heldout",
        "heldout",
        "default",
    )
    assert held["population_name"] == "spread-heldout"
    assert held["population_digest"] == learned.digest("spread", "heldout")
    assert held["trained_population_digest"] == learned.digest("spread")
    teams = make_env("spread", partners="heldout").population.team_names
    assert list(held["per_partner_return"]) == list(teams)
    assert evaluation_path(run_dir, "heldout").exists()
    assert json.loads(evaluation_path(run_dir, "train").read_text()) == result  # untouched


def test_a_changed_population_is_noted(run_dir: Path, tmp_path: Path) -> None:
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    write_json(copy / "partners.json", {"env": "spread", "partners": "default", "digest": "0"})
    noted = evaluate_run(copy, episodes=EPISODES)
    assert noted["trained_population_digest"] == "0"
    assert any("trained against population 0" in n for n in noted["notes"]), noted["notes"]


def test_named_checkpoint_and_bad_names(run_dir: Path, tmp_path: Path) -> None:
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    first = evaluate_run(copy, episodes=EPISODES, checkpoint="chunk_000000.msgpack")
    assert first["checkpoint"] == "checkpoints/chunk_000000.msgpack" and first["step"] == 500
    assert evaluate_run(copy, episodes=EPISODES, checkpoint="0") == first
    with pytest.raises(ConfigError, match=r"'7' not found.*chunk_000000.msgpack, chunk_000001"):
        evaluate_run(copy, episodes=EPISODES, checkpoint="7")
    with pytest.raises(ConfigError, match="episodes must be an integer >= 2"):
        evaluate_run(copy, episodes=1)
    with pytest.raises(ConfigError, match="unknown partners 'test'"):
        evaluate_run(copy, partners="test")  # type: ignore[arg-type]
    shutil.rmtree(copy / "checkpoints")
    with pytest.raises(ConfigError, match="no checkpoints"):
        evaluate_run(copy, episodes=EPISODES)


def test_a_corrupt_newest_checkpoint_falls_back_to_the_previous_one(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    newest = copy / "checkpoints" / "chunk_000001.msgpack"
    newest.write_bytes(newest.read_bytes()[:-100])  # truncated
    capsys.readouterr()
    res = evaluate_run(copy, episodes=EPISODES)
    assert res["checkpoint"] == "checkpoints/chunk_000000.msgpack" and res["step"] == 500
    assert "chunk_000001.msgpack failed verification" in capsys.readouterr().err
    assert any("chunk_000001.msgpack failed verification" in n for n in res["notes"])
    assert newest.exists()  # evaluation reports it and leaves it where it is
    with pytest.raises(ConfigError, match=r"chunk_000001\.msgpack failed verification"):
        evaluate_run(copy, episodes=EPISODES, checkpoint="1")  # named: no silent fallback


def test_cli_prints_a_summary(
    run_dir: Path, result: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    Evaluate(str(run_dir), episodes=EPISODES).run()
    out = capsys.readouterr().out
    assert "partner probe accuracy" in out and "eval_train.json" in out


def test_a_run_played_from_given_starts_is_its_evaluation_on_those_episodes(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Starts taken from the resets ``evaluate_run`` plays with seed 2 give exactly its
    per-episode returns; another seed then samples other actions on the same starts."""

    from transam.train.programs import env_and_model

    env = env_and_model(load_run_config(run_dir))[0]
    team = balanced_partners(EPISODES, env.num_partners)
    k_reset, _ = jax.random.split(jax.random.key(2))
    states, _ = jax.vmap(env.reset)(jax.random.split(k_reset, EPISODES), team)
    path = tmp_path / "theirs.npz"
    np.savez(path, positions=np.asarray(states.game.p_pos), team=team, group=team % 2)
    res = evaluate_starts(run_dir, path, seed=2, out=tmp_path)
    expected = final.paired_random_returns(run_dir, EPISODES, seed=2)[0]
    np.testing.assert_allclose(res["returns"], expected, rtol=1e-6)
    assert res["team"] == team.tolist() and sorted(res["per_group"]) == [0, 1]
    assert res["return"]["mean"] == pytest.approx(np.mean(expected))
    assert {"action_accuracy_newest", "policy_entropy"} <= set(res)
    on_disk = json.loads((tmp_path / "eval_starts-theirs.json").read_text())
    assert on_disk["returns"] == res["returns"] and on_disk["step"] == res["step"]
    other = evaluate_starts(run_dir, path, seed=3, out=tmp_path)["returns"]
    assert not np.allclose(other, expected)
    Evaluate(str(run_dir), starts=str(path), out=str(tmp_path)).run()
    assert "group 1" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="--starts plays the run's own partners"):
        Evaluate(str(run_dir), starts=str(path), partners="heldout").run()


def test_no_dropout_changes_only_the_acting_and_keeps_the_run_evaluation(
    run_dir: Path, result: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--no-dropout``: the shipped TransAM (dropout in its encoder, act_dropout on) acts
    without it into eval_train-nodropout.*, beside its own evaluation, which it leaves as it
    was; for LIAM (no dropout) it changes no number and says so."""
    name = "spread-transam"
    base = evaluate_run(name, EPISODES, seed=3, out=tmp_path)
    on_disk = evaluation_path(tmp_path, "train").read_text()
    off = evaluate_run(name, EPISODES, seed=3, out=tmp_path, dropout=False)
    assert (base["act_dropout"], off["act_dropout"]) == (True, False)
    assert off[ACC_NEWEST] != base[ACC_NEWEST] and off["probe"] != base["probe"]
    assert any("without the agent model's dropout" in n for n in off["notes"]), off["notes"]
    assert evaluation_path(tmp_path, "train").read_text() == on_disk  # untouched
    assert json.loads(evaluation_path(tmp_path, "train", dropout=False).read_text()) == off
    assert (tmp_path / "eval_train-nodropout_pca.npz").exists()
    assert evaluate_run(name, EPISODES, seed=3, out=tmp_path, dropout=False) == off

    env = make_env("spread")
    team = balanced_partners(EPISODES, env.num_partners)
    states, _ = jax.vmap(env.reset)(jax.random.split(jax.random.key(5), EPISODES), team)
    starts = tmp_path / "theirs.npz"
    np.savez(starts, positions=np.asarray(states.game.p_pos), team=team, group=team % 2)
    played = evaluate_starts(name, starts, seed=3, out=tmp_path, dropout=False)
    assert played["act_dropout"] is False
    assert (tmp_path / "eval_starts-theirs-nodropout.json").exists()
    assert not (tmp_path / "eval_starts-theirs.json").exists()

    liam = tmp_path / "liam"
    shutil.copytree(run_dir, liam)
    same = evaluate_run(liam, episodes=EPISODES, dropout=False)
    for key in ("return", ACC_NEWEST, "obs_mse", "probe", "per_step"):
        assert same[key] == result[key], key
    assert same["act_dropout"] is result["act_dropout"] is False
    assert any("changes nothing here: liam" in n for n in same["notes"]), same["notes"]
    Evaluate(str(liam), episodes=EPISODES, no_dropout=True).run()
    assert "eval_train-nodropout.json" in capsys.readouterr().out.replace("\n", "")


def test_nam_has_no_decoder_metrics_and_no_probe(smoke_grid: Path, tmp_path: Path) -> None:
    run = tmp_path / "nam"
    shutil.copytree(smoke_grid / "runs/spread/nam/seed_0", run)
    res = evaluate_run(run, episodes=EPISODES)
    for key in ("action_accuracy_newest", "action_accuracy_all_positions", "obs_mse", "probe"):
        assert key not in res
    assert "pca" not in res
    assert set(res["per_step"]) == {"cum_return", "policy_entropy", "obs_norm", "z_norm"}
    assert res["step"] == 1000
    # NAM's z is its previous action, one-hot: |z| 0 at the first step, 1 after.
    assert res["per_step"]["z_norm"][0] == 0.0
    np.testing.assert_allclose(res["per_step"]["z_norm"][1:], 1.0, rtol=1e-6)
    assert any("no learned embedding" in note for note in res["notes"])
    assert not (run / "eval_train_pca.npz").exists()
    assert (run / "eval_train.png").exists()


# ------------------------------------------------------------------ pretrained runs


def test_a_pretrained_export_evaluates_exactly_as_its_checkpoint(
    run_dir: Path, result: dict[str, Any], tmp_path: Path
) -> None:
    pre = tmp_path / "pre"
    card = export_run(run_dir, pre)
    assert (card["step"], card["checkpoint"]) == (1000, "checkpoints/chunk_000001.msgpack")
    assert sorted(p.name for p in pre.iterdir()) == [
        "card.json",
        "config.json",
        "params.safetensors",
        "partners.json",
    ]
    newest = run_dir / "checkpoints" / "chunk_000001.msgpack"
    assert (pre / "params.safetensors").stat().st_size < newest.stat().st_size / 2
    res = evaluate_run(pre, episodes=EPISODES, out=tmp_path / "ev")
    assert not (pre / "eval_train.json").exists()  # outputs in --out only
    assert (tmp_path / "ev" / "eval_train.png").exists()
    same = {k: v for k, v in result.items() if k not in ("checkpoint", "notes")}
    assert {k: v for k, v in res.items() if k not in ("checkpoint", "notes")} == same
    assert res["checkpoint"] == "params.safetensors" and res["notes"] == result["notes"]
    with pytest.raises(ConfigError, match="pretrained run: it has no --checkpoint"):
        evaluate_run(pre, episodes=EPISODES, checkpoint="0", out=tmp_path / "ev")
    with pytest.raises(ConfigError, match="exists and is not a pretrained run"):
        Export(str(run_dir), str(tmp_path / "ev")).run()  # would replace other files


def test_a_pretrained_run_whose_settings_do_not_fit_its_weights_is_refused(
    run_dir: Path, tmp_path: Path
) -> None:
    pre = tmp_path / "pre"
    Export(str(run_dir), str(pre)).run()
    saved = json.loads((pre / "config.json").read_text())
    saved["baseline"]["hidden"] *= 2
    write_json(pre / "config.json", saved)
    with pytest.raises(
        ConfigError,
        match=r"params.safetensors: the model parameters do not fit|"
        r"params.safetensors: model/.* has shape",
    ):
        evaluate_run(pre, episodes=EPISODES, out=tmp_path / "ev")


def test_unknown_pretrained_name_lists_the_shipped_ones(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"no run directory 'spread-nope'.*shipped pretrained"):
        evaluate_run("spread-nope", episodes=EPISODES, out=tmp_path / "ev")


def test_the_demo_shows_each_shipped_run_beside_random_play_and_the_levels(
    run_dir: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    shipped = tmp_path / "package"
    export_run(run_dir, shipped / "spread-liam")
    export_run(run_dir, shipped / "other-env")
    card = json.loads((shipped / "other-env" / "card.json").read_text())
    write_json(shipped / "other-env" / "card.json", {**card, "env": "tag"})
    liam_card = json.loads((shipped / "spread-liam" / "card.json").read_text())
    write_json(shipped / "spread-liam" / "card.json", {**liam_card, "summary": "how it trained"})
    monkeypatch.setattr(weights, "PRETRAINED_DIR", shipped)
    monkeypatch.chdir(tmp_path)  # the outputs go to runs/pretrained/NAME
    assert weights.pretrained_names() == ["other-env", "spread-liam"]
    assert showcase.shipped_for("spread") == ["spread-liam"]
    _print_showcase("spread", EPISODES)
    text = capsys.readouterr().out
    for row in ("spread-liam", "random agent", "landmark rule", "memoryless", "by step"):
        assert row in text, row
    # the per-step table holds the population's per-step level under the accuracy row
    recorded = partner_levels(["spread"])["spread"]
    assert recorded is not None
    level = recorded["memoryless_own_accuracy_by_step"]
    assert re.search(rf"memoryless\s*│\s*{level[0]:.2f}\s*│", text)
    level2 = recorded["memoryless_own2_accuracy_by_step"]  # and the two-step level beneath
    assert re.search(rf"2 steps\s*│\s*{level2[0]:.2f}\s*│", text)
    assert f"{recorded['memoryless_own2_accuracy']:.3f}" in text
    assert "spread-liam: how it trained" in text  # budgets and settings differ between runs
    res = json.loads((tmp_path / "runs/pretrained/spread-liam/eval_train.json").read_text())
    assert f"{res['return']['mean']:.4g}" in text
    trained, random = final.paired_random_returns("spread-liam", EPISODES)
    np.testing.assert_allclose(res["returns"], trained, rtol=1e-6)  # the same episodes
    assert trained.mean() == pytest.approx(res["return"]["mean"])
    assert f"{random.mean():.4g}" in text and random.mean() != trained.mean()
    assert f"{(trained - random).mean():+.2f}" in text
    assert weights.resolve_run("spread-liam") == shipped / "spread-liam"
    assert weights.is_shipped(shipped / "spread-liam") and not weights.is_shipped(run_dir)
