"""A2C training: the update, its configuration and presets, the compiled programs, logging and
the loop (the run directory it writes is :mod:`transam.rundir`'s).

The package is callable: ``transam.train(config)`` is :func:`transam.train.loop.train`. Python
binds ``transam.train`` to this subpackage once anything imports it, so the Python API's
``from transam import train`` must be this package for ``train(config)`` to work either way.
Nothing here imports JAX until it is called.
"""

import sys
import types
from typing import Any


class _CallablePackage(types.ModuleType):
    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        from transam.train.loop import train

        return train(*args, **kwargs)


sys.modules[__name__].__class__ = _CallablePackage
