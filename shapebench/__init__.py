"""shapebench: benchmark few-shot 3D shape completion.

Everything a plugin needs is importable from here::

    from shapebench import Completion, Context, Method, Metric, MetricCard, hookimpl

:data:`hookimpl` marks the hook implementations declared in :mod:`shapebench.hookspecs`; the
interfaces live in :mod:`shapebench.method`, :mod:`shapebench.dataset` and
:mod:`shapebench.metric`, the data passed between them in :mod:`shapebench.types`.
``docs/api.md`` is their reference (``python -m shapebench.apidoc`` writes it).

Only :data:`hookimpl` is imported eagerly: the other names are loaded on first access (PEP 562),
so that ``import shapebench`` (and ``shapebench --help``) imports neither numpy nor torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from shapebench.hookspecs import hookimpl

__version__ = "0.1.0"

#: Public name -> the module that defines it.
_LAZY: dict[str, str] = {
    "Method": "shapebench.method",
    "TrainingContext": "shapebench.method",
    "TrainerOptions": "shapebench.method",
    "Dataset": "shapebench.dataset",
    "MeshDataset": "shapebench.dataset",
    "MeshOptions": "shapebench.dataset",
    "ObjectLoadError": "shapebench.dataset",
    "Metric": "shapebench.metric",
    "MetricCard": "shapebench.metric",
    "UNIT_SPHERE_FRAME": "shapebench.metric",
    "Context": "shapebench.types",
    "Completion": "shapebench.types",
    "ObjectData": "shapebench.types",
    "ObjectRef": "shapebench.types",
    "Category": "shapebench.types",
    "Supervision": "shapebench.types",
    "TRAIN": "shapebench.types",
    "TRAINED": "shapebench.types",
    "NOVEL": "shapebench.types",
    "NoOptions": "shapebench.options",
    "ShapebenchError": "shapebench.errors",
}

# Written out, not built from _LAZY, so that linters see the re-exports (a test compares them).
__all__ = [
    "__version__",
    "hookimpl",
    "Method",
    "TrainingContext",
    "TrainerOptions",
    "Dataset",
    "MeshDataset",
    "MeshOptions",
    "ObjectLoadError",
    "Metric",
    "MetricCard",
    "UNIT_SPHERE_FRAME",
    "Context",
    "Completion",
    "ObjectData",
    "ObjectRef",
    "Category",
    "Supervision",
    "TRAIN",
    "TRAINED",
    "NOVEL",
    "NoOptions",
    "ShapebenchError",
]

if TYPE_CHECKING:  # for type checkers and IDEs; at run time __getattr__ does the importing
    from shapebench.dataset import Dataset, MeshDataset, MeshOptions, ObjectLoadError
    from shapebench.errors import ShapebenchError
    from shapebench.method import Method, TrainerOptions, TrainingContext
    from shapebench.metric import UNIT_SPHERE_FRAME, Metric, MetricCard
    from shapebench.options import NoOptions
    from shapebench.types import (
        NOVEL,
        TRAIN,
        TRAINED,
        Category,
        Completion,
        Context,
        ObjectData,
        ObjectRef,
        Supervision,
    )


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'shapebench' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later accesses skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
