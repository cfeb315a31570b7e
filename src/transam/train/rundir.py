"""The run directory's integrity: atomic writes, verified checkpoints, one writer at a time, and
stopping cleanly on SIGINT/SIGTERM. Imported by the training loop, ``transam evaluate`` and the
grid, so each of these concepts lives here once.

* **Atomic writes** (:func:`write_atomic`): a temporary file in the same directory, fsynced,
  renamed over the target. A failed write (disk full, a read-only or vanished ``--out``) removes
  the temporary file, leaves the target's previous contents untouched and raises
  :class:`WriteError` naming the path.
* **Verified checkpoints** (:func:`save_checkpoint`, :func:`read_checkpoint`): each
  ``chunk_NNNNNN.msgpack`` is a msgpack map ``{"format": "transam-checkpoint", "version": 1,
  "sha256": ..., "state": <the flax-serialised RunnerState>}``; reading checks the digest, then
  decodes the state against the run's structure. A file written before the checksum existed
  (the bare flax msgpack) is verified by decoding alone. The newest ``KEEP_CHECKPOINTS`` are
  kept so that a corrupt newest one has a predecessor; :func:`newest_good_checkpoint` reports
  each one that fails (by name, on stderr) and falls back to the newest good one.
* **One writer** (:func:`run_lock`): ``--out/.lock``, held with ``fcntl.flock`` by train,
  resume and evaluate for as long as they write. The kernel drops the lock when its process
  dies, however it dies, so a stale ``.lock`` file never blocks a resume; the file only names
  the holder (pid, host, command) for the error message. Where the filesystem has no flock
  (some NFS mounts), the holder's pid is checked instead: a live process on this host blocks,
  a dead one does not.
* **Stop requests** (:func:`stop_on_signals`): the first SIGINT/SIGTERM only sets a flag; the
  loop checkpoints at the next chunk boundary and raises :class:`RunInterrupted`. Both signals
  then get their default action back, so a second one ends the process at once (the run stays
  resumable: every file is replaced atomically and metrics past the last checkpoint are
  recomputed on resume). The loop waits for a chunk with :func:`wait_ready`, which returns to
  Python every few milliseconds so that the handler runs at once, not when the chunk ends
  (a signal during a compilation still waits for the compiler).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import jax
import msgpack
from flax import serialization

from transam.train.config import ConfigError

KEEP_CHECKPOINTS = 2
LOCK_FILE = ".lock"
CHECKPOINT_FORMAT = "transam-checkpoint"
CHECKPOINT_VERSION = 1
CORRUPT_SUFFIX = ".corrupt"


# ---------------------------------------------------------------- atomic writes


class WriteError(OSError):
    """A file of the run could not be written; its previous version (if any) is untouched."""

    def __init__(self, path: Path, err: OSError, hint: str = "") -> None:
        super().__init__(err.errno, err.strerror or str(err))
        self.path = path
        self.hint = hint

    def __str__(self) -> str:
        hint = f"; {self.hint}" if self.hint else ""
        return f"cannot write {self.path}: {self.strerror}{hint}"


def write_atomic(path: Path, data: bytes) -> None:
    """Write to a temporary file in the same directory, then rename over ``path``."""
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise WriteError(path, err) from err


def write_json(path: Path, obj: Any) -> None:
    write_atomic(path, (json.dumps(obj, indent=2) + "\n").encode())


# ---------------------------------------------------------------- checkpoints


class CheckpointError(ValueError):
    """A checkpoint file failed verification (truncated, corrupt, or not a run state)."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(f"checkpoint {path} failed verification: {reason}")
        self.path = path
        self.reason = reason


def checkpoints(seed_dir: Path) -> dict[int, Path]:
    """A run's checkpoint files by chunk index (what --resume, evaluation and the grid read)."""
    found = {}
    for p in (seed_dir / "checkpoints").glob("chunk_*.msgpack"):
        try:
            found[int(p.stem.split("_")[1])] = p
        except ValueError:
            continue
    return found


