"""The numbers of a report (results.json and marl_eval.json): the aggregated cells of a grid,
the claims with their verdicts, what ran and on what, and the partners' recorded levels.
:mod:`~transam.reproduce.report.markdown` renders them; nothing here formats text for reading.
"""

from __future__ import annotations

import datetime as dt
import shlex
from collections import Counter
from pathlib import Path
from typing import Any

from transam import registry
from transam.reproduce.report import aggregate, claims
from transam.reproduce.report.load import Grid
from transam.reproduce.report.stats import CONFIDENCE, RESAMPLES, RNG_SEED

Table = dict[str, dict[str, dict[str, Any]]]
"""env -> method -> aggregated cell (:func:`~transam.reproduce.report.aggregate.cells`)."""

CI_METHOD = " ".join(
    (
        f"{CONFIDENCE:.0%} percentile bootstrap over seeds: the seeds of each (env, method) are",
        f"resampled with replacement {RESAMPLES:,} times (numpy RNG seed {RNG_SEED}), the mean",
        "is recomputed for each resample, and the interval runs from the 2.5th to the 97.5th",
        "percentile of those means. Where several environments enter one number (the",
        "aggregates) the bootstrap is stratified: seeds are resampled within each environment,",
        "as rliable does. rliable itself is not installable next to this stack, so this is a",
        "numpy implementation of the same method (checked against scipy.stats.bootstrap in the",
        "tests). A claim compares two methods with the bootstrap CI of the difference of their",
        "means (each side's seeds resampled independently). With one seed the interval is the",
        "point itself (marked n=1); with 2-3 seeds a bootstrap interval is crude (with 2 seeds",
        "it is roughly the range of the two values, and it is narrower than a t-interval) and",
        "claims resting on it are weak evidence either way.",
    )
)
"""How the intervals are computed (results.json's ``statistics.description``; the report
quotes it)."""
ACC_NEWEST, ACC_ALL = aggregate.ACC_NEWEST, aggregate.ACC_ALL
FIGURES = {
    "returns": "returns_training.png",
    ACC_NEWEST: "action_accuracy_training.png",
    "episode": "transam_episode.png",
    "probe": "probe_per_step.png",
    "pca": "transam_pca.png",
}
"""The report's figures: key -> file name under report/figures/."""


def grid_seeds(grid: Grid) -> list[int]:
    """The seeds grid.json's runs name (``runs/ENV/METHOD/seed_S``): what ``--seeds`` gave,
    where the budget's ``seeds`` is only the count used without it."""
    return sorted({int(rel.rsplit("seed_", 1)[1]) for rel in grid.expected if "seed_" in rel})


def usual_seeds(table: Table) -> int | None:
    ns = [
        c["metrics"]["return"]["n"]
        for env in table.values()
        for c in env.values()
        if "return" in c["metrics"]
    ]
    return Counter(ns).most_common(1)[0][0] if ns else None


LEVEL_KEYS = ("action_ceiling", "memoryless_accuracy", "majority_rate")
"""What ``transam partners diversity --record`` stores about the partners' actions."""


def partner_levels(
    envs: list[str], split: str = "default", root: Path | None = None
) -> dict[str, dict[str, Any] | None]:
    """Per env, the accuracy levels recorded in its shipped manifest's ``split`` entry (or in
    the population directory ``root``'s manifest) (``diversity``: ceiling, memoryless level,
    majority rate, digest), or None when the manifest has none (not recorded, or no shipped
    population). A manifest that cannot be read is an error naming the file
    (:class:`~transam.partners.learned.ManifestError`), not "none recorded"."""
    from transam.partners.learned import ManifestError, data_dir, load_manifest

    out: dict[str, dict[str, Any] | None] = {}
    for env in envs:
        try:
            manifest = load_manifest(env, root)
        except FileNotFoundError:  # no shipped population
            manifest = {}
        entry = manifest.get(split) or {}
        found = (entry.get("diversity") or {}) if isinstance(entry, dict) else None
        if not isinstance(found, dict):
            path = (root or data_dir(env)) / "manifest.json"
            raise ManifestError(f"partner manifest {path}: its {split!r} entry is damaged")
        ok = all(isinstance(found.get(k), int | float) for k in LEVEL_KEYS)
        keep = (
            *LEVEL_KEYS,
            "memoryless_own_accuracy",
            "memoryless_own2_accuracy",
            aggregate.MEMORYLESS_BY_STEP,
            "memoryless_own2_accuracy_by_step",
            "memoryless_window_accuracy",
            "memoryless_window_accuracy_by_step",
            "population_digest",
            "measured_by",
        )
        out[env] = {k: found.get(k) for k in keep} if ok else None
    return out


