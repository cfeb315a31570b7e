"""The Ray backend of the grid: the same files as the local backend, a killed worker's run
resumed from its checkpoint (and nothing else redone), and clear errors without a cluster."""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from local_data import SMOKE_ENVS as ENVS
from local_data import SMOKE_METHODS as METHODS
from local_data import SMOKE_SEEDS as SEEDS

from transam.reproduce import grid
from transam.reproduce.grid_ray import connect, run_ray
from transam.rundir import EVAL_PARTNERS, read_metrics
from transam.train.config import ConfigError

SMOKE = grid.BUDGETS["smoke"]


@pytest.fixture(scope="module")
def ray_session() -> Any:
    import ray  # a test extra: installed wherever the tests run

    # A 2-CPU instance, and 2 CPUs per run (below): one run at a time, as XLA uses both cores.
    # Each Ray worker process compiles (or loads) every program itself, so two concurrent
    # 1-CPU workers took twice the CPU for the same grid on the 2-core CI machine.
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def run_files(out: Path, spec: grid.RunSpec) -> dict[str, Any]:
    run = out / spec.rel
    files: dict[str, Any] = {"metrics": read_metrics(run / "metrics.jsonl")}
    for partners in EVAL_PARTNERS:
        files[partners] = json.loads((run / f"eval_{partners}.json").read_text())
    return files


def report_numbers(out: Path) -> dict[str, Any]:
    """results.json without what differs between two grids of the same runs (date, path,
    machine and wall times)."""
    from transam.reproduce.report.build import build_report

    results = json.loads((build_report(out).parent / "results.json").read_text())
    for key in ("generated", "compute"):
        results.pop(key)
    results["grid"].pop("out")
    return results


def _kill_after_first_checkpoint(out: Path, spec: grid.RunSpec, killed: list[int]) -> None:
    """SIGKILL the worker training ``spec`` once it has a checkpoint and is not finished. The
    worker is stopped while its files are looked at, so what is seen is what is killed."""
    run = out / spec.rel
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline:
        time.sleep(0.01)
        launches = [e for e in grid.read_launches(out, spec) if e["event"] == "train"]
        if not launches:
            continue
        pid = launches[0]["pid"]
        os.kill(pid, signal.SIGSTOP)
        if any((run / "checkpoints").glob("chunk_*.msgpack")):
            if (run / "final.json").exists():
                os.kill(pid, signal.SIGCONT)
            else:
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
            return
        os.kill(pid, signal.SIGCONT)


def test_ray_grid_with_a_killed_worker_matches_the_local_grid(
    ray_session: Any, smoke_grid: Path, tmp_path: Path
) -> None:
    """conftest's ``smoke_grid`` (local backend) again through Ray, with the worker of one run
    SIGKILLed after its first checkpoint, and one run that fails by itself: the killed run is
    retried and resumes from that checkpoint, nothing else is redone, the error is reported,
    and every file and the report equal the local grid's."""
    out = tmp_path / "ray"
    specs = grid.grid_specs(ENVS, METHODS, SEEDS)
    victim = grid.RunSpec("spread", "liam", 0)
    bad = grid.RunSpec("spread", "bogus", 0)  # fails inside the worker: reported, not retried
    grid.open_grid(out, "smoke", specs, ["reproduce", "--backend", "ray"])
    killed: list[int] = []
    killer = threading.Thread(target=_kill_after_first_checkpoint, args=(out, victim, killed))
    killer.start()
    try:
        failures = run_ray(out, [*specs, bad], SMOKE, cpus_per_run=2)
    finally:
        killer.join()
    grid.close_grid(out, failures)
    assert len(failures) == 1 and failures[0].startswith(
        "runs/spread/bogus/seed_0: ConfigError: unknown method 'bogus'"
    )
    assert killed, "the run finished before it could be killed"
    trains = [e for e in grid.read_launches(out, victim) if e["event"] == "train"]
    assert len(trains) == 2 and trains[0]["pid"] == killed[0] != trains[1]["pid"]
    assert (trains[0]["start_chunk"], trains[1]["start_chunk"], trains[1]["resume"]) == (0, 1, True)
    for spec in specs:
        if spec != victim:  # not redone
            assert [e["event"] for e in grid.read_launches(out, spec)] == ["train", "done"]
        ray_files = run_files(out, spec)
        assert [r["chunk"] for r in ray_files["metrics"]] == [0, 1]
        assert ray_files == run_files(smoke_grid, spec), spec.rel
    assert report_numbers(out) == report_numbers(smoke_grid)
    assert not list((out / "log").glob("ray_driver_*"))  # the marker is cleaned up


def test_missing_ray_is_a_clear_error(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    with pytest.raises(ConfigError, match=r"Ray is not installed: pip install 'transam\[ray\]'"):
        run_ray(tmp_path, grid.grid_specs(ENVS, METHODS, SEEDS), SMOKE)


def test_unreachable_cluster_fails_fast(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ConfigError, match=r"cannot reach the Ray cluster at '127.0.0.1:1'"):
        connect("127.0.0.1:1")
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")
    with pytest.raises(ConfigError, match=r"'127.0.0.1:1' \(from 'auto'\)"):
        connect("auto")
    with pytest.raises(ConfigError, match=r"'nowhere' is not HOST:PORT"):
        connect("nowhere")
