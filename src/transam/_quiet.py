"""Import third-party packages that print on import (jaxmarl) without polluting stdout."""

from __future__ import annotations

import contextlib
import io
import os
import sys
from collections.abc import Iterator


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """Swallow stdout, at the Python and the file-descriptor level, while importing.

    jaxmarl's import swaps ``sys.stdout`` before printing, so a Python-level redirect alone
    does not catch it.
    """
    sys.stdout.flush()
    streams = sys.stdout, sys.stderr  # jaxmarl also resets both to sys.__stdout__/__stderr__
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        with contextlib.redirect_stdout(io.StringIO()):
            yield
        sys.stdout.flush()
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)
        sys.stdout, sys.stderr = streams
