"""The learnability table of one environment from its archived runs
(docs/results/ENV/learnability/METHOD/, written by learnability.sh): per method the final
evaluation of each seed (final.json: the last training evaluation, 100 episodes), `transam
evaluate` on the training and the held-out population, and the training curve's milestones.

    python docs/results/scripts/learnability_table.py lbf [--curve]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def fmt(x: float, digits: int) -> str:
    return f"{x:.{digits}f}".replace("-", "−")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("env")
    parser.add_argument("--curve", action="store_true", help="print every evaluation too")
    args = parser.parse_args()
    digits = 4 if args.env == "lbf" else 2
    base = ROOT / args.env / "learnability"
    print(
        "| method | steps × seeds | final evaluation, mean (seeds) | evaluate, default "
        "population | evaluate, held-out | accuracy | entropy at the end |"
    )
    print("|---|---|---|---|---|---|---|")
    for run in sorted(p for p in base.iterdir() if (p / "final.json").exists()):
        config = json.loads((run / "config.json").read_text())
        finals = json.loads((run / "final.json").read_text())["seeds"]
        seeds = [f["seed"] for f in finals]
        final = [f["eval/return"] for f in finals]
        evals = {}
        for pop in ("train", "heldout"):
            rows = [json.loads((run / f"seed_{s}" / f"eval_{pop}.json").read_text()) for s in seeds]
            means = [r["return"]["mean"] for r in rows]
            ses = [r["return"]["std"] / np.sqrt(r["episodes"]) for r in rows]
            acc = [r.get("action_accuracy_newest") for r in rows]
            evals[pop] = (means, ses, rows[0]["episodes"], acc)

        def cells(means: list[float], ses: list[float]) -> str:
            return ", ".join(
                f"{fmt(a, digits)} ± {fmt(b, digits)}" for a, b in zip(means, ses, strict=True)
            )

        m, se, n, acc = evals["train"]
        hm, hse, hn, hacc = evals["heldout"]
        acc_text = "—" if acc[0] is None else " / ".join(f"{a:.3f}" for a in acc + hacc)
        entropy = [f.get("eval/policy_entropy", float("nan")) for f in finals]
        print(
            f"| {config['method']} | {config['total_steps']:,} × {len(seeds)} | "
            f"{fmt(np.mean(final), digits)} ({', '.join(fmt(x, digits) for x in final)}) | "
            f"{cells(m, se)} ({n} eps) | {cells(hm, hse)} ({hn} eps) | {acc_text} | "
            f"{', '.join(f'{e:.2f}' for e in entropy)} |"
        )
    if args.curve:
        for run in sorted(p for p in base.iterdir() if (p / "final.json").exists()):
            for seed_dir in sorted(run.glob("seed_*")):
                text = (seed_dir / "metrics.jsonl").read_text()
                recs = [json.loads(x) for x in text.splitlines()]
                print(f"\n{run.name} {seed_dir.name}: step, eval return, train return, entropy")
                for r in recs:
                    print(
                        f"  {r['step']:>9,} {fmt(r['eval/return'], digits):>9} "
                        f"{fmt(r['train/return'], digits):>9} {r['train/entropy']:.3f}"
                        f" v{r['train/value_loss']:.3f}"
                    )


if __name__ == "__main__":
    main()
