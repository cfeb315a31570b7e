"""Which runs of the per-environment grids exist (issue 36): environment x method, the seeds
finished (a final evaluation on the training partners), carried (an unfinished run kept with
its newest checkpoint) and not started, read from the archives in docs/results/*/grid. What a
session should start next is what this prints as "-".

    python docs/results/scripts/coverage.py
"""

from __future__ import annotations

from pathlib import Path

from transam.registry import display
from transam.reproduce.report.load import METHOD_ORDER as METHODS

ROOT = Path(__file__).resolve().parents[1]
GRIDS = {"spread": "medium", "tag": "tag", "overcooked": "overcooked", "lbf": "lbf"}
SEEDS = (0, 1, 2)


def state(run: Path) -> str:
    """'done' (evaluated), 'carried' (a checkpoint to resume from) or '-' (not started)."""
    if (run / "eval_train.json").exists():
        return "done"
    if any(run.glob("checkpoints/chunk_*.msgpack")):
        return "carried"
    return "-"


def main() -> None:
    print("| method | " + " | ".join(GRIDS) + " |")
    print("|---|" + "---|" * len(GRIDS))
    left = 0
    for method in METHODS:
        cells = []
        for env, folder in GRIDS.items():
            runs = ROOT / folder / "grid" / "runs" / env / method
            states = [state(runs / f"seed_{s}") for s in SEEDS]
            left += sum(s != "done" for s in states)
            done = [str(s) for s, st in zip(SEEDS, states, strict=True) if st == "done"]
            carried = [str(s) for s, st in zip(SEEDS, states, strict=True) if st == "carried"]
            text = ",".join(done) if done else "-"
            cells.append(text + (f" (carried {','.join(carried)})" if carried else ""))
        print(f"| {display(method)} | " + " | ".join(cells) + " |")
    total = len(METHODS) * len(GRIDS) * len(SEEDS)
    print(f"\nseeds finished per cell; {left} of {total} runs left")


if __name__ == "__main__":
    main()
