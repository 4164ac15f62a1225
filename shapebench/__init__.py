"""shapebench: benchmark few-shot 3D shape completion.

Plugins import :data:`hookimpl` from here to implement the hooks declared in
:mod:`shapebench.hookspecs`; the interfaces they implement live in :mod:`shapebench.method`,
:mod:`shapebench.dataset` and :mod:`shapebench.metric`.
"""

from shapebench.hookspecs import hookimpl

__version__ = "0.1.0"

__all__ = ["__version__", "hookimpl"]
