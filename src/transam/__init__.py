"""TransAM: transformer-based agent modeling for multi-agent RL, in JAX.

The Python API (README "Python API"): :func:`make_env`, :func:`make_model`,
:class:`TrainConfig`, :func:`train`, :func:`evaluate_run`, and :func:`register_env` /
:func:`register_method` to add a game or a method from your own code.
"""

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from transam.compose import make_env
    from transam.evaluation.final import evaluate_run
    from transam.models import make_model
    from transam.registry import register_env, register_method
    from transam.train.config import TrainConfig
    from transam.train.loop import train

__version__ = "0.1.0"

_EXPORTS = {
    "make_env": "transam.compose",
    "make_model": "transam.models",
    "TrainConfig": "transam.train.config",
    "train": "transam.train",  # the package, callable as train.loop.train (its docstring)
    "evaluate_run": "transam.evaluation.final",
    "register_env": "transam.registry",
    "register_method": "transam.registry",
}
"""Each public name and the module that defines it (``train``: a module itself)."""

__all__ = [
    "TrainConfig",
    "evaluate_run",
    "make_env",
    "make_model",
    "register_env",
    "register_method",
    "train",
]


def __getattr__(name: str) -> Any:
    # Lazy, so `import transam` (and the CLI's start) does not import JAX.
    if name == "train":
        return import_module(_EXPORTS[name])
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'transam' has no attribute {name!r}")