def checkpoint_bytes(state: Any) -> bytes:
    """The bytes of a checkpoint of ``state``: the flax msgpack of the state inside a map that
    carries its SHA-256."""
    payload = serialization.to_bytes(state)
    return msgpack.packb(
        {
            "format": CHECKPOINT_FORMAT,
            "version": CHECKPOINT_VERSION,
            "sha256": hashlib.sha256(payload).hexdigest(),
            "state": payload,
        },
        use_bin_type=True,
    )


def read_checkpoint(path: Path, template: Any) -> Any:
    """The state in checkpoint ``path``, restored onto ``template``'s structure; raises
    :class:`CheckpointError` when the file is unreadable, truncated or does not verify."""
    try:
        data = path.read_bytes()
    except OSError as err:
        raise CheckpointError(path, f"unreadable ({err.strerror})") from err
    if not data:
        raise CheckpointError(path, "empty file")
    try:
        outer = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception as err:  # msgpack raises several types for truncated input
        raise CheckpointError(path, f"not a complete msgpack file ({err})") from err
    if isinstance(outer, dict) and outer.get("format") == CHECKPOINT_FORMAT:
        payload = outer.get("state")
        if not isinstance(payload, bytes):
            raise CheckpointError(path, "no state inside")
        digest = hashlib.sha256(payload).hexdigest()
        if digest != outer.get("sha256"):
            raise CheckpointError(path, f"checksum mismatch (stored {outer.get('sha256')})")
    else:
        payload = data  # written before checksums: the bare flax state (decoding verifies it)
    try:
        return serialization.from_bytes(template, payload)
    except Exception as err:
        reason = f"not a state of this run ({type(err).__name__}: {err})"
        raise CheckpointError(path, reason) from err


def save_checkpoint(seed_dir: Path, chunk: int, state: Any) -> Path:
    ckpt_dir = seed_dir / "checkpoints"
    path = ckpt_dir / f"chunk_{chunk:06d}.msgpack"
    previous = max(checkpoints(seed_dir).items(), default=None)
    try:
        ckpt_dir.mkdir(parents=True, exist_ok=True)
        write_atomic(path, checkpoint_bytes(state))
    except OSError as err:
        kept = f"the previous checkpoint {previous[1]} is intact" if previous else "none kept"
        raise WriteError(
            path, err, f"{kept}; free space or fix the directory, then resume with --resume"
        ) from err
    return path


def prune_checkpoints(seed_dir: Path) -> None:
    """Keep the newest KEEP_CHECKPOINTS checkpoints; drop temporary files of earlier writers
    (killed mid-write: the caller holds the run's lock, so no one else is writing)."""
    for _, p in sorted(checkpoints(seed_dir).items())[:-KEEP_CHECKPOINTS]:
        p.unlink(missing_ok=True)
    for p in (seed_dir / "checkpoints").glob(".chunk_*.msgpack.tmp*"):
        p.unlink(missing_ok=True)


def warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr, flush=True)


def newest_good_checkpoint(
    dirs: list[Path],
    template: Any,
    quarantine: bool = False,
    report: Callable[[str], None] = warn,
) -> tuple[int, list[Any]] | None:
    """(chunk, one state per directory) of the newest chunk checkpointed and verified in every
    directory of ``dirs`` (the seeds of one group), or None when there is none. Every
    checkpoint that fails verification is reported by name; with ``quarantine`` (training,
    which holds the run's lock) it is also renamed to ``*.msgpack.corrupt`` so that it is
    neither read again nor counted among the kept checkpoints."""
    found = [checkpoints(d) for d in dirs]
    common = set.intersection(*(set(f) for f in found)) if found else set()
    for chunk in sorted(common, reverse=True):
        states, bad = [], []
        for f in found:
            try:
                states.append(read_checkpoint(f[chunk], template))
            except CheckpointError as err:
                bad.append(err)
        for failed in bad:
            aside = ""
            if quarantine:
                target = failed.path.with_name(failed.path.name + CORRUPT_SUFFIX)
                with contextlib.suppress(OSError):
                    failed.path.replace(target)
                    aside = f"; moved aside to {target.name}"
            report(f"{failed}{aside}; falling back to an older checkpoint")
        if not bad:
            return chunk, states
    return None


