"""Import jaxmarl's environment modules quietly and without its package ``__init__``s.

jaxmarl prints on import, and its ``__init__``s import every environment it has (SMAX, Hanabi,
STORM, JaxNav...): about 5 s of every process's start, for the two or three modules we use.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import os
import sys
from collections.abc import Iterator
from types import ModuleType
from typing import Any

_PACKAGES = ("jaxmarl", "jaxmarl.environments")


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


def _deferred_package(name: str) -> ModuleType:
    """The package ``name``, created but not executed: a missing attribute that names a
    submodule imports that submodule (as ``from jaxmarl.environments import spaces`` would),
    and any other runs the package's own ``__init__`` (``jaxmarl.make``, ``from
    jaxmarl.environments import SMAX``), so the package is whole for whoever uses it."""
    spec = importlib.util.find_spec(name)
    assert spec is not None and spec.loader is not None, name
    module, loader = importlib.util.module_from_spec(spec), spec.loader

    def __getattr__(attr: str) -> Any:
        if importlib.util.find_spec(f"{name}.{attr}") is not None:  # a submodule: just it
            return importlib.import_module(f"{name}.{attr}")
        del module.__dict__["__getattr__"]  # once: the real __init__ now
        with quiet():
            loader.exec_module(module)
        return getattr(module, attr)

    module.__dict__["__getattr__"] = __getattr__  # PEP 562
    return module


@contextlib.contextmanager
def jaxmarl_modules() -> Iterator[None]:
    """Import jaxmarl's modules inside this block quietly, its packages deferred."""
    with quiet():
        for name in _PACKAGES:
            if name not in sys.modules:
                sys.modules[name] = module = _deferred_package(name)
                parent, _, child = name.rpartition(".")
                if parent:
                    setattr(sys.modules[parent], child, module)
        yield
