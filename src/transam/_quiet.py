"""Import third-party packages that print on import (jaxmarl) without polluting stdout."""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """Swallow stdout while importing a chatty package."""
    with contextlib.redirect_stdout(io.StringIO()):
        yield
