"""TransAM: transformer-based agent modeling for multi-agent RL, in JAX."""

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from transam.compose import make_env

__version__ = "0.1.0"

__all__ = ["make_env"]


def __getattr__(name: str) -> Any:
    # Lazy, so `import transam` (and the CLI's start) does not import JAX.
    if name == "make_env":
        from transam.compose import make_env

        return make_env
    raise AttributeError(f"module 'transam' has no attribute {name!r}")
