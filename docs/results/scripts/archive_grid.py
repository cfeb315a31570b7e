"""Keep a grid's finished runs without their checkpoints, so a study outlives the machine.

A session's machine does not keep runs/, and a medium grid takes longer than one session. This
copies, from a grid directory (`transam reproduce --out`), grid.json, log/ and every
*finished* run (trained, and evaluated on both populations) without checkpoints/, tb/ and
figures: what `transam report` reads (config.json, partners.json, metrics.jsonl, final.json,
eval_*.json, eval_*_pca.npz), a few hundred KB a run. Unfinished runs are left out (without
checkpoints they could neither resume nor be evaluated). To continue a grid on a new machine,
copy the archive back and run the same `transam reproduce` command: finished runs are
skipped, the rest train.

    python docs/results/scripts/archive_grid.py runs/medium docs/results/medium/grid
    cp -r docs/results/medium/grid runs/medium      # on a new machine, then reproduce again
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from transam.rundir import EVAL_PARTNERS, evaluation_path

SKIP = ("checkpoints", "tb", "*.png", "*.lock", "*.tmp")


def archive(src: Path, dest: Path) -> list[str]:
    """Copy the grid's files and finished runs from ``src`` into ``dest``; the runs copied."""
    if not (src / "grid.json").exists():
        raise SystemExit(f"{src} holds no grid.json: pass a `transam reproduce --out` directory")
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copy2(src / "grid.json", dest / "grid.json")
    if (src / "log").is_dir():
        shutil.copytree(src / "log", dest / "log", dirs_exist_ok=True)
    copied = []
    for final in sorted(src.glob("runs/*/*/seed_*/final.json")):
        run = final.parent
        if not all(evaluation_path(run, p).exists() for p in EVAL_PARTNERS):
            continue  # trained, not yet evaluated: the evaluation needs the checkpoints
        rel = run.relative_to(src)
        shutil.copytree(run, dest / rel, ignore=shutil.ignore_patterns(*SKIP), dirs_exist_ok=True)
        copied.append(str(rel))
    return copied


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("src", type=Path, help="the grid directory (transam reproduce --out)")
    parser.add_argument("dest", type=Path, help="where to keep it (e.g. under docs/results/)")
    args = parser.parse_args()
    copied = archive(args.src, args.dest)
    size = sum(f.stat().st_size for f in args.dest.rglob("*") if f.is_file())
    print(f"{len(copied)} finished runs into {args.dest} ({size / 1e6:.1f} MB in all)")
    for rel in copied:
        print(" ", rel)


if __name__ == "__main__":
    main()
