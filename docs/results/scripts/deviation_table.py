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
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from parity_plot import WINDOW, by_step, mean_ci, seed_records

KEYS = (
    ("eval/return", "return"),
    ("eval/action_accuracy_newest", "accuracy"),
    ("train/entropy", "entropy"),
)


def summary(run: Path) -> dict[str, np.ndarray]:
    """Per metric, each seed's mean over the window (or its last evaluation before it)."""
    seeds = seed_records(run)
    out = {}
    for key, name in KEYS:
        steps, values = by_step(seeds, key)
        inside = (steps >= WINDOW[0]) & (steps <= WINDOW[1])
        if not inside.any():
            inside = steps == steps.max()
        out[name] = np.nanmean(values[:, inside], axis=1)
    out["steps"] = np.array([steps.max()])
    return out


def fmt(values: np.ndarray) -> str:
    mean, ci = mean_ci(values[:, None])
    return f"{mean[0]:.3g} ± {ci[0]:.2g}" if ci[0] else f"{mean[0]:.3g}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="*", help="LABEL=RUN_DIR")
    parser.add_argument("--baseline", type=Path, required=True, help="the --preset authors run")
    parser.add_argument("--baseline-label", default="preset (authors)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    base = summary(args.baseline)
    head = ["run", "steps", "return", "Δ return", "accuracy", "Δ accuracy", "entropy"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, path in [(args.baseline_label, str(args.baseline))] + [
        tuple(s.split("=", 1)) for s in args.runs
    ]:
        s = summary(Path(path))
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
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
