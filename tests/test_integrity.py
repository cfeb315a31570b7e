"""Run integrity: corrupt checkpoints, non-finite training, a second writer, SIGINT/SIGTERM and
failed writes (transam.rundir and its use by the loop, evaluation and the grid).

Whole runs are NAM on Spread with scripted partners: 16 envs x 5 steps = 80 steps per update,
25 updates (2,000 steps) per chunk, five chunks. Chunks are that long (a fraction of a second
each) so that a signal sent by a test when the first checkpoint appears reaches the run well
before it ends; every comparison is of metrics and final.json with an uninterrupted run.
"""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import msgpack
import numpy as np
import pytest

from transam import rundir
from transam.cli import main
from transam.reproduce import grid
from transam.rundir import (
    CheckpointError,
    RunLockedError,
    WriteError,
    checkpoint_bytes,
    read_checkpoint,
    read_metrics,
    run_lock,
)
from transam.train.config import A2CConfig, ConfigError, EvalConfig, TrainConfig
from transam.train.loop import train

CHUNK_STEPS = 25 * 80
CHUNKS = 5
ARGS = {
    "--env": "spread",
    "--method": "nam",
    "--partners": "heuristic",
    "--total-steps": str(CHUNKS * CHUNK_STEPS),
    "--a2c.num-envs": "16",
    "--eval.every-episodes": "80",
    "--eval.episodes": "8",
}
"""The `transam train` arguments of :func:`tiny` (plus --a2c.no-anneal-lr --no-progress)."""


def tiny(out: Path, **kw: Any) -> TrainConfig:
    return TrainConfig(
        env="spread",
        method="nam",
        partners="heuristic",
        total_steps=CHUNKS * CHUNK_STEPS,
        out=str(out),
        progress=False,
        a2c=A2CConfig(num_envs=16, anneal_lr=False),
        eval=EvalConfig(every_episodes=80, episodes=8),
        **kw,
    )


def cli_args(out: Path, *extra: str) -> list[str]:
    flat = [x for kv in ARGS.items() for x in kv]
    return ["train", *flat, "--a2c.no-anneal-lr", "--no-progress", "--out", str(out), *extra]


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[dict[str, Any]], Any]:
    """An uninterrupted run: its metrics and final.json."""
    out = tmp_path_factory.mktemp("ref") / "run"
    assert train(tiny(out)).finished
    records = read_metrics(out / "metrics.jsonl")
    assert len(records) == CHUNKS
    return records, json.loads((out / "final.json").read_text())


def assert_same_as(reference: tuple[list[dict[str, Any]], Any], out: Path) -> None:
    records, final = reference
    assert read_metrics(out / "metrics.jsonl") == records
    assert json.loads((out / "final.json").read_text()) == final


def names(out: Path) -> list[str]:
    return sorted(p.name for p in (out / "checkpoints").iterdir())


# ------------------------------------------------------------------ verified checkpoints


def test_read_metrics_drops_only_a_torn_last_line(tmp_path: Path) -> None:
    """A kill mid-append leaves a torn last line (no newline after it): dropped. Any other line
    that is not a record (a damaged file) is an error naming the file and line, not a record
    silently lost."""
    path = tmp_path / "metrics.jsonl"
    good = [{"chunk": 0, "step": 10}, {"chunk": 1, "step": 20}]
    whole = "".join(json.dumps(r) + "\n" for r in good)
    path.write_text(whole)
    assert read_metrics(path) == good
    path.write_text(whole + '{"chunk": 2, "st')  # torn
    assert read_metrics(path) == good
    path.write_text(whole + "[1, 2]")  # a last line without its newline, but not a record
    assert read_metrics(path) == good
    for bad, number in (
        ('{"chunk": 0, "st\n' + whole, 1),  # a torn line with records after it
        (whole + '{"chunk": 2, "st\n', 3),  # a bad last line that did get its newline
        (json.dumps(good[0]) + "\n\n" + json.dumps(good[1]) + "\n", 2),  # an empty line
        (whole + "[1, 2]\n", 3),  # JSON, but not a record
    ):
        path.write_text(bad)
        with pytest.raises(rundir.MetricsError, match=rf"metrics\.jsonl, line {number}: not a"):
            read_metrics(path)
    assert issubclass(rundir.MetricsError, ConfigError)  # the CLI prints it as an error


