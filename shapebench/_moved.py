"""Import paths of shapebench 0.1 that moved when the package was regrouped into rooms, and
documented paths of the rooms that moved since.

``import shapebench.types`` (or ``from shapebench.testing import check_method``, or
``pytest_plugins = ["shapebench.registry.testing"]``) keeps working for one release: the old name
is bound to the module at its new place, the very same module object, and a
:class:`DeprecationWarning` names the new path. Remove this table in 0.3.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import warnings
from types import ModuleType

#: Old module -> the module that now holds its code (docs/architecture.md has the rooms). Two old
#: modules are packages now: ``shapebench.registry`` hands on the names of its ``discovery``
#: module with the same warning, ``shapebench.cli`` exports ``cli`` and ``main`` as before. The
#: plugin checks left ``registry/`` for a room of their own, split by concern: the old module
#: ``check`` is the package ``shapebench.conformance``, which re-exports its public names.
MOVED: dict[str, str] = {
    "shapebench.hookspecs": "shapebench.api.hookspecs",
    "shapebench.method": "shapebench.api.method",
    "shapebench.dataset": "shapebench.api.dataset",
    "shapebench.metric": "shapebench.api.metric",
    "shapebench.types": "shapebench.api.types",
    "shapebench.options": "shapebench.api.options",
    "shapebench.errors": "shapebench.api.errors",
    "shapebench.protocol": "shapebench.api.protocol",
    "shapebench.contexts": "shapebench.api.contexts",
    "shapebench.resolve": "shapebench.registry.resolve",
    "shapebench.variant": "shapebench.registry.variant",
    "shapebench.code_digest": "shapebench.registry.code_digest",
    "shapebench.check": "shapebench.conformance",
    "shapebench.testing": "shapebench.conformance.testing",
    "shapebench.registry.check": "shapebench.conformance",
    "shapebench.registry.testing": "shapebench.conformance.testing",
    "shapebench.tracking": "shapebench.store.tracking",
    "shapebench.records": "shapebench.store.records",
    "shapebench.merge": "shapebench.store.merge",
    "shapebench.listing": "shapebench.store.listing",
    "shapebench.locks": "shapebench.store.locks",
    "shapebench.provenance": "shapebench.store.provenance",
    "shapebench.ui": "shapebench.store.ui",
    "shapebench.training": "shapebench.train.training",
    "shapebench.lightning_fit": "shapebench.train.lightning_fit",
    "shapebench.checkpoints": "shapebench.train.checkpoints",
    "shapebench.reference_checkpoints": "shapebench.train.references",
    "shapebench.orchestrate": "shapebench.evaluation.orchestrate",
    "shapebench.runner": "shapebench.evaluation.runner",
    "shapebench.pictures": "shapebench.evaluation.pictures",
    "shapebench.prepare": "shapebench.evaluation.prepare",
    "shapebench.leaderboard": "shapebench.boards.leaderboard",
    "shapebench.board_stats": "shapebench.boards.stats",
    "shapebench.figures": "shapebench.boards.figures",
    "shapebench.cost": "shapebench.boards.cost",
    "shapebench.paper": "shapebench.boards.paper",
    "shapebench.html_report": "shapebench.boards.html_report",
    "shapebench.sweep": "shapebench.sweeps.spec",
    "shapebench.sweep_plan": "shapebench.sweeps.plan",
    "shapebench.cluster": "shapebench.sweeps.cluster",
    "shapebench.launchers": "shapebench.sweeps.launchers",
    "shapebench.sweep_cli": "shapebench.sweeps.submit",
    "shapebench.report": "shapebench.cli.printing",
    "shapebench.implicit.module_base": "shapebench.train.lightning_module",
}


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Answers the old names of :data:`MOVED` with the module at its new place."""

    def __init__(self) -> None:
        self._specs: dict[str, importlib.machinery.ModuleSpec] = {}

    def find_spec(self, fullname: str, path: object = None, target: object = None):
        if fullname not in MOVED:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        new = MOVED[spec.name]
        warnings.warn(
            f"{spec.name} has moved to {new}; import it from there "
            "(the old path works until shapebench 0.3)",
            DeprecationWarning,
            stacklevel=2,
        )
        module = importlib.import_module(new)
        self._specs[spec.name] = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        """The module ran under its new name already; only undo the import system's
        overwriting ``__spec__`` with the old name's (pickling and reloads read it)."""
        module.__spec__ = self._specs.pop(module.__spec__.name, module.__spec__)


def install() -> None:
    """Put the finder first on :data:`sys.meta_path` (once): it answers only the old names, and
    one of them (``shapebench.reference_checkpoints``) is also a data folder that the path finder
    would take for a namespace package."""
    if not any(isinstance(f, _MovedModules) for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedModules())
