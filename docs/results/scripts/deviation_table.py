"""The deviation table: each run (the authors' preset with one setting put back to ours)
against the preset run itself. Per run: evaluation return, evaluation partner-action
accuracy (newest position) and policy entropy over the evaluations in 400k-625k steps (each
seed's mean, then mean ± 95% t-interval over seeds; at shorter runs, the last evaluation),
and the difference in return and accuracy from the preset.

    python docs/results/scripts/deviation_table.py --baseline runs/parity/authors \
        --out docs/results/parity/deviations.md "clock (--a2c.time-feature)=runs/deviations/clock"
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from parity_plot import WINDOW, by_step, mean_ci, seed_records, write_curves

KEYS = (
    ("eval/return", "return"),
    ("eval/action_accuracy_newest", "accuracy"),
    ("train/entropy", "entropy"),
)


EARLY = (100_000, 375_000)
"""The early window: where a deviation that learns slower shows it before catching up."""


def summary(seeds: list[list[dict[str, Any]]]) -> dict[str, np.ndarray]:
    """Per metric, each seed's mean over the window (or its last evaluation before it), and
    over the early window (``early <name>``; NaN where a run did not reach it)."""
    out = {}
    for key, name in KEYS:
        steps, values = by_step(seeds, key)
        for window, prefix in ((WINDOW, ""), (EARLY, "early ")):
            inside = (steps >= window[0]) & (steps <= window[1])
            if not inside.any() and not prefix:  # a shorter run: its last evaluation
                inside = steps == steps.max()
            out[prefix + name] = (
                np.nanmean(values[:, inside], axis=1)
                if inside.any()
                else np.full(len(seeds), np.nan)
            )
    out["steps"] = np.array([steps.max()])
    return out


def per_seed(label: str, s: dict[str, np.ndarray]) -> str:
    """One line: each seed's window means, then the early window's means over seeds."""
    seeds = ", ".join(f"{r:.2f}/{a:.3f}" for r, a in zip(s["return"], s["accuracy"], strict=True))
    (ret,), _ = mean_ci(s["early return"][:, None])  # NaN (quietly) before the window
    (acc,), _ = mean_ci(s["early accuracy"][:, None])
    early = f"{ret:.2f}/{acc:.3f}"
    return f"{label}: seeds (return/accuracy) {seeds}; {EARLY[0]:,}-{EARLY[1]:,}: {early}"


def stored_labels(path: Path) -> list[str]:
    """The row labels a curves file holds, in its order (none if it does not exist yet)."""
    if not path.exists():
        return []
    with path.open() as f:
        return list(dict.fromkeys(r["label"] for r in csv.DictReader(f)))


def fmt(values: np.ndarray) -> str:
    mean, ci = mean_ci(values[:, None])
    return f"{mean[0]:.3g} ± {ci[0]:.2g}" if ci[0] else f"{mean[0]:.3g}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="*", help="LABEL=RUN_DIR")
    parser.add_argument(
        "--baseline",
        type=Path,
        required=True,
        help="the baseline run directory (or a curves csv holding --baseline-label)",
    )
    parser.add_argument("--baseline-label", default="preset (authors)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument(
        "--curves",
        type=Path,
        help="keep every evaluation of every row in this csv (read back for rows not given)",
    )
    args = parser.parse_args()
    given = [(args.baseline_label, str(args.baseline))] + [
        tuple(s.split("=", 1)) for s in args.runs
    ]
    fresh = {label: seed_records(Path(path), label) for label, path in given}
    stored = stored_labels(args.curves) if args.curves else []
    runs = {
        label: fresh[label] if label in fresh else seed_records(args.curves, label)
        for label in dict.fromkeys([args.baseline_label, *stored, *fresh])
    }
    sums = {label: summary(seeds) for label, seeds in runs.items()}
    base = sums[args.baseline_label]
    head = ["run", "steps", "return", "Δ return", "accuracy", "Δ accuracy", "entropy"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, s in sums.items():
        d_ret = np.nanmean(s["return"]) - np.nanmean(base["return"])
        d_acc = np.nanmean(s["accuracy"]) - np.nanmean(base["accuracy"])
        lines.append(
            f"| {label} | {int(s['steps'][0]):,} | {fmt(s['return'])} | {d_ret:+.2f} | "
            f"{fmt(s['accuracy'])} | {d_acc:+.3f} | {fmt(s['entropy'])} |"
        )
    note = (
        f"\n\nEach seed's mean over its evaluations in {WINDOW[0]:,}-{WINDOW[1]:,} steps (the "
        "last evaluation where a run is shorter), then mean ± 95% t-interval over seeds. "
        f"Δ: difference of the means from the first row, {args.baseline_label}.\n"
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + note)
    print("\n".join(lines))
    print("\n".join(per_seed(label, s) for label, s in sums.items()))
    print(f"wrote {args.out}")
    if args.curves:
        write_curves(args.curves, runs)
        print(f"wrote {args.curves}")


if __name__ == "__main__":
    main()