def test_checkpoint_verification_catches_truncation_bit_flips_and_reads_old_files(
    tmp_path: Path,
) -> None:
    state = {"w": np.arange(6, dtype=np.float32).reshape(2, 3), "n": np.int32(4)}
    template = {"w": np.zeros((2, 3), np.float32), "n": np.int32(0)}
    good = tmp_path / "good.msgpack"
    good.write_bytes(checkpoint_bytes(state))
    restored = read_checkpoint(good, template)
    np.testing.assert_array_equal(restored["w"], state["w"])
    data = good.read_bytes()
    outer = msgpack.unpackb(data)
    assert outer["format"] == "transam-checkpoint" and len(outer["sha256"]) == 64

    cut = tmp_path / "cut.msgpack"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match=r"cut\.msgpack failed verification: not a complete"):
        read_checkpoint(cut, template)
    flipped = bytearray(data)
    flipped[-3] ^= 0xFF  # inside the state's bytes: still valid msgpack
    (tmp_path / "flip.msgpack").write_bytes(bytes(flipped))
    with pytest.raises(CheckpointError, match="checksum mismatch"):
        read_checkpoint(tmp_path / "flip.msgpack", template)
    (tmp_path / "empty.msgpack").write_bytes(b"")
    with pytest.raises(CheckpointError, match="empty file"):
        read_checkpoint(tmp_path / "empty.msgpack", template)
    # A checkpoint written before checksums (the bare flax msgpack) still loads.
    from flax import serialization

    (tmp_path / "old.msgpack").write_bytes(serialization.to_bytes(state))
    assert int(read_checkpoint(tmp_path / "old.msgpack", template)["n"]) == 4


