"""Test-wide JAX settings: CPU, float32, persistent compilation cache to keep reruns fast."""

from __future__ import annotations

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# The suite is mostly XLA compilation of small programs run briefly, so it compiles for speed
# of compiling: LLVM's optimisation level 0 (the tiny training runs compile ~30% faster), and
# XLA:CPU's older loop emitters instead of its MLIR fusion emitters (the whole suite: 1,221 ->
# 805 CPU-s cold, 2026-12-03). Programs run 3-4x slower at level 0; few tests run long.
# Subprocesses (grid workers, Ray) inherit the flags.
os.environ.setdefault(
    "XLA_FLAGS", "--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false"
)

import jax

from transam.jaxcache import enable_compilation_cache

enable_compilation_cache()
jax.config.update("jax_enable_x64", False)


# ------------------------------------------------------------------ xdist: one worker per group

import pytest  # noqa: E402

# Test files that share the session-scoped smoke grid below run on one xdist worker (so it is
# built once); every other file is its own group (what --dist loadfile would do).
GRID_FILES = {"test_reproduce.py", "test_evaluation.py", "test_grid_ray.py"}


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook reads the markers into node ids
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        name = item.path.name
        item.add_marker(pytest.mark.xdist_group("grid" if name in GRID_FILES else name))


@pytest.fixture(scope="session")
def smoke_grid(tmp_path_factory: pytest.TempPathFactory):
    """`transam reproduce --budget smoke` on Spread (nam, liam; seeds 0, 1) with the local
    backend, one run of which was interrupted after its first checkpoint beforehand."""
    from local_data import SMOKE_ARGS

    from transam.cli import main
    from transam.reproduce import grid
    from transam.train.loop import train

    out = tmp_path_factory.mktemp("grid") / "smoke"
    interrupted = grid.RunSpec("spread", "liam", 1)
    out.mkdir()
    grid.open_grid(out, "smoke", [interrupted], ["setup"])
    config = grid.run_config(interrupted, grid.BUDGETS["smoke"], out)
    assert not train(config, stop_after_chunks=1).finished
    main(["reproduce", "--budget", "smoke", "--out", str(out), "--jobs", "1", *SMOKE_ARGS])
    return out
