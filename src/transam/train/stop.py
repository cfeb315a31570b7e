"""Stopping a training run cleanly on SIGINT/SIGTERM.

The first SIGINT/SIGTERM only sets a flag (:func:`stop_on_signals`); the loop checkpoints at
the next chunk boundary and raises :class:`RunInterrupted`. Both signals then get their default
action back, so a second one ends the process at once (the run stays resumable: every file is
replaced atomically and metrics past the last checkpoint are recomputed on resume). The loop
waits for a chunk with :func:`wait_ready`, which returns to Python every few milliseconds so
that the handler runs at once, not when the chunk ends (a signal during a compilation still
waits for the compiler).
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import jax


class RunInterrupted(KeyboardInterrupt):
    """Training stopped on a signal after checkpointing (a KeyboardInterrupt, so that a grid
    stops too instead of counting it as one failed run)."""

    def __init__(self, signum: int, message: str) -> None:
        super().__init__(message)
        self.signum = signum
        self.message = message

    def __str__(self) -> str:
        return self.message

    def __reduce__(self) -> tuple[type, tuple[int, str]]:
        # picklable with both arguments: a grid's worker process sends it to the parent
        return (RunInterrupted, (self.signum, self.message))


class StopRequest:
    """Set by the first SIGINT/SIGTERM; the loop reads it at chunk boundaries."""

    def __init__(self) -> None:
        self.signum: int | None = None

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum else ""


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def handling_stop_signals(handler: Callable[[int, Any], None]) -> Iterator[None]:
    """``handler`` for SIGINT and SIGTERM for the duration, then the previous handlers again
    (main thread only: elsewhere signals cannot be caught, and they keep their actions)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    for s in STOP_SIGNALS:
        signal.signal(s, handler)
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@contextlib.contextmanager
def stop_on_signals() -> Iterator[StopRequest]:
    """Catch the first SIGINT/SIGTERM as a stop request for the duration (main thread only:
    elsewhere signals cannot be caught and the request never comes)."""
    request = StopRequest()

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

    with handling_stop_signals(handler):
        yield request


def wait_ready(tree: Any, poll_s: float = 0.02) -> None:
    """Block until every array of ``tree`` is computed, back in Python every ``poll_s`` so that
    a signal handler runs promptly (``jax.block_until_ready`` holds the main thread in XLA for
    the whole chunk, and Python runs handlers only between bytecodes)."""
    for leaf in jax.tree.leaves(tree):
        while hasattr(leaf, "is_ready") and not leaf.is_ready():
            time.sleep(poll_s)
