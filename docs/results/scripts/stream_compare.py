"""The window model against the streaming one: a markdown table from their run directories.

    python docs/results/scripts/stream_compare.py window=runs/sw/window stream=runs/sw/stream \\
        [--lo 800000] [--hi 1000000] [--eval eval_train.json] > docs/results/stream/table.md

Each LABEL=DIR is a vmapped-seed run (DIR/seed_k/metrics.jsonl). Per run: the training-time
evaluations with ``lo <= step <= hi`` (100 episodes each), averaged per seed; the table gives
the mean over seeds with a 95% confidence interval over the per-seed-and-evaluation means
(Student t; the evaluations of one seed are correlated, so this interval is, if anything,
narrow). With ``--eval``, each seed's final evaluation (``transam evaluate``'s JSON) adds the
return and newest-position accuracy over all its episodes pooled across seeds, and the
all-window-positions accuracy (the window model only: a causal stream has one decoded position
per step) and the per-timestep accuracy at a few steps of the episode.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from scipy import stats

KEYS = {"return": "eval/return", "accuracy": "eval/action_accuracy_newest"}


def evaluations(run: Path, lo: int, hi: int) -> dict[str, list[list[float]]]:
    """Per metric, per seed: the training-time evaluations in [lo, hi]."""
    out: dict[str, list[list[float]]] = {k: [] for k in KEYS}
    for seed_dir in sorted(run.glob("seed_*")):
        rows = [json.loads(line) for line in (seed_dir / "metrics.jsonl").open()]
        rows = [r for r in rows if lo <= r["step"] <= hi and KEYS["return"] in r]
        for name, key in KEYS.items():
            out[name].append([float(r[key]) for r in rows if key in r])
    return out


def mean_ci(values: list[float]) -> tuple[float, float]:
    """(mean, half-width of the 95% t interval)."""
    x = np.asarray(values, np.float64)
    if x.size < 2:
        return float(x.mean()), math.nan
    half = stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size)
    return float(x.mean()), float(half)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="LABEL=RUN_DIR")
    parser.add_argument("--lo", type=int, default=800_000)
    parser.add_argument("--hi", type=int, default=1_000_000)
    parser.add_argument("--eval", default="", help="final-evaluation JSON name in each seed dir")
    args = parser.parse_args()
    print(f"| run | seeds | evaluations in {args.lo:,}-{args.hi:,} | return | accuracy (newest) |")
    print("|---|---|---|---|---|")
    finals = {}
    for spec in args.runs:
        label, _, path = spec.partition("=")
        run = Path(path)
        ev = evaluations(run, args.lo, args.hi)
        cells = []
        for name in KEYS:
            flat = [v for seed in ev[name] for v in seed]
            m, h = mean_ci(flat)
            cells.append(f"{m:.3f} ± {h:.3f}" if name == "accuracy" else f"{m:.2f} ± {h:.2f}")
        count = sum(len(s) for s in ev["return"])
        print(f"| {label} | {len(ev['return'])} | {count} | {' | '.join(cells)} |")
        if args.eval:
            finals[label] = [
                json.loads(p.read_text()) for p in sorted(run.glob(f"seed_*/{args.eval}"))
            ]
    if not finals:
        return
    print()
    print(
        "| run | final evaluation: episodes | return | accuracy (newest) "
        "| accuracy (all window positions) | newest-position accuracy at steps 1, 6, 12, 24 |"
    )
    print("|---|---|---|---|---|---|")
    for label, evals in finals.items():
        episodes = sum(e["episodes"] for e in evals)
        ret = np.mean([e["return"]["mean"] for e in evals])
        # Pooled standard error of the mean return over all episodes of all seeds.
        var = np.mean([e["return"]["std"] ** 2 for e in evals])
        se = math.sqrt(var / episodes)
        acc = np.mean([e["action_accuracy_newest"] for e in evals])
        every = [e.get("action_accuracy_all_positions") for e in evals]
        all_pos = "—" if None in every else f"{np.mean(every):.3f}"
        curve = np.mean([e["per_step"]["action_accuracy_newest"] for e in evals], axis=0)
        steps = ", ".join(f"{curve[t]:.2f}" for t in (1, 6, 12, 24))
        print(
            f"| {label} | {episodes} | {ret:.2f} ± {1.96 * se:.2f} | {acc:.3f} | {all_pos} "
            f"| {steps} |"
        )


if __name__ == "__main__":
    main()