def runs_summary(grid: Grid) -> dict[str, Any]:
    by = lambda status: [r.rel for r in grid.runs if r.status == status]
    finished = [r for r in grid.runs if r.status == "finished"]
    return {
        "expected": len(grid.expected),
        "found": len(grid.runs),
        "finished": by("finished"),
        "unfinished": by("unfinished"),
        "missing": by("missing"),
        "not_evaluated_train": [r.rel for r in finished if "train" not in r.evals],
        "not_evaluated_heldout": [r.rel for r in finished if "heldout" not in r.evals],
        "not_in_grid_json": [r.rel for r in grid.runs if r.rel not in grid.expected],
        "problems": {r.rel: r.problems for r in grid.runs if r.problems},
    }


def compute_summary(grid: Grid) -> dict[str, Any]:
    invocations = [i for i in grid.info.get("invocations", []) if isinstance(i, dict)]
    machines: list[dict[str, Any]] = []
    for inv in invocations:
        m = inv.get("machine")
        if isinstance(m, dict) and m not in machines:
            machines.append(m)
    walls = [float(i["wall_s"]) for i in invocations if isinstance(i.get("wall_s"), int | float)]
    # a failure ("runs/ENV/METHOD/seed_S: error") of a run that a later invocation finished is
    # history, not a problem of the grid: counted, not listed
    failures = [f for i in invocations for f in (i.get("failures") or [])]
    finished = {r.rel for r in grid.runs if r.status == "finished"}
    return {
        "commands": [shlex.join(str(a) for a in i["argv"]) for i in invocations if i.get("argv")],
        "invocations": len(invocations),
        "invocations_without_end": sum(1 for i in invocations if i.get("ended") is None),
        "invocations_with_end": len(walls),
        "wall_seconds": sum(walls),
        "run_seconds_from_logs": grid.launch_seconds,
        "failures": [f for f in failures if f.split(":", 1)[0] not in finished],
        "failures_of_finished_runs": sum(f.split(":", 1)[0] in finished for f in failures),
        "machines": machines,
    }


def marl_eval(grid: Grid) -> dict[str, Any]:
    """marl-eval's raw data: env -> task -> algorithm -> run -> step_k {step_count, return
    [...]} and absolute_metrics. metrics.jsonl keeps the mean over an evaluation's episodes,
    not every episode, so each list holds that one mean."""
    data: dict[str, Any] = {}
    for run in grid.runs:
        if run.status == "missing":
            continue
        known = run.env in registry.env_names()
        names = registry.env_entry(run.env).marl_eval if known else None
        env_name, task = names or (run.env, run.env)
        entry: dict[str, Any] = {}
        k = 0
        for rec in run.metrics:
            ret = aggregate.number(rec.get("eval/return"))
            if ret is None or not isinstance(rec.get("step"), int):
                continue
            step = {"step_count": rec["step"], "return": [ret]}
            acc = aggregate.number(rec.get(f"eval/{ACC_NEWEST}"))
            if acc is not None:
                step[ACC_NEWEST] = [acc]
            entry[f"step_{k}"] = step
            k += 1
        finals = aggregate.run_finals(run)
        if finals:
            entry["absolute_metrics"] = {
                m: [finals[m][0]]
                for m in ("return", ACC_NEWEST, ACC_ALL, "heldout_return")
                if m in finals
            }
        if entry:
            algo = data.setdefault(env_name, {}).setdefault(task, {}).setdefault(run.method, {})
            algo[f"run_{run.seed}"] = entry
    return data


def grid_levels(grid: Grid) -> dict[str, dict[str, Any] | None]:
    """The recorded levels of the population each env of ``grid`` trained against: a shipped
    split's, or a population directory's (``transam partners diversity --population DIR
    --record``); None where none are recorded (the scripted population, a directory that is
    gone or holds none)."""
    from transam.partners.learned import is_population_dir

    envs = sorted({r.env for r in grid.runs})
    split = grid.info.get("partners", "default")
    if split in ("default", "heldout"):
        return partner_levels(envs, split)
    if is_population_dir(split):
        return partner_levels(envs, "default", Path(split))
    return {e: None for e in envs}


def build_results(
    grid: Grid,
    table: Table,
    figures: dict[str, str],
    levels: dict[str, dict[str, Any] | None],
) -> dict[str, Any]:
    """results.json of ``grid`` (aggregated into ``table``), naming the ``figures`` drawn
    (``levels``: :func:`grid_levels`)."""
    return {
        "generated": dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "grid": {
            "out": str(grid.out),
            "budget": grid.info.get("budget", "unknown"),
            "budget_settings": grid.info.get("budget_settings", {}),
            "seeds": grid_seeds(grid),
            "partners": grid.info.get("partners", "default"),
            "settings": grid.info.get("settings", {}),
        },
        "compute": compute_summary(grid),
        "runs": runs_summary(grid),
        "statistics": {
            "ci": "percentile bootstrap over seeds",
            "confidence": CONFIDENCE,
            "resamples": RESAMPLES,
            "rng_seed": RNG_SEED,
            "std": "across seeds, ddof 1",
            "description": CI_METHOD,
        },
        "usual_seeds": usual_seeds(table),
        "cells": table,
        "aggregates": aggregate.aggregates(table),
        "partner_levels": {env: levels.get(env) for env in table},
        "claims": claims.evaluate_claims(table),
        "figures": figures,
    }
