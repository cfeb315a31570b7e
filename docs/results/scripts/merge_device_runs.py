"""Merge runs trained on a lent GPU machine (device_grid.sh's runK-GRID.tgz) into a grid.

Each tarball holds a grid as the device left it (grid.json, log/, the one run it trained,
runs/ENV/METHOD/seed_S, with its newest checkpoint). A run replaces the grid's copy only
where it is further along (more chunks in metrics.jsonl); the device's invocations (their
machine record says "gpu") are appended to grid.json and its log lines to log/, so the grid
says where every chunk was trained. The grid then resumes the runs with the same `transam
reproduce` command (paper_budget.sh, env_grid.sh); a grid not here yet starts as the device's.

    python docs/results/scripts/merge_device_runs.py DEVICE_FILES/run*-paper-budget.tgz \
        --grid runs/paper-budget
"""

from __future__ import annotations

import argparse
import json
import shutil
import tarfile
import tempfile
from pathlib import Path

from transam.rundir import write_json


def _chunks(run: Path) -> int:
    path = run / "metrics.jsonl"
    return len(path.read_text().splitlines()) if path.exists() else 0


def merge(tarball: Path, grid_dir: Path) -> list[str]:
    """Merge one tarball into ``grid_dir``; the runs it replaced."""
    replaced = []
    with tempfile.TemporaryDirectory() as tmp, tarfile.open(tarball) as tar:
        tar.extractall(tmp, filter="data")
        src = Path(tmp)
        device = json.loads((src / "grid.json").read_text())
        if not (grid_dir / "grid.json").exists():
            (grid_dir / "log").mkdir(parents=True, exist_ok=True)
            write_json(grid_dir / "grid.json", {**device, "runs": [], "invocations": []})
        grid = json.loads((grid_dir / "grid.json").read_text())
        for key in ("budget_settings", "partners"):  # a tarball of another grid
            if device.get(key) != grid.get(key):
                raise SystemExit(
                    f"{tarball}: {key} {device.get(key)} is not {grid_dir}'s {grid.get(key)}; "
                    "merge each device_grid.sh tarball (runK-GRID.tgz) into its own grid"
                )
        for rel in device["runs"]:
            run, mine = src / rel, grid_dir / rel
            if not (run / "config.json").exists() or _chunks(run) <= _chunks(mine):
                continue
            shutil.rmtree(mine, ignore_errors=True)
            shutil.copytree(run, mine, ignore=shutil.ignore_patterns(".lock"))
            replaced.append(f"{rel}: {_chunks(run)} chunks")
            if rel not in grid["runs"]:
                grid["runs"].append(rel)
        known = {inv["started"] for inv in grid["invocations"]}
        grid["invocations"] += [i for i in device["invocations"] if i["started"] not in known]
        for log in sorted((src / "log").glob("*.jsonl")):
            dest = grid_dir / "log" / log.name
            have = set(dest.read_text().splitlines()) if dest.exists() else set()
            new = [line for line in log.read_text().splitlines() if line not in have]
            with dest.open("a") as f:
                f.writelines(line + "\n" for line in new)
    write_json(grid_dir / "grid.json", grid)
    return replaced


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("tarballs", nargs="+", type=Path)
    parser.add_argument("--grid", type=Path, default=Path("runs/paper-budget"))
    args = parser.parse_args()
    missing = [str(t) for t in args.tarballs if not t.is_file()]
    if missing:
        parser.error(f"no such tarball: {', '.join(missing)} (device_grid.sh's runK-GRID.tgz)")
    for tarball in args.tarballs:
        for line in merge(tarball, args.grid):
            print(f"{tarball}: {line}")


if __name__ == "__main__":
    main()
