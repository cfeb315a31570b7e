"""Environment throughput: `python benchmarks/envs.py` (same as `transam envs bench`)."""

from transam.cli import main

if __name__ == "__main__":
    main(["envs", "bench"])
