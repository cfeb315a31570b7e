"""Aggregation over seeds: one *cell* per (env, method) with per-seed values, mean, std across
seeds and 95% bootstrap CI for every final metric, and mean + CI curves (during training and
within the episode)."""

from __future__ import annotations

from typing import Any

import numpy as np

from transam.reproduce.report.load import ENV_ORDER, METHOD_ORDER, Grid, RunData, order_key
from transam.reproduce.report.stats import curve_ci, interval, stratified_bootstrap

ACC_NEWEST, ACC_ALL = "action_accuracy_newest", "action_accuracy_all_positions"
EVAL_METRICS = (
    "return",
    ACC_NEWEST,
    ACC_ALL,
    "obs_mse",
    "obs_mse_all_positions",
    "obs_norm",
    "z_norm",
)
"""Final metrics read from the final evaluation (a metric a method lacks is absent)."""
FINAL_METRICS = (
    *EVAL_METRICS,
    "heldout_return",
    "probe_accuracy",
    f"trend:{ACC_NEWEST}",
    "trend:accuracy_gain",
    "trend:obs_mse",
)
CURVE_METRICS = ("return", ACC_NEWEST, "obs_mse")
"""Curves of the evaluations during training (``eval/`` in metrics.jsonl)."""
TRAIN_CURVE_METRICS = (ACC_NEWEST, ACC_ALL)
"""Curves of the training batches' metrics (``train/``; the authors chart all-positions)."""
MEMORYLESS_BY_STEP = "memoryless_own_accuracy_by_step"
LEVELS_BY_STEP = (
    (MEMORYLESS_BY_STEP, "one step"),
    ("memoryless_own2_accuracy_by_step", "two steps"),
    ("memoryless_window_accuracy_by_step", "window"),
)
"""The recorded per-step memoryless levels a per-step accuracy curve is drawn against (from the
controlled agent's last one, two and window's observations)."""
"""The recorded level (``transam partners diversity --record``) the accuracy gain is read over."""
PER_STEP_METRICS = ("cum_return", ACC_NEWEST, ACC_ALL, "obs_mse")
SOURCE_EVAL = "final evaluation"
SOURCE_TRAIN = "last training evaluation"


def number(x: Any) -> float | None:
    """A finite float from a number or a {"mean": ...} entry, else None."""
    if isinstance(x, dict):
        x = x.get("mean")
    if isinstance(x, bool) or not isinstance(x, int | float):
        return None
    return float(x) if np.isfinite(x) else None


def _series(x: Any) -> np.ndarray | None:
    """A per-step list as floats (null -> NaN: no episode running at that step), or None."""
    if not isinstance(x, list) or not x:
        return None
    try:
        arr = np.array([np.nan if v is None else v for v in x], dtype=float)
    except (TypeError, ValueError):
        return None
    arr[~np.isfinite(arr)] = np.nan
    return arr if arr.ndim == 1 and np.isfinite(arr).any() else None