# ---------------------------------------------------------------- one writer per run directory


class RunLockedError(ConfigError):
    """Another process holds the run directory's lock."""


def _holder(fd: int) -> dict[str, Any]:
    try:
        text = os.pread(fd, 4096, 0).decode()
        info = json.loads(text) if text.strip() else {}
    except (OSError, ValueError):
        return {}
    return info if isinstance(info, dict) else {}


def _describe(info: dict[str, Any]) -> str:
    if not info.get("pid"):
        return "another process"
    since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(info.get("since", 0)))
    return (
        f"process {info['pid']} on {info.get('host', '?')} ({info.get('command', '?')}, "
        f"since {since})"
    )


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def run_lock(out: Path, command: str) -> Iterator[None]:
    """Hold ``out``'s lock (creating ``out`` if needed) for the duration; raises
    :class:`RunLockedError` naming the holder when another live process has it, and
    :class:`WriteError` when ``out`` cannot be created or written."""
    path = out / LOCK_FILE
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as err:
        raise WriteError(path, err, f"is --out {str(out)!r} writable?") from err
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            info = _holder(fd)
            kill = f" (kill {info['pid']})" if info.get("pid") else ""
            raise RunLockedError(
                f"{str(out)!r} is in use by {_describe(info)}: one process at a time may "
                f"train, resume or evaluate a run; wait for it to end or stop it{kill}"
            ) from None
        except OSError as err:  # no flock on this filesystem: check the recorded holder
            if err.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                raise WriteError(path, err) from err
            info = _holder(fd)
            pid, host = info.get("pid"), info.get("host")
            if pid and pid != os.getpid() and (host != socket.gethostname() or _alive(pid)):
                where = "" if host == socket.gethostname() else f"; if it has ended, delete {path}"
                raise RunLockedError(
                    f"{str(out)!r} is in use by {_describe(info)} (this filesystem has no "
                    f"flock; the lock file names it){where}"
                ) from None
        me = {"pid": os.getpid(), "host": socket.gethostname(), "command": command}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps({**me, "since": time.time()}).encode(), 0)
        try:
            yield
        finally:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)  # nobody holds it now
    finally:
        os.close(fd)  # releases the flock


# ---------------------------------------------------------------- SIGINT / SIGTERM


class RunInterrupted(KeyboardInterrupt):
    """Training stopped on a signal after checkpointing (a KeyboardInterrupt, so that a grid
    stops too instead of counting it as one failed run)."""

    def __init__(self, signum: int, message: str) -> None:
        super().__init__(message)
        self.signum = signum
        self.message = message

    def __str__(self) -> str:
        return self.message


class StopRequest:
    """Set by the first SIGINT/SIGTERM; the loop reads it at chunk boundaries."""

    def __init__(self) -> None:
        self.signum: int | None = None

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum else ""


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def stop_on_signals() -> Iterator[StopRequest]:
    """Catch the first SIGINT/SIGTERM as a stop request for the duration (main thread only:
    elsewhere signals cannot be caught and the request never comes)."""
    request = StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield request
        return
    previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}

    def handler(signum: int, frame: Any) -> None:
        request.signum = signum
        for s in STOP_SIGNALS:  # a second signal ends the process at once
            signal.signal(s, signal.SIG_DFL)
        print(
            f"\n{signal.Signals(signum).name}: saving a checkpoint at the end of this chunk, "
            "then stopping; send it again (Ctrl-C) to stop at once (the run stays resumable "
            "from its last checkpoint)",
            file=sys.stderr,
            flush=True,
        )

    for s in STOP_SIGNALS:
        signal.signal(s, handler)
    try:
        yield request
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def wait_ready(tree: Any, poll_s: float = 0.02) -> None:
    """Block until every array of ``tree`` is computed, back in Python every ``poll_s`` so that
    a signal handler runs promptly (``jax.block_until_ready`` holds the main thread in XLA for
    the whole chunk, and Python runs handlers only between bytecodes)."""
    for leaf in jax.tree.leaves(tree):
        while hasattr(leaf, "is_ready") and not leaf.is_ready():
            time.sleep(poll_s)
