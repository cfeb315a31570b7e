"""The reproduction grid on a Ray cluster: one Ray task per (env, method, seed) run.

Each task calls :func:`transam.reproduce.grid.run_one`, which is idempotent, so fault
tolerance is only a matter of calling it again: when a worker process or a node dies, Ray
re-runs the task (``max_retries`` times) on a live worker, and run_one resumes that run from
its last checkpoint; finished runs are skipped. Rerunning the whole command after a crash of
the driver or the cluster resumes the grid the same way.

Retries. A task whose worker process or node dies is retried, up to ``max_retries`` times
(out-of-memory kills by Ray's memory monitor follow Ray's own retry policy). Of the exceptions
a run raises, only ``OSError`` is retried (counted against the same ``max_retries``): on a
network filesystem it is the transient kind (stale file handle, a dropped mount). Everything
else (a bad setting, a numerical or XLA error) would fail again the same way, so it is
reported as the run's failure at once.

Shared filesystem. Runs write their directories themselves, on whatever node they run, so
the grid's ``--out`` must be one filesystem mounted at the same path on every node (NFS,
Lustre, a cloud filestore): what the field does for cluster RL experiments. Each task checks
at its start that it sees a file the driver wrote into ``--out`` and fails at once otherwise;
the driver checks at the end that every run has its final.json and evaluations.

The driver needs only Ray and this package; every node needs the same environment
(``pip install "transam[ray]"``, or ``"transam[cuda,ray]"`` on GPU nodes).
"""

from __future__ import annotations

import os
import socket
import time
import uuid
from pathlib import Path
from typing import Any

from transam.reproduce.grid import Budget, RunSpec, run_one
from transam.train.config import ConfigError

RAY_MISSING = "Ray is not installed: pip install 'transam[ray]'"
CONNECT_TIMEOUT_S = 5.0
"""How long to wait for the cluster's head to accept a connection (ray.init itself retries an
unreachable address for minutes)."""
SHARED_WAIT_S = 30.0
"""How long a task waits for the driver's marker file to appear (NFS attribute caching)."""
RETRY_EXCEPTIONS = [OSError]
"""Run exceptions worth retrying (see the module docstring)."""


def run_ray(
    out: Path,
    specs: list[RunSpec],
    budget: Budget,
    address: str | None = "auto",
    cpus_per_run: float = 1,
    gpus_per_run: float = 0,
    max_retries: int = 3,
) -> list[str]:
    """Run the grid as Ray tasks, ``cpus_per_run`` CPUs and ``gpus_per_run`` GPUs each, on the
    cluster at ``address`` ("auto": the one ``ray start`` started or RAY_ADDRESS names;
    "HOST:PORT" or "ray://HOST:PORT"; None or "local": a new instance on this machine). A
    process already connected to Ray (``ray.init`` called before) uses that connection.
    Returns the failed runs, as :func:`transam.reproduce.grid.run_local` does."""
    try:
        import ray
    except ImportError as err:
        raise ConfigError(RAY_MISSING) from err
    if not cpus_per_run > 0:
        raise ConfigError(f"cpus_per_run must be > 0, got {cpus_per_run!r}")
    if not gpus_per_run >= 0:
        raise ConfigError(f"gpus_per_run must be >= 0, got {gpus_per_run!r}")
    if max_retries < 0:
        raise ConfigError(f"max_retries must be >= 0, got {max_retries!r}")
    out = Path(out).resolve()  # workers do not share the driver's working directory
    started = not ray.is_initialized()
    if started:
        connect(address)
    try:
        if address in (None, "local"):  # whoever started it (`transam reproduce` connects first)
            _check_fits(ray.cluster_resources(), cpus_per_run, gpus_per_run)
        return _run(ray, out, specs, budget, cpus_per_run, gpus_per_run, max_retries)
    finally:
        if started:
            ray.shutdown()


def _check_fits(resources: dict[str, float], cpus_per_run: float, gpus_per_run: float) -> None:
    """On a new local instance (no autoscaler) a run that fits no node would wait forever."""
    for name, wanted, flag in (("CPU", cpus_per_run, "cpus"), ("GPU", gpus_per_run, "gpus")):
        have = resources.get(name, 0.0)
        if wanted > have:
            raise ConfigError(
                f"{flag}_per_run {wanted:g} is more than this machine's {have:g} {name}s"
            )


def connect(address: str | None) -> None:
    """``ray.init``, but an unreachable cluster is a :class:`ConfigError` within seconds."""
    try:
        import ray
    except ImportError as err:
        raise ConfigError(RAY_MISSING) from err

    if address is None or address == "local":
        ray.init(address="local", include_dashboard=False)
        return
    target: str | None = address
    if address == "auto":  # the address ray.init would resolve (it may be a dead cluster's)
        target = os.environ.get("RAY_ADDRESS") or _last_cluster_address()
    if target and target not in ("auto", "local"):
        _check_reachable(target, address)
    try:
        ray.init(address=address)
    except ConnectionError as err:
        raise ConfigError(
            f"cannot connect to the Ray cluster at {address!r}: {err} (start one with "
            "`ray start --head`, or use address 'local' for a new instance on this machine)"
        ) from err


