"""shapebench: benchmark few-shot 3D shape completion.

Everything a plugin needs is importable from here::

    from shapebench import Completion, Context, Method, Metric, MetricCard, hookimpl

and, for notebooks, runs and their results as pandas DataFrames (docs/python.md)::

    scores = shapebench.evaluate("gauss", "synthetic", contexts=(50, 1000))
    scores = shapebench.load_results("synthetic", "trained")

:data:`hookimpl` marks the hook implementations declared in :mod:`shapebench.api.hookspecs`; the
interfaces live in :mod:`shapebench.api.method`, :mod:`shapebench.api.dataset` and
:mod:`shapebench.api.metric`, the data passed between them in :mod:`shapebench.api.types`.
Their reference is the documentation site's API section (``docs/reference/api/``, rendered from
these docstrings by ``mkdocs build``).

Only :data:`hookimpl` is imported eagerly: the other names are loaded on first access (PEP 562),
so that ``import shapebench`` (and ``shapebench --help``) imports neither numpy nor torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from shapebench import _moved
from shapebench.api.hookspecs import hookimpl

_moved.install()  # the import paths of 0.1 keep working, with a warning (shapebench/_moved.py)

__version__ = "0.1.0"

#: Public name -> the module that defines it.
_LAZY: dict[str, str] = {
    "Method": "shapebench.api.method",
    "TrainingContext": "shapebench.api.method",
    "TrainerOptions": "shapebench.api.method",
    "Dataset": "shapebench.api.dataset",
    "MeshDataset": "shapebench.api.dataset",
    "MeshOptions": "shapebench.api.dataset",
    "ObjectLoadError": "shapebench.api.dataset",
    "Metric": "shapebench.api.metric",
    "MetricCard": "shapebench.api.metric",
    "UNIT_SPHERE_FRAME": "shapebench.api.metric",
    "NotApplicable": "shapebench.api.metric",
    "Context": "shapebench.api.types",
    "Completion": "shapebench.api.types",
    "ObjectData": "shapebench.api.types",
    "ObjectRef": "shapebench.api.types",
    "Category": "shapebench.api.types",
    "Supervision": "shapebench.api.types",
    "GroundTruthArray": "shapebench.api.types",
    "TRAIN": "shapebench.api.types",
    "TRAINED": "shapebench.api.types",
    "NOVEL": "shapebench.api.types",
    "NoOptions": "shapebench.api.options",
    "ShapebenchError": "shapebench.api.errors",
    # Results as DataFrames, for notebooks (docs/python.md).
    "load_results": "shapebench.boards.frames",
    "load_leaderboard": "shapebench.boards.frames",
    "evaluate": "shapebench.notebook",
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
    "NotApplicable",
    "Context",
    "Completion",
    "ObjectData",
    "ObjectRef",
    "Category",
    "Supervision",
    "GroundTruthArray",
    "TRAIN",
    "TRAINED",
    "NOVEL",
    "NoOptions",
    "ShapebenchError",
    "load_results",
    "load_leaderboard",
    "evaluate",
]

if TYPE_CHECKING:  # for type checkers and IDEs; at run time __getattr__ does the importing
    from shapebench.api.dataset import Dataset, MeshDataset, MeshOptions, ObjectLoadError
    from shapebench.api.errors import ShapebenchError
    from shapebench.api.method import Method, TrainerOptions, TrainingContext
    from shapebench.api.metric import UNIT_SPHERE_FRAME, Metric, MetricCard, NotApplicable
    from shapebench.api.options import NoOptions
    from shapebench.api.types import (
        NOVEL,
        TRAIN,
        TRAINED,
        Category,
        Completion,
        Context,
        GroundTruthArray,
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
