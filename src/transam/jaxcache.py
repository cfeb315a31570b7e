"""JAX's persistent compilation cache, shared by the CLI and the tests."""

from __future__ import annotations

import os
from pathlib import Path

import jax


def cache_dir() -> Path:
    """``$TRANSAM_JAX_CACHE`` or ``~/.cache/transam/jax``."""
    default = Path.home() / ".cache" / "transam" / "jax"
    return Path(os.environ.get("TRANSAM_JAX_CACHE", default))


def enable_compilation_cache() -> None:
    """Reuse compiled programs across processes (big programs take seconds to compile)."""
    path = cache_dir()
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
