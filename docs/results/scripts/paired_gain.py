"""Each run's return gain over a uniformly random controlled agent on the same evaluation
episodes (same partners and starts: the paired difference, with its standard error), as
`transam demo` shows it for the shipped runs. A run is a one-seed run directory, a pretrained
run's directory or a shipped pretrained run's name.

    python docs/results/scripts/paired_gain.py spread-transam runs/x/seed_0 --episodes 1000
"""

from __future__ import annotations

import argparse

import numpy as np

from transam.evaluation.final import paired_random_returns


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    for run in args.runs:
        trained, random = paired_random_returns(run, args.episodes, args.seed)
        gain = trained - random
        se = gain.std() / np.sqrt(len(gain))
        print(
            f"{run}: {trained.mean():.2f} vs random {random.mean():.2f}: "
            f"gain {gain.mean():+.2f} ± {se:.2f} (paired s.e., {len(gain)} episodes)"
        )


if __name__ == "__main__":
    main()
