"""`transam reproduce --budget smoke` end to end (the session fixture ``smoke_grid`` in
conftest.py): the grid, its evaluations and the report; an interrupted run is resumed from its
checkpoint and finished runs are never redone."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from local_data import SMOKE_ARGS as GRID
from local_data import SMOKE_ENVS as ENVS
from local_data import SMOKE_METHODS as METHODS
from local_data import SMOKE_SEEDS as SEEDS

from transam.cli import main
from transam.reproduce import grid
from transam.rundir import EVAL_PARTNERS, read_metrics


@pytest.fixture(scope="module")
def smoke(smoke_grid: Path) -> Path:
    return smoke_grid


def test_every_run_is_trained_and_evaluated(smoke: Path) -> None:
    specs = grid.grid_specs(ENVS, METHODS, SEEDS)
    for spec in specs:
        run = smoke / spec.rel
        assert (run / "final.json").exists()
        records = read_metrics(run / "metrics.jsonl")
        assert [r["chunk"] for r in records] == list(range(len(records))) and len(records) >= 2
        for rec in records:  # LIAM reconstructs both; NAM has no decoder (absent, not zero)
            assert np.isfinite(rec["eval/return"]) and np.isfinite(rec["train/policy_loss"])
            assert (
                ("eval/action_accuracy_newest" in rec)
                == ("eval/obs_mse" in rec)
                == (spec.method == "liam")
            )
        for partners in EVAL_PARTNERS:
            ev = json.loads((run / f"eval_{partners}.json").read_text())
            assert ev["episodes"] == grid.BUDGETS["smoke"].final_episodes
            assert ("action_accuracy_newest" in ev) == (spec.method == "liam")
            assert "action_accuracy_all_positions" not in ev  # LIAM: one position per z
            assert (run / f"eval_{partners}.png").stat().st_size > 0
    launches = grid.read_launches(smoke, grid.RunSpec("spread", "liam", 1))
    trains = [e for e in launches if e["event"] == "train"]
    assert [(e["resume"], e["start_chunk"]) for e in trains] == [(True, 1)]


def test_report_has_every_artefact(smoke: Path) -> None:
    report = smoke / "report"
    text = (report / "report.md").read_text()
    results = json.loads((report / "results.json").read_text())
    assert "spread" in text and "liam" in text and "nam" in text
    assert "reproduce --budget smoke" in text  # the exact command
    figures = sorted(p.name for p in (report / "figures").glob("*.png"))
    assert figures, "no figures"
    for name in figures:
        assert f"figures/{name}" in text, f"{name} is not linked from report.md"
    assert results


def test_rerun_redoes_nothing(smoke: Path) -> None:
    before = {
        p: p.read_bytes()
        for p in smoke.rglob("*")
        if p.is_file() and p.suffix in (".jsonl", ".msgpack") and "log" not in p.parts
    }
    launches = sum(len(grid.read_launches(smoke, s)) for s in grid.grid_specs(ENVS, METHODS, SEEDS))
    main(["reproduce", "--budget", "smoke", "--out", str(smoke), "--jobs", "1", *GRID])
    after = sum(len(grid.read_launches(smoke, s)) for s in grid.grid_specs(ENVS, METHODS, SEEDS))
    assert after == launches
    for p, data in before.items():
        assert p.read_bytes() == data, f"{p} was rewritten"


def test_an_archived_grid_copied_back_redoes_nothing(smoke: Path, tmp_path: Path) -> None:
    """archive_grid keeps what the report reads of each finished run, not its checkpoints; a
    grid rebuilt from it on a new machine trains and evaluates nothing again."""
    archive = tmp_path / "archive"
    copied = grid.archive_grid(smoke, archive)
    specs = grid.grid_specs(ENVS, METHODS, SEEDS)
    assert copied == sorted(spec.rel for spec in specs)
    assert not list(archive.rglob("checkpoints")) and not list(archive.rglob("*.png"))
    for spec in specs:
        for name in ("config.json", "final.json", "metrics.jsonl", "eval_train.json"):
            assert (archive / spec.rel / name).exists(), (spec.rel, name)
    # A trained but unevaluated run stays out: restored without checkpoints, it could not be
    # evaluated.
    unevaluated = tmp_path / "unevaluated"
    shutil.copytree(smoke, unevaluated, ignore=shutil.ignore_patterns("checkpoints", "tb"))
    (unevaluated / specs[0].rel / "eval_heldout.json").unlink()
    assert specs[0].rel not in grid.archive_grid(unevaluated, tmp_path / "partial")

    restored = tmp_path / "restored"
    shutil.copytree(archive, restored)
    main(["reproduce", "--budget", "smoke", "--out", str(restored), "--jobs", "1", *GRID])
    for spec in specs:
        assert grid.read_launches(restored, spec) == grid.read_launches(smoke, spec)
        assert not (restored / spec.rel / "checkpoints").exists()
    assert (restored / "report" / "report.md").exists()


def test_a_run_with_a_corrupt_newest_checkpoint_resumes_from_the_previous_one(
    smoke: Path, tmp_path: Path
) -> None:
    """The grid's resume goes through train(): a truncated newest checkpoint is moved aside, the
    run retrains from the one before and ends with the same metrics and evaluation."""
    spec = grid.RunSpec("spread", "nam", 0)
    out = tmp_path / "grid"
    shutil.copytree(smoke, out)
    run = out / spec.rel
    newest = run / "checkpoints" / "chunk_000001.msgpack"
    newest.write_bytes(newest.read_bytes()[:500])
    for name in ("final.json", "eval_train.json", "eval_heldout.json"):
        (run / name).unlink()
    summary = grid.run_one(out, spec, grid.BUDGETS["smoke"])
    assert summary["trained"] and summary["evaluated"] == ["train", "heldout"]
    assert (run / "checkpoints" / "chunk_000001.msgpack.corrupt").exists()
    original = smoke / spec.rel
    for name in ("metrics.jsonl", "final.json", "eval_train.json"):
        assert (run / name).read_text() == (original / name).read_text(), name


def test_a_carried_unfinished_run_resumes_on_a_new_machine(smoke: Path, tmp_path: Path) -> None:
    """archive_grid(carry=True) keeps an unfinished run with its newest checkpoint only;
    copied back, the run resumes there and ends as the uninterrupted one did; archived again
    once finished, the carried checkpoint leaves the archive."""
    spec = grid.RunSpec("spread", "nam", 0)
    out = tmp_path / "grid"
    shutil.copytree(smoke, out)
    run = out / spec.rel  # as if stopped after its first chunk
    for name in ("final.json", "eval_train.json", "eval_heldout.json"):
        (run / name).unlink()
    (run / "checkpoints" / "chunk_000001.msgpack").unlink()
    lines = (run / "metrics.jsonl").read_text().splitlines(keepends=True)
    (run / "metrics.jsonl").write_text(lines[0])
    archive = tmp_path / "archive"
    copied = grid.archive_grid(out, archive, carry=True)
    assert f"{spec.rel} (carried)" in copied
    assert [p.name for p in (archive / spec.rel / "checkpoints").iterdir()] == [
        "chunk_000000.msgpack"
    ]
    assert grid.archive_grid(out, tmp_path / "plain") == sorted(
        s.rel for s in grid.grid_specs(ENVS, METHODS, SEEDS) if s != spec
    )
    restored = tmp_path / "restored"
    shutil.copytree(archive, restored)
    summary = grid.run_one(restored, spec, grid.BUDGETS["smoke"])
    assert summary["trained"] and summary["evaluated"] == ["train", "heldout"]
    for name in ("metrics.jsonl", "final.json", "eval_train.json"):
        assert (restored / spec.rel / name).read_text() == (smoke / spec.rel / name).read_text()
    assert spec.rel in grid.archive_grid(restored, archive, carry=True)
    assert not (archive / spec.rel / "checkpoints").exists()


def test_budget_overrides_reevaluate_without_retraining(smoke: Path, tmp_path: Path) -> None:
    """--final-episodes evaluates finished runs again at the new count without training them
    again, and grid.json keeps the count for later invocations that do not give it;
    --total-steps sets a new grid's run length and is refused for one that has another."""
    out = tmp_path / "grid"
    shutil.copytree(smoke, out)
    one = ["--envs", "spread", "--methods", "nam", "--seeds", "0"]
    run = out / grid.RunSpec("spread", "nam", 0).rel
    metrics = (run / "metrics.jsonl").read_bytes()
    main(["reproduce", "--budget", "smoke", "--out", str(out), "--jobs", "1", *one,
          "--final-episodes", "39"])  # fmt: skip
    saved = json.loads((out / "grid.json").read_text())
    assert saved["budget_settings"]["final_episodes"] == 39
    assert grid.grid_budget(saved).final_episodes == 39
    for partners in EVAL_PARTNERS:
        assert json.loads((run / f"eval_{partners}.json").read_text())["episodes"] == 39
    assert (run / "metrics.jsonl").read_bytes() == metrics
    evaluated = (run / "eval_train.json").read_bytes()
    main(["reproduce", "--budget", "smoke", "--out", str(out), "--jobs", "1", *one])
    assert (run / "eval_train.json").read_bytes() == evaluated
    # A grid's run length is fixed once it has runs; a new grid may set its own.
    saved = json.loads((out / "grid.json").read_text())
    with pytest.raises(SystemExit, match="holds a grid with total_steps 1,000"):
        main(["reproduce", "--budget", "smoke", "--out", str(out), *one, "--total-steps", "2000"])
    assert json.loads((out / "grid.json").read_text()) == saved
    spec = grid.RunSpec("spread", "nam", 0)
    changes = {"total_steps": 2000, "evals": 4, "eval_episodes": None}
    budget = grid.grid_budget(
        grid.open_grid(tmp_path / "new", "smoke", [spec], [], "default", changes)
    )
    assert (budget.total_steps, budget.evals, budget.eval_episodes) == (2000, 4, 8)
    assert grid.run_config(spec, budget, tmp_path / "new").total_steps == 2000


