"""Test-wide JAX settings: CPU, float32, persistent compilation cache to keep reruns fast."""

from __future__ import annotations

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax

from transam.jaxcache import enable_compilation_cache

enable_compilation_cache()
jax.config.update("jax_enable_x64", False)
