"""A grid task for test_grid's stop test, importable by the grid's spawned worker processes
(module level, like the real one): it marks its start, waits for a stop request as a training
run does, and then stops as a training run does."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from transam.train.stop import RunInterrupted, stop_on_signals


def wait_for_stop(out: str, specs: list[Any], budget: Any, vmap_seeds: bool) -> list[str]:
    name = specs[0].rel.replace("/", "_")
    with stop_on_signals() as request:
        Path(out, f"started-{name}").touch()  # inside: a signal from now on is a stop request
        deadline = time.monotonic() + 120
        while request.signum is None and time.monotonic() < deadline:
            time.sleep(0.02)
    if request.signum is None:
        return [f"{specs[0].rel}: no stop request came"]
    Path(out, f"stopped-{name}").touch()
    raise RunInterrupted(request.signum, f"{specs[0].rel} stopped")