def test_vmapped_seeds_write_the_runs_a_grid_writes(smoke: Path, tmp_path: Path) -> None:
    """--vmap-seeds: a method's seeds train as one program; every run directory, evaluation
    and launch record is what the grid writes, and a rerun redoes nothing."""
    out = tmp_path / "vmapped"
    args = ["--budget", "smoke", "--out", str(out), "--jobs", "1", "--methods", "nam"]
    main(["reproduce", *args, "--vmap-seeds", "--envs", *ENVS, "--seeds", *map(str, SEEDS)])
    for seed in SEEDS:
        spec = grid.RunSpec("spread", "nam", seed)
        mine, theirs = out / spec.rel, smoke / spec.rel
        assert sorted(p.name for p in mine.iterdir() if p.name != "checkpoints") == sorted(
            p.name for p in theirs.iterdir() if p.name != "checkpoints"
        )
        records = read_metrics(mine / "metrics.jsonl")
        assert [r["seed"] for r in records] == [seed] * len(read_metrics(theirs / "metrics.jsonl"))
        (train,) = [e for e in grid.read_launches(out, spec) if e["event"] == "train"]
        assert train["vmapped_with"] == list(SEEDS)
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*.json*")}
    main(["reproduce", *args, "--vmap-seeds", "--envs", *ENVS, "--seeds", *map(str, SEEDS)])
    changed = [p for p, t in before.items() if p.stat().st_mtime_ns != t]
    assert all(p.parent == out or "report" in p.parts for p in changed), changed  # grid.json


