"""Keep a grid's finished runs without their checkpoints, so a study outlives the machine.

A session's machine does not keep runs/, and a medium grid takes longer than one session.
This copies grid.json, log/ and every finished run (trained, and evaluated on both
populations) of a grid directory without checkpoints, TensorBoard files and figures: what
`transam report` reads, about 60 KB a run (`transam.reproduce.grid.archive_grid`). To
continue the grid on a new machine, copy the archive back and run the same
`transam reproduce` command: finished runs are skipped, the rest train.

    python docs/results/scripts/archive_grid.py runs/medium docs/results/medium/grid
    cp -r docs/results/medium/grid runs/medium      # on a new machine, then reproduce again

With --carry, unfinished runs come along with their newest checkpoint (and lose it once they
finish), so that a run longer than a session resumes on the next machine.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from transam.reproduce.grid import archive_grid


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("src", type=Path, help="the grid directory (transam reproduce --out)")
    parser.add_argument("dest", type=Path, help="where to keep it (e.g. under docs/results/)")
    parser.add_argument(
        "--carry", action="store_true", help="also unfinished runs, with their newest checkpoint"
    )
    args = parser.parse_args()
    copied = archive_grid(args.src, args.dest, carry=args.carry)
    size = sum(f.stat().st_size for f in args.dest.rglob("*") if f.is_file())
    print(f"{len(copied)} runs into {args.dest} ({size / 1e6:.1f} MB in all)")
    for rel in copied:
        print(" ", rel)


if __name__ == "__main__":
    main()