def _last_cluster_address() -> str | None:
    """The address of the cluster ``ray start`` started last on this machine, if any."""
    try:
        from ray._private.utils import read_ray_address  # private, but pinned with Ray

        return read_ray_address()
    except Exception:  # a newer Ray: let ray.init resolve it
        return None


def _check_reachable(target: str, given: str) -> None:
    host, sep, port = target.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit():
        raise ConfigError(
            f"Ray address {given!r} is not HOST:PORT, ray://HOST:PORT, 'auto' or 'local'"
        )
    try:
        with socket.create_connection((host.strip("[]"), int(port)), CONNECT_TIMEOUT_S):
            pass
    except OSError as err:
        via = "" if target == given else f" (from {given!r})"
        raise ConfigError(
            f"cannot reach the Ray cluster at {target!r}{via}: {err}. Start one with "
            "`ray start --head`, or pass the head node's HOST:6379"
        ) from err


def runtime_env(gpus_per_run: float) -> dict[str, Any]:
    """Environment variables of the run processes. The platform follows the resources asked
    for: a CPU run must not take a GPU that Ray gave to another task, and a GPU run must fail
    loudly rather than train on the CPU when the node's JAX has no CUDA. Runs sharing a GPU
    must not each preallocate most of its memory."""
    env = {"JAX_PLATFORMS": "cuda" if gpus_per_run > 0 else "cpu"}
    if 0 < gpus_per_run < 1:
        env["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"
    for name in ("XLA_FLAGS", "TRANSAM_JAX_CACHE"):  # the driver's choices, where made
        if name in os.environ:
            env[name] = os.environ[name]
    return {"env_vars": env}


def _run(
    ray: Any,
    out: Path,
    specs: list[RunSpec],
    budget: Budget,
    cpus_per_run: float,
    gpus_per_run: float,
    max_retries: int,
) -> list[str]:
    from transam.rundir import write_json

    marker = out / "log" / f"ray_driver_{uuid.uuid4().hex}.json"
    marker.parent.mkdir(parents=True, exist_ok=True)
    write_json(marker, {"host": socket.gethostname(), "time": time.time()})
    task = ray.remote(
        num_cpus=cpus_per_run,
        num_gpus=gpus_per_run,
        # JAX binds the GPU it first sees for the life of the process: one run per process.
        max_calls=1 if gpus_per_run > 0 else 0,
        max_retries=max_retries,
        retry_exceptions=RETRY_EXCEPTIONS,
        runtime_env=runtime_env(gpus_per_run),
    )(_ray_task)
    pending = {task.remote(str(out), spec, budget, str(marker)): spec for spec in specs}
    failures: dict[RunSpec, str] = {}
    try:
        while pending:
            [ready], _ = ray.wait(list(pending), num_returns=1)
            spec = pending.pop(ready)
            try:
                ray.get(ready)
            except ray.exceptions.RayError as err:  # one bad run must not stop the grid
                failures[spec] = _describe(err)
    finally:
        marker.unlink(missing_ok=True)
    found = [f"{s.rel}: {failures[s]}" if s in failures else _check_outputs(out, s) for s in specs]
    return [f for f in found if f]


def _describe(err: Exception) -> str:
    """'Type: message' of a failed task: the run's own exception, or why Ray gave up on it."""
    cause = getattr(err, "cause", None) or err
    lines = str(cause).strip().splitlines()
    return f"{type(cause).__name__}: {lines[0] if lines else ''}"


def _check_outputs(out: Path, spec: RunSpec) -> str:
    """'' when the run's outputs are all in --out as this machine sees it, else why not."""
    from transam.rundir import EVAL_PARTNERS, evaluation_path

    run_dir = out / spec.rel
    missing = [
        p.name
        for p in [run_dir / "final.json", *(evaluation_path(run_dir, p) for p in EVAL_PARTNERS)]
        if not p.exists()
    ]
    if not missing:
        return ""
    return (
        f"{spec.rel}: the task succeeded but {', '.join(missing)} is missing here: is --out on a "
        "filesystem shared by all nodes, at the same path?"
    )


def _ray_task(out: str, spec: RunSpec, budget: Budget, marker: str) -> dict[str, Any]:
    """One grid run inside a Ray worker process."""
    from transam.jaxcache import enable_compilation_cache

    deadline = time.monotonic() + SHARED_WAIT_S
    while not Path(marker).exists():
        if time.monotonic() > deadline:
            raise ConfigError(
                f"--out {out!r} is not shared with node {socket.gethostname()}: it does not "
                f"see {marker!r}, written by the driver. Put --out on a filesystem mounted at "
                "the same path on every node"
            )
        time.sleep(1.0)
    enable_compilation_cache()
    return run_one(out, spec, budget)