def test_truncated_newest_checkpoint_resume_uses_the_previous_one(
    reference: tuple[list[dict[str, Any]], Any],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "run"
    assert not train(tiny(out), stop_after_chunks=3).finished
    assert names(out) == ["chunk_000001.msgpack", "chunk_000002.msgpack"]  # two kept
    newest = out / "checkpoints" / "chunk_000002.msgpack"
    newest.write_bytes(newest.read_bytes()[:1000])  # a kill mid-write on a network filesystem
    capsys.readouterr()
    assert train(tiny(out, resume=True)).finished
    err = capsys.readouterr().err
    assert "chunk_000002.msgpack failed verification" in err and "moved aside" in err
    assert (out / "checkpoints" / "chunk_000002.msgpack.corrupt").exists()
    assert_same_as(reference, out)  # resumed from chunk 1: the same numbers


def test_keep_checkpoints_zero_keeps_every_one_and_resume_may_change_it(
    reference: tuple[list[dict[str, Any]], Any], tmp_path: Path
) -> None:
    out = tmp_path / "run"
    assert not train(tiny(out), stop_after_chunks=3).finished
    assert names(out) == ["chunk_000001.msgpack", "chunk_000002.msgpack"]
    # How many are kept is how the run is driven, not what it is: --resume may change it.
    assert train(tiny(out, resume=True, keep_checkpoints=0)).finished
    assert names(out) == [f"chunk_{c:06d}.msgpack" for c in range(1, CHUNKS)]
    assert "keep_checkpoints" not in json.loads((out / "config.json").read_text())
    assert_same_as(reference, out)
    with pytest.raises(ConfigError, match=r"keep_checkpoints must be >= 0, got -1"):
        tiny(out, keep_checkpoints=-1).validate()


def test_resume_with_more_steps_continues_a_finished_run_as_if_set_longer_from_the_start(
    reference: tuple[list[dict[str, Any]], Any], tmp_path: Path
) -> None:
    out = tmp_path / "run"
    short = dataclasses.replace(tiny(out), total_steps=2 * CHUNK_STEPS)
    assert train(short).finished and len(read_metrics(out / "metrics.jsonl")) == 2
    with pytest.raises(rundir.RunDirError, match="continued to more steps, not fewer"):
        train(dataclasses.replace(short, total_steps=CHUNK_STEPS, resume=True))
    assert train(tiny(out, resume=True)).finished
    assert_same_as(reference, out)  # the five chunks of a run set for five from the start
    assert json.loads((out / "config.json").read_text())["total_steps"] == CHUNKS * CHUNK_STEPS


def test_resume_with_more_steps_is_refused_where_the_steps_done_would_differ(
    tmp_path: Path,
) -> None:
    by_run = tmp_path / "by_run"  # annealed over its own length: every step depends on it
    cfg = dataclasses.replace(tiny(by_run), total_steps=CHUNK_STEPS)
    cfg = dataclasses.replace(cfg, a2c=dataclasses.replace(cfg.a2c, anneal_lr=True))
    assert train(cfg).finished
    with pytest.raises(rundir.RunDirError, match="anneals its learning rate over its own 2000"):
        train(dataclasses.replace(cfg, total_steps=2 * CHUNK_STEPS, resume=True))
    cut = tmp_path / "cut"  # ends with a short chunk
    cfg = dataclasses.replace(tiny(cut), total_steps=CHUNK_STEPS + 80)
    assert train(cfg).finished
    before = (cut / "config.json").read_bytes(), (cut / "final.json").read_bytes()
    with pytest.raises(rundir.RunDirError, match="ends with a short chunk"):
        train(dataclasses.replace(cfg, total_steps=2 * CHUNK_STEPS, resume=True))
    assert ((cut / "config.json").read_bytes(), (cut / "final.json").read_bytes()) == before


# ------------------------------------------------------------------ non-finite training


def test_nan_stops_the_run_naming_step_seed_and_quantity(tmp_path: Path) -> None:
    out = tmp_path / "nan"
    # --a2c.lr 1e4 diverges within a few updates; 2-update chunks so one checkpoint exists.
    with pytest.raises(SystemExit) as exc:
        # (our earlier plain A2C: one update per rollout, so chunks of 2 updates)
        main(cli_args(out, "--preset", "2026-11", "--a2c.lr", "1e4", "--eval.every-episodes", "6"))
    message = str(exc.value.code)
    match = re.search(r"seed 0: non-finite ([\w/, ]+) at update (\d+) \(step ([\d,]+)\)", message)
    assert match, message
    quantities, update, step = match.group(1), int(match.group(2)), match.group(3)
    assert "loss" in quantities or "grad_norm" in quantities
    assert int(step.replace(",", "")) == update * 80
    chunk = (update - 1) // 2
    assert chunk >= 1, "diverged in the first chunk: nothing to keep"
    assert "start over with --force" in message and "chunk_" in message
    assert not (out / "final.json").exists()
    records = read_metrics(out / "metrics.jsonl")
    assert [r["chunk"] for r in records] == list(range(chunk))  # nothing of the bad chunk
    assert all(r["train/value_loss"] is not None for r in records)
    kept = sorted(rundir.checkpoints(out))
    assert kept and kept[-1] == chunk - 1  # the last good checkpoint stays the newest


def test_reproduce_records_a_diverged_run_as_failed_and_goes_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Both runs diverge (a learning rate of 1e4 patched into the grid's settings): the second
    is still trained after the first failed, and grid.json records both with the message."""
    run_config = grid.run_config

    def diverging(
        spec: grid.RunSpec,
        budget: grid.Budget,
        out: Any,
        partners: str = "default",
        settings: dict[str, Any] | None = None,
    ) -> TrainConfig:
        cfg = run_config(spec, budget, out, partners, settings)
        return dataclasses.replace(
            cfg, partners="heuristic", a2c=dataclasses.replace(cfg.a2c, lr=1e4)
        )

    monkeypatch.setattr(grid, "run_config", diverging)
    out = tmp_path / "grid"
    args = ["--envs", "spread", "--methods", "nam", "--seeds", "0", "1", "--jobs", "1"]
    with pytest.raises(SystemExit) as exc:
        main(["reproduce", "--budget", "smoke", "--out", str(out), *args])
    assert exc.value.code == 1
    failures = json.loads((out / "grid.json").read_text())["invocations"][-1]["failures"]
    assert [f.split(":")[0] for f in failures] == [
        "runs/spread/nam/seed_0",
        "runs/spread/nam/seed_1",
    ]
    for seed, failure in enumerate(failures):
        assert f"NonFiniteError: training diverged in chunk 0: seed {seed}: non-finite" in failure
        assert not (out / f"runs/spread/nam/seed_{seed}/final.json").exists()


def test_vmapped_seeds_stop_together_naming_the_diverged_seed() -> None:
    from transam.train.loop import _nonfinite_message
    from transam.train.programs import Plan

    health = {
        "nonfinite": np.array([[False] * 8, [True, True] + [False] * 4 + [True, False]]),
        "nonfinite_update": np.array([0, 7]),
    }
    message = _nonfinite_message(health, [3, 4], 2, Plan(80, 100, 25), [])
    assert message is not None
    assert "seed 4: non-finite policy_loss, value_loss, policy_params at update 7 (step 560)" in (
        message
    )
    assert "seed 3" not in message and "no checkpoint yet" in message
    fine = {"nonfinite": np.zeros((2, 8), bool), "nonfinite_update": np.zeros(2)}
    assert _nonfinite_message(fine, [3, 4], 2, Plan(80, 100, 25), []) is None


def test_nonfinite_check_inside_the_chunk() -> None:
    from types import SimpleNamespace

    from transam.train.a2c import NONFINITE_QUANTITIES, nonfinite_check

    state = SimpleNamespace(policy_params={"w": jnp.ones(3)}, model_params={}, update=30)

    metrics = {k: jnp.zeros(5) for k in NONFINITE_QUANTITIES[:6]}
    ok = nonfinite_check(metrics, state, jnp.int32(25))  # type: ignore[arg-type]
    assert not ok["nonfinite"].any() and int(ok["nonfinite_update"]) == 0
    metrics["value_loss"] = jnp.array([0.0, 0.0, jnp.inf, jnp.nan, 0.0])
    metrics["entropy"] = jnp.array([0.0, 0.0, 0.0, jnp.nan, 0.0])
    bad = nonfinite_check(metrics, state, jnp.int32(25))  # type: ignore[arg-type]
    flagged = [q for q, b in zip(NONFINITE_QUANTITIES, bad["nonfinite"], strict=True) if b]
    assert flagged == ["value_loss"] and int(bad["nonfinite_update"]) == 28  # the first one


# ------------------------------------------------------------------ one writer per run


HOLD = """
import sys, time
from pathlib import Path
from transam.rundir import run_lock
with run_lock(Path(sys.argv[1]), "test holder"):
    print("locked", flush=True)
    time.sleep(600)
"""


def test_second_writer_is_refused_and_a_dead_holder_does_not_block(
    reference: tuple[list[dict[str, Any]], Any], tmp_path: Path
) -> None:
    out = tmp_path / "run"
    assert not train(tiny(out), stop_after_chunks=2).finished
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(out)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "locked"
        who = rf"in use by process {holder.pid} on .*test holder"
        with pytest.raises(RunLockedError, match=who):
            train(tiny(out, resume=True))
        with pytest.raises(RunLockedError, match=who):
            from transam.evaluation.final import evaluate_run

            evaluate_run(out, episodes=8)
        with pytest.raises(SystemExit, match=rf"error: .*in use by process {holder.pid}"):
            main(cli_args(out, "--resume"))
    finally:
        holder.kill()  # SIGKILL: no cleanup runs; the lock file still names it
        holder.wait()
    assert json.loads((out / ".lock").read_text())["pid"] == holder.pid
    assert train(tiny(out, resume=True)).finished
    assert_same_as(reference, out)


def test_lock_without_flock_checks_the_recorded_pid(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_flock(fd: int, op: int) -> None:
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(rundir.fcntl, "flock", no_flock)
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
    try:
        host = rundir.socket.gethostname()
        lock = tmp_path / rundir.LOCK_FILE
        lock.write_text(json.dumps({"pid": alive.pid, "host": host, "command": "x"}))
        with (
            pytest.raises(RunLockedError, match=rf"process {alive.pid} .*no flock"),
            run_lock(tmp_path, "test"),
        ):
            pass
    finally:
        alive.kill()
        alive.wait()
    with run_lock(tmp_path, "test"):  # its holder is dead now
        assert json.loads(lock.read_text())["pid"] == os.getpid()
    assert lock.read_text() == ""  # released


# ------------------------------------------------------------------ signals


def start(out: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "transam.cli", *cli_args(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def wait_for(path: Path, proc: subprocess.Popen[str]) -> None:
    """Poll until ``path`` exists (the run's first checkpoint); fail if the run ends first."""
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.01)


def test_sigterm_checkpoints_and_the_resumed_run_is_identical(
    reference: tuple[list[dict[str, Any]], Any], tmp_path: Path
) -> None:
    out = tmp_path / "run"
    proc = start(out)
    wait_for(out / "checkpoints" / "chunk_000000.msgpack", proc)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM, (stdout, stderr)
    assert "SIGTERM: saving a checkpoint at the end of this chunk" in stderr
    assert re.search(r"stopped by SIGTERM after chunk (\d+)", stdout), stdout
    assert "resume with: transam train" in stdout and "--resume" in stdout
    assert not (out / "final.json").exists()
    chunk = int(re.findall(r"after chunk (\d+)", stdout)[0])
    assert max(rundir.checkpoints(out)) == chunk  # saved at the chunk boundary
    assert train(tiny(out, resume=True)).finished
    assert_same_as(reference, out)


def test_second_ctrl_c_exits_at_once_and_the_run_stays_resumable(
    reference: tuple[list[dict[str, Any]], Any], tmp_path: Path
) -> None:
    out = tmp_path / "run"
    proc = start(out)
    wait_for(out / "checkpoints" / "chunk_000000.msgpack", proc)
    proc.send_signal(signal.SIGINT)
    assert proc.stderr is not None
    line = proc.stderr.readline()
    while line and "SIGINT" not in line:
        line = proc.stderr.readline()
    assert "send it again (Ctrl-C) to stop at once" in line
    proc.send_signal(signal.SIGINT)  # the handler ran: this one ends the process
    proc.communicate(timeout=120)
    assert proc.returncode == -signal.SIGINT  # killed, not a clean stop after the chunk
    assert not (out / "final.json").exists()
    assert train(tiny(out, resume=True)).finished
    assert_same_as(reference, out)


# ------------------------------------------------------------------ failed writes


def test_disk_full_names_the_path_and_keeps_the_previous_checkpoint(
    reference: tuple[list[dict[str, Any]], Any],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    out = tmp_path / "run"
    fsync = os.fsync

    def full(fd: int) -> None:
        if "chunk_000001.msgpack.tmp" in os.readlink(f"/proc/self/fd/{fd}"):
            raise OSError(errno.ENOSPC, "No space left on device")
        fsync(fd)

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(WriteError) as exc:
        train(tiny(out))
    message = str(exc.value)
    assert f"cannot write {out}/checkpoints/chunk_000001.msgpack: No space left" in message
    assert "chunk_000000.msgpack is intact" in message and "--resume" in message
    assert names(out) == ["chunk_000000.msgpack"]  # no temporary file left behind
    monkeypatch.setattr(os, "fsync", fsync)
    assert train(tiny(out, resume=True)).finished
    assert_same_as(reference, out)


def test_unwritable_out_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("not a directory")
    out = tmp_path / "file" / "run"
    with pytest.raises(SystemExit, match=rf"error: cannot write {out}/\.lock: Not a directory"):
        main(cli_args(out))
