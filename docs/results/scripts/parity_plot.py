"""Our TransAM runs against the authors' measured learning curve on Spread.

For each run directory (one seed, or ``seed_S/`` subdirectories of a multi-seed run): the
evaluation return and the evaluation partner-action accuracy (newest window position) by
training step, mean over seeds with a 95% t-interval, over the authors' curve
(``curve.csv``: ``eval_return``, ``eval_action_accuracy_newest``, ``policy_entropy``; several,
one per seed of their script, give their mean and 95% t-interval). Writes
``parity.png`` and ``parity.md`` (the window 400k-625k steps, where their curve levels off, the
first evaluation, and every 50k-step evaluation side by side, so unfinished runs compare too)
into ``--out``, and ``curves.csv``: every evaluation of every seed of every run (label, seed,
step and the metrics), so the figure can be redrawn and compared without the run directories,
which are not part of the repository: a run given as ``LABEL=path/curves.csv`` is read from
such a file (its rows with that label).

    python docs/results/scripts/parity_plot.py --out docs/results/parity \
        "authors loop=runs/parity/authors" "our defaults=runs/parity/defaults"
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262}
"""Two-sided 95% t quantiles by degrees of freedom (1.96 beyond)."""

METRICS = (
    ("eval/return", "eval_return", "evaluation return"),
    (
        "eval/action_accuracy_newest",
        "eval_action_accuracy_newest",
        "partner-action accuracy (newest)",
    ),
    ("train/entropy", "policy_entropy", "policy entropy (training)"),
)
"""(our metrics key, the authors' curve.csv column, title); the table uses the first two."""
EVERY = 50_000
"""Step spacing of the per-evaluation table."""
WINDOW = (400_000, 625_000)


CSV_KEYS = ("eval/return", "eval/action_accuracy_newest", "train/entropy", "eval/policy_entropy")
"""The metrics kept in curves.csv (a column each, named after the key)."""


def seed_records(run: Path, label: str = "") -> list[list[dict[str, Any]]]:
    """metrics.jsonl records of each seed of the run in ``run`` (or, for a curves.csv, the
    rows labelled ``label``)."""
    if run.suffix == ".csv":
        seeds: dict[str, list[dict[str, Any]]] = {}
        with run.open() as f:
            for r in csv.DictReader(f):
                if r["label"] == label:
                    rec = {"step": int(r["step"])}
                    rec.update({k: float(r[k]) for k in CSV_KEYS if r.get(k) not in ("", None)})
                    seeds.setdefault(r["seed"], []).append(rec)
        if not seeds:
            raise SystemExit(f"no rows labelled {label!r} in {run}")
        return list(seeds.values())
    files = sorted(run.glob("seed_*/metrics.jsonl")) or [run / "metrics.jsonl"]
    out = []
    for f in files:
        if f.exists():
            lines = [json.loads(x) for x in f.read_text().splitlines() if x.strip()]
            out.append(lines)
    if not out:
        raise SystemExit(f"no metrics.jsonl in {run}")
    return out


def mean_ci(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean over axis 0 and the half-width of its 95% t-interval (0 for one seed)."""
    n = values.shape[0]
    with warnings.catch_warnings():  # all-NaN columns (a window the runs did not reach)
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(values, axis=0)
        if n < 2:
            return mean, np.zeros_like(mean)
        t = T975.get(n - 1, 1.96)
        return mean, t * np.nanstd(values, axis=0, ddof=1) / math.sqrt(n)


def by_step(seeds: list[list[dict[str, Any]]], key: str) -> tuple[np.ndarray, np.ndarray]:
    """(steps every seed reached, values [seeds, steps])."""
    common = sorted(set.intersection(*({r["step"] for r in s} for s in seeds)))
    table = [{r["step"]: r.get(key) for r in s} for s in seeds]
    values = np.array([[np.nan if t[x] is None else t[x] for x in common] for t in table])
    return np.array(common), values


def read_curves(paths: list[Path]) -> dict[str, np.ndarray]:
    """The authors' curves (one curve.csv per seed) as {column: [seeds, steps]} over the
    controlled steps every seed reached."""
    seeds = []
    for path in paths:
        with open(path) as f:
            rows = list(csv.DictReader(f))
        seeds.append({int(float(r["controlled_steps"])): r for r in rows})
    steps = sorted(set.intersection(*(set(s) for s in seeds)))
    columns = [k for k in seeds[0][steps[0]] if k != "controlled_steps"]
    out = {k: np.array([[float(s[x][k]) for x in steps] for s in seeds]) for k in columns}
    out["controlled_steps"] = np.array(steps)
    return out


def window_mean(steps: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Each seed's mean over the evaluations inside WINDOW (NaN where there are none)."""
    inside = (steps >= WINDOW[0]) & (steps <= WINDOW[1])
    if not inside.any():
        return np.full(values.shape[0], np.nan)
    return np.nanmean(values[:, inside], axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="LABEL=RUN_DIR")
    parser.add_argument(
        "--curve",
        type=Path,
        nargs="+",
        required=True,
        help="the authors' curve.csv (one per seed of their script: mean and 95%% CI)",
    )
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument(
        "--title", default="TransAM on Spread: ours (mean, 95% CI over seeds) vs the authors' loop"
    )
    args = parser.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curve = read_curves(args.curve)
    n_theirs = len(args.curve)
    theirs_label = f"authors ({n_theirs} seed{'s' if n_theirs > 1 else ''})"
    runs = {}
    for spec in args.runs:
        label, _, path = spec.partition("=")
        runs[label] = seed_records(Path(path), label)
    args.out.mkdir(parents=True, exist_ok=True)
    write_curves(args.out / "curves.csv", runs)

    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    rows = []
    for ax, (key, column, title) in zip(axes, METRICS, strict=True):
        if column in curve:
            steps = curve["controlled_steps"]
            mean, ci = mean_ci(curve[column])
            ax.plot(steps, mean, "k-", lw=1.5, label=theirs_label)
            if n_theirs > 1:
                ax.fill_between(steps, mean - ci, mean + ci, color="k", alpha=0.12)
        for label, seeds in runs.items():
            steps, values = by_step(seeds, key)
            if not len(steps) or np.isnan(values).all():
                continue
            mean, ci = mean_ci(values)
            (line,) = ax.plot(steps, mean, lw=1.5, label=f"{label} ({len(seeds)} seeds)")
            ax.fill_between(steps, mean - ci, mean + ci, color=line.get_color(), alpha=0.2)
        ax.set_title(title)
        ax.set_xlabel("controlled-agent steps")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(args.title)
    fig.tight_layout()
    fig.savefig(args.out / "parity.png", dpi=120)

    c_steps = curve["controlled_steps"]
    for label, seeds in [("authors (curve.csv)", None), *runs.items()]:
        row = [label, str(n_theirs) if seeds is None else str(len(seeds))]
        for key, column, _ in METRICS[:2]:
            if seeds is None:
                first = mean_ci(curve[column][:, :1])
                win = mean_ci(window_mean(c_steps, curve[column])[:, None])
                row += [_pm(first[0][0], first[1][0]), _pm(win[0][0], win[1][0])]
                continue
            steps, values = by_step(seeds, key)
            if not len(steps):
                row += ["-", "-"]
                continue
            f_mean, f_ci = mean_ci(values[:, :1])
            w_mean, w_ci = mean_ci(window_mean(steps, values)[:, None])
            row += [_pm(f_mean[0], f_ci[0]), _pm(w_mean[0], w_ci[0])]
        rows.append(row)
    head = [
        "run",
        "seeds",
        "return, first eval",
        "return, 400k-625k",
        "accuracy, first eval",
        "accuracy, 400k-625k",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    note = (
        "\n\nMean over seeds ± 95% t-interval; '400k-625k' is each seed's mean over its "
        "evaluations in that window (nan: the runs did not reach it). Figure: parity.png.\n"
    )
    lines += ["", *step_table(curve, runs)]
    (args.out / "parity.md").write_text("\n".join(lines) + note)
    print("\n".join(lines))
    print(f"wrote {args.out / 'parity.png'} and {args.out / 'parity.md'}")


def write_curves(path: Path, runs: dict[str, list[list[dict[str, Any]]]]) -> None:
    """Every evaluation of every seed of every run, one row each."""
    rows = []
    for label, seeds in runs.items():
        for i, records in enumerate(seeds):
            for r in records:
                if "eval/return" in r:
                    vals = [r.get(k, "") for k in CSV_KEYS]
                    rows.append([label, i, r["step"], *vals])
    tmp = path.with_suffix(".tmp")  # the input may be this very file
    with tmp.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["label", "seed", "step", *CSV_KEYS])
        w.writerows(rows)
    tmp.replace(path)


def step_table(curve: dict[str, np.ndarray], runs: dict[str, Any]) -> list[str]:
    """Markdown rows: at every EVERY steps, the authors' value and each run's mean ± CI."""
    c_steps = (curve["controlled_steps"] // 1000 * 1000).astype(int)
    head = ["step", "metric", "authors", *runs]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    reached = {label: by_step(seeds, "eval/return")[0] for label, seeds in runs.items()}
    last = max((int(s[-1]) for s in reached.values() if len(s)), default=0)
    for step in range(EVERY, last + 1, EVERY):
        for key, column, title in METRICS:
            at = np.flatnonzero(c_steps == step) if column in curve else np.array([], int)
            theirs = _pm(*(float(v[0]) for v in mean_ci(curve[column][:, at]))) if len(at) else "-"
            row = [f"{step // 1000}k", title, theirs]
            for seeds in runs.values():
                steps, values = by_step(seeds, key)
                at = np.flatnonzero(steps == step)
                row.append(_pm(*(float(v[0]) for v in mean_ci(values[:, at]))) if len(at) else "-")
            out.append("| " + " | ".join(row) + " |")
    return out


def _pm(mean: float, ci: float) -> str:
    if math.isnan(mean):
        return "nan"
    return f"{mean:.3g} ± {ci:.2g}" if ci else f"{mean:.3g}"


if __name__ == "__main__":
    main()