def test_bad_grid_arguments_fail_before_writing(tmp_path: Path, capsys) -> None:
    out = tmp_path / "g"
    with pytest.raises(SystemExit):
        main(["reproduce", "--budget", "smoke", "--out", str(out), "--methods", "lima"])
    assert "lima" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="distinct"):
        main(["reproduce", "--budget", "smoke", "--out", str(out), "--seeds", "0", "0"])
    with pytest.raises(SystemExit, match="final_episodes must be >= 1, got 0"):
        main(["reproduce", "--budget", "smoke", "--out", str(out), "--final-episodes", "0"])
    with pytest.raises(SystemExit, match="--vmap-seeds runs with --backend local only"):
        main(
            [
                "reproduce",
                "--budget",
                "smoke",
                "--out",
                str(out),
                "--vmap-seeds",
                "--backend",
                "ray",
            ]
        )
    assert not out.exists()


def test_a_grid_with_settings_trains_every_run_with_them_and_reports_them(tmp_path: Path) -> None:
    """--set changes a setting in every run of a new grid (each run's config.json has it), a
    later invocation without it keeps it, and the report says so."""
    out = tmp_path / "scaled"
    one = ["--budget", "smoke", "--out", str(out), "--jobs", "1", "--envs", "spread"]
    one += ["--methods", "nam", "--seeds", "0"]
    main(["reproduce", *one, "--set", "a2c.ent_coef=0.02", "a2c.hidden=64"])
    config = json.loads((out / grid.RunSpec("spread", "nam", 0).rel / "config.json").read_text())
    assert (config["a2c"]["ent_coef"], config["a2c"]["hidden"]) == (0.02, 64)
    main(["reproduce", *one])  # resumes the grid as it was made: nothing to redo
    assert grid.grid_settings(out) == {"a2c.ent_coef": 0.02, "a2c.hidden": 64}
    results = json.loads((out / "report" / "results.json").read_text())
    assert results["grid"]["settings"] == {"a2c.ent_coef": 0.02, "a2c.hidden": 64}
    assert "**a2c.ent_coef=0.02**, **a2c.hidden=64**" in (out / "report" / "report.md").read_text()