def _trend(curve: np.ndarray) -> float | None:
    """Mean of the last quarter of an episode's per-step curve minus that of the first (over
    the steps with a value), or None with fewer than two."""
    values = curve[np.isfinite(curve)]
    if len(values) < 2:
        return None
    q = max(1, len(values) // 4)
    return float(values[-q:].mean() - values[:q].mean())


def run_finals(
    run: RunData, level_by_step: list[float | None] | None = None
) -> dict[str, tuple[float, str]]:
    """The final metrics of a finished run: metric -> (value, source). The final evaluation
    (eval_train.json) is preferred; the last training evaluation (final.json) stands in for a
    run not evaluated yet. ``level_by_step``: the population's memoryless own-view accuracy
    per timestep; with it, ``trend:accuracy_gain`` is the trend of the newest-position
    accuracy above that level (the level itself falls through the episode: early steps are
    easier to predict without history)."""
    out: dict[str, tuple[float, str]] = {}
    if run.status != "finished":
        return out
    ev, last = run.evals.get("train"), run.final or {}
    for metric in EVAL_METRICS:
        value = number(ev.get(metric)) if ev else None
        if value is not None:
            out[metric] = (value, SOURCE_EVAL)
        elif ev is None and (v := number(last.get(f"eval/{metric}"))) is not None:
            out[metric] = (v, SOURCE_TRAIN)
    held = run.evals.get("heldout")
    if held and (v := number(held.get("return"))) is not None:
        out["heldout_return"] = (v, SOURCE_EVAL)
    probe = ev.get("probe") if ev else None
    if isinstance(probe, dict) and (v := number(probe.get("accuracy"))) is not None:
        out["probe_accuracy"] = (v, SOURCE_EVAL)
    per_step = (ev or {}).get("per_step") or {}
    for metric in (ACC_NEWEST, "obs_mse"):
        curve = _series(per_step.get(metric))
        if curve is not None and (trend := _trend(curve)) is not None:
            out[f"trend:{metric}"] = (trend, SOURCE_EVAL)
    curve, level = _series(per_step.get(ACC_NEWEST)), _series(level_by_step)
    if curve is not None and level is not None:
        n = min(len(curve), len(level))
        if (trend := _trend(curve[:n] - level[:n])) is not None:
            out["trend:accuracy_gain"] = (trend, SOURCE_EVAL)
    return out


def stat(values: list[float], seeds: list[int]) -> dict[str, Any]:
    """Mean, std across seeds (ddof 1; 0 for one seed), 95% bootstrap CI, and the values."""
    ci = interval(values)
    std = float(np.std(values, ddof=1)) if len(values) > 1 else 0.0
    return {
        "mean": ci.mean,
        "std": std,
        "lo": ci.lo,
        "hi": ci.hi,
        "n": ci.n,
        "values": list(values),
        "seeds": list(seeds),
    }


def _training_curve(runs: list[RunData], key: str) -> dict[str, Any] | None:
    """Mean + CI of ``key`` (``eval/...`` or ``train/...``) over seeds at each logged step
    (unfinished runs included)."""
    series = []
    for run in runs:
        pts = {
            int(r["step"]): v
            for r in run.metrics
            if isinstance(r.get("step"), int) and (v := number(r.get(key))) is not None
        }
        if pts:
            series.append(pts)
    if not series:
        return None
    steps = sorted(set().union(*series))
    matrix = np.array([[s.get(t, np.nan) for t in steps] for s in series], dtype=float)
    return {"step": steps, **curve_ci(matrix)}


def _episode_curve(curves: list[np.ndarray]) -> dict[str, Any]:
    """Mean + CI over seeds of a per-timestep curve (cut to the shortest seed's length)."""
    length = min(len(c) for c in curves)
    matrix = np.stack([c[:length] for c in curves])
    return {"t": list(range(length)), **curve_ci(matrix)}


def cell(runs: list[RunData], level_by_step: list[float | None] | None = None) -> dict[str, Any]:
    """Everything the report shows for one (env, method), from its runs (``level_by_step``:
    see :func:`run_finals`)."""
    finished = [r for r in runs if r.status == "finished"]
    out: dict[str, Any] = {
        "seeds": [r.seed for r in finished],
        "seeds_unfinished": [r.seed for r in runs if r.status == "unfinished"],
        "seeds_missing": [r.seed for r in runs if r.status == "missing"],
        "seeds_not_evaluated": [r.seed for r in finished if "train" not in r.evals],
        "metrics": {},
    }
    finals = [(r.seed, run_finals(r, level_by_step)) for r in finished]
    for metric in FINAL_METRICS:
        have = [(seed, f[metric]) for seed, f in finals if metric in f]
        if have:
            values = [v for _, (v, _) in have]
            out["metrics"][metric] = stat(values, [s for s, _ in have])
            sources = sorted({src for _, (_, src) in have})
            out["metrics"][metric]["source"] = sources[0] if len(sources) == 1 else "mixed"
    stds = [
        number(r.evals["train"]["return"].get("std"))
        if "train" in r.evals
        else number((r.final or {}).get("eval/return_std"))
        for r in finished
    ]
    stds_ok = [s for s in stds if s is not None]
    out["episode_return_std"] = float(np.mean(stds_ok)) if stds_ok else None
    chances = [
        number(r.evals["train"]["probe"].get("chance"))
        for r in finished
        if isinstance(r.evals.get("train", {}).get("probe"), dict)
    ]
    chances_ok = [c for c in chances if c is not None]
    out["probe_chance"] = float(np.mean(chances_ok)) if chances_ok else None
    notes = [
        r.evals["train"]["probe"]["note"]
        for r in finished
        if isinstance(r.evals.get("train", {}).get("probe"), dict)
        and isinstance(r.evals["train"]["probe"].get("note"), str)
    ]
    out["probe_note"] = notes[0] if notes else None
    out["curves"] = {
        k: curve for k in CURVE_METRICS if (curve := _training_curve(runs, f"eval/{k}")) is not None
    }
    out["train_curves"] = {
        k: curve
        for k in TRAIN_CURVE_METRICS
        if (curve := _training_curve(runs, f"train/{k}")) is not None
    }
    evals = [r.evals["train"] for r in finished if "train" in r.evals]
    series: dict[str, list[np.ndarray]] = {}
    for ev in evals:
        probe_info: dict[str, Any] = ev["probe"] if isinstance(ev.get("probe"), dict) else {}
        lists = {**(ev.get("per_step") or {}), "probe_accuracy": probe_info.get("per_step")}
        for metric in (*PER_STEP_METRICS, "probe_accuracy"):
            if (arr := _series(lists.get(metric))) is not None:
                series.setdefault(metric, []).append(arr)
    out["per_step"] = {metric: _episode_curve(arrs) for metric, arrs in series.items()}
    return out


def cells(
    grid: Grid, levels: dict[str, dict[str, Any] | None]
) -> dict[str, dict[str, dict[str, Any]]]:
    """env -> method -> cell, in the paper's order. ``levels``: the partners' recorded levels
    per env (:func:`~transam.reproduce.report.results.grid_levels`), for the per-step
    memoryless level."""
    groups: dict[tuple[str, str], list[RunData]] = {}
    for run in grid.runs:
        groups.setdefault((run.env, run.method), []).append(run)
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for (env, method), runs in groups.items():
        by_step = (levels.get(env) or {}).get(MEMORYLESS_BY_STEP)
        out.setdefault(env, {})[method] = cell(runs, by_step)
    envs, methods = order_key(ENV_ORDER), order_key(METHOD_ORDER)
    return {e: {m: out[e][m] for m in sorted(out[e], key=methods)} for e in sorted(out, key=envs)}


def aggregates(table: dict[str, dict[str, dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """Per method, the mean over environments of its mean action / probe accuracy (both on a
    0-1 scale; returns are not comparable across envs), with a stratified bootstrap CI (seeds
    resampled within each env)."""
    out: dict[str, dict[str, Any]] = {}
    methods = sorted({m for env in table.values() for m in env}, key=order_key(METHOD_ORDER))
    for metric in (ACC_NEWEST, "probe_accuracy"):
        for method in methods:
            strata = {
                env: env_cells[method]["metrics"][metric]["values"]
                for env, env_cells in table.items()
                if metric in env_cells.get(method, {}).get("metrics", {})
            }
            if not strata:
                continue
            point, lo, hi = stratified_bootstrap(list(strata.values()))
            out.setdefault(metric, {})[method] = {
                "mean": float(point),
                "lo": float(lo),
                "hi": float(hi),
                "envs": list(strata),
                "seeds_per_env": [len(v) for v in strata.values()],
            }
    return out
