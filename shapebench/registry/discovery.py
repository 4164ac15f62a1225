"""Plugin discovery: entry points in the ``shapebench`` group, loaded one at a time.

pluggy's ``load_setuptools_entrypoints`` stops at the first plugin that fails to import. Here each
entry point is loaded on its own: a plugin that raises on import (or inside a hook) becomes a
warning naming it, and every other plugin still loads. ``shapebench plugins`` shows the failures.

Metric classes are checked when they are loaded (their card must pass
:meth:`~shapebench.api.metric.MetricCard.validate`, see
:func:`shapebench.api.metric.check_metric`). Since a
run computes every installed metric, asking for the metric names loads and checks them all: a
metric whose class cannot be imported, cannot be built or states a bad card is left out with a
warning naming its plugin, and the other metrics still run. Asking for that metric by name is an
error saying why.

Set ``SHAPEBENCH_DISABLE_PLUGINS=name1,name2`` (entry-point or distribution names) to skip plugins.
"""

from __future__ import annotations

import importlib
import os
import traceback
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field
from importlib.metadata import EntryPoint, entry_points
from typing import Any

import pluggy

from shapebench.api import hookspecs
from shapebench.api.errors import PluginConflictError, ShapebenchError, UnknownNameError

KINDS = ("method", "dataset", "metric")
_HOOK_FOR_KIND = {
    "method": "shapebench_register_methods",
    "dataset": "shapebench_register_datasets",
    "metric": "shapebench_register_metrics",
}


class PluginWarning(UserWarning):
    """A plugin could not be loaded; the others are unaffected."""


@dataclass
class PluginInfo:
    """One entry point of the ``shapebench`` group and what it contributed."""

    name: str
    module: str
    distribution: str
    version: str
    error: str | None = None
    provides: dict[str, list[str]] = field(default_factory=lambda: {k: [] for k in KINDS})


@dataclass
class Registration:
    """A name offered by a plugin; ``load()`` imports the class on first use."""

    kind: str
    name: str
    target: Any
    plugin: PluginInfo
    #: Why this name cannot be used (its class failed to load or its metric card is bad).
    error: ShapebenchError | None = None
    reason: str = ""

    def load(self) -> type:
        """The registered class, imported on first use (and, for a metric, checked)."""
        if self.error is not None:
            raise self.error
        target = self.target
        if isinstance(target, str):
            module_name, _, attr = target.partition(":")
            try:
                target = getattr(importlib.import_module(module_name), attr)
            except Exception as exc:  # a broken plugin must not take the CLI down
                self.error = self._failure(
                    f"failed to load {self.target!r}: {type(exc).__name__}: {exc}",
                    f"reinstall or upgrade {self.plugin.distribution}",
                )
                raise self.error from exc
        if self.kind == "metric":
            self._check_metric(target)
        self.target = target
        return target

    def _check_metric(self, cls: object) -> None:
        from shapebench.api.metric import check_metric  # imports numpy: not at start-up

        try:
            check_metric(cls)
        except ValueError as exc:
            self.error = self._failure(
                f"is disabled: {exc}",
                f"fix the metric's card() in {self.plugin.distribution} (the MetricCard "
                "reference, docs/reference/api/metric.md, lists the allowed values)",
            )
            raise self.error from exc

    def _failure(self, what: str, fix: str) -> ShapebenchError:
        self.reason = what
        return ShapebenchError(
            f"{self.kind} {self.name!r} from plugin {self.plugin.name!r} "
            f"({self.plugin.distribution} {self.plugin.version}) {what}",
            f"{fix}, or disable it with SHAPEBENCH_DISABLE_PLUGINS={self.plugin.name}",
        )


class Registry:
    """Every method, dataset and metric the installed plugins provide."""

    def __init__(self) -> None:
        self.plugins: list[PluginInfo] = []
        self._entries: dict[str, dict[str, list[Registration]]] = {k: {} for k in KINDS}

    # -- building ------------------------------------------------------------------------------
    def add(self, kind: str, name: str, target: Any, plugin: PluginInfo) -> None:
        if not isinstance(name, str) or not name:
            raise TypeError(f"register() needs a non-empty name, got {name!r}")
        self._entries[kind].setdefault(name, []).append(Registration(kind, name, target, plugin))
        plugin.provides[kind].append(name)

    # -- querying ------------------------------------------------------------------------------
    def names(self, kind: str) -> list[str]:
        """The usable names of ``kind``. For metrics this loads and checks every class (a run
        computes them all): one that fails is left out with a :class:`PluginWarning`."""
        if kind == "metric":
            return sorted(name for name, regs in self._entries[kind].items() if _usable(regs))
        return sorted(self._entries[kind])

    def conflicts(self) -> list[tuple[str, str, list[Registration]]]:
        return [
            (kind, name, regs)
            for kind in KINDS
            for name, regs in sorted(self._entries[kind].items())
            if len(regs) > 1
        ]

    def get(self, kind: str, name: str) -> Registration:
        regs = self._entries[kind].get(name)
        if not regs:
            raise UnknownNameError(kind, name, self.names(kind))
        if len(regs) > 1:
            owners = " and ".join(f"{r.plugin.distribution} {r.plugin.version}" for r in regs)
            raise PluginConflictError(
                f"{kind} {name!r} is provided by more than one installed distribution: {owners}",
                "uninstall one of them, or disable one with SHAPEBENCH_DISABLE_PLUGINS=<plugin>",
            )
        return regs[0]

    def load(self, kind: str, name: str) -> type:
        return self.get(kind, name).load()


def _usable(regs: list[Registration]) -> bool:
    """Whether a name loads; a name two plugins offer stays listed, for ``get`` to report."""
    if len(regs) > 1:
        return True
    reg = regs[0]
    if reg.error is not None:
        return False
    try:
        reg.load()
    except ShapebenchError as exc:
        note = f"{reg.kind} {reg.name!r} {reg.reason or exc.message}"
        reg.plugin.error = f"{reg.plugin.error}; {note}" if reg.plugin.error else note
        warnings.warn(
            f"shapebench plugin {reg.plugin.name!r} ({reg.plugin.distribution} "
            f"{reg.plugin.version}): {note}; the other {reg.kind}s are still available",
            PluginWarning,
            stacklevel=3,
        )
        return False
    return True


def _disabled() -> set[str]:
    raw = os.environ.get("SHAPEBENCH_DISABLE_PLUGINS", "")
    return {part.strip() for part in raw.split(",") if part.strip()}


def _dist_of(ep: EntryPoint) -> tuple[str, str]:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return ("unknown", "unknown")
    return (dist.metadata["Name"] or dist.name, dist.version)


def _describe_error(exc: BaseException) -> str:
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" ({frames[-1].filename}:{frames[-1].lineno})" if frames else ""
    return f"{type(exc).__name__}: {exc}{where}"


def discover(eps: Iterable[EntryPoint] | None = None) -> Registry:
    """Load every ``shapebench`` entry point and collect what each registers."""
    registry = Registry()
    pm = pluggy.PluginManager(hookspecs.PROJECT_NAME)
    pm.add_hookspecs(hookspecs)
    disabled = _disabled()
    if eps is None:
        eps = entry_points(group=hookspecs.ENTRY_POINT_GROUP)
    seen: set[tuple[str, str]] = set()
    for ep in sorted(eps, key=lambda e: (e.name, e.value)):
        dist, version = _dist_of(ep)
        if (ep.name, ep.value) in seen:  # the same distribution seen twice on sys.path
            continue
        seen.add((ep.name, ep.value))
        info = PluginInfo(ep.name, ep.value, dist, version)
        registry.plugins.append(info)
        if ep.name in disabled or dist in disabled:
            info.error = "disabled by SHAPEBENCH_DISABLE_PLUGINS"
            continue
        try:
            module = ep.load()
            pm.register(module, name=f"{dist}:{ep.name}")
        except Exception as exc:
            info.error = f"failed to import: {_describe_error(exc)}"
            warnings.warn(
                f"shapebench plugin {ep.name!r} ({dist} {version}) {info.error}; "
                "the other plugins are still available",
                PluginWarning,
                stacklevel=2,
            )
            continue
        _collect(pm, module, info, registry)
    return registry


def _collect(pm: pluggy.PluginManager, module: object, info: PluginInfo, reg: Registry) -> None:
    """Call this plugin's hook implementations, attributing what they register to it."""
    for kind, hook_name in _HOOK_FOR_KIND.items():
        for impl in getattr(pm.hook, hook_name).get_hookimpls():
            if impl.plugin is not module:
                continue
            try:
                impl.function(register=lambda n, t, k=kind: reg.add(k, n, t, info))
            except Exception as exc:
                info.error = f"hook {hook_name} raised {_describe_error(exc)}"
                warnings.warn(
                    f"shapebench plugin {info.name!r} ({info.distribution}) {info.error}",
                    PluginWarning,
                    stacklevel=3,
                )
    try:  # a hookimpl whose name matches no spec is a typo that would otherwise do nothing
        pm.check_pending()
    except pluggy.PluginValidationError as exc:
        info.error = f"implements an unknown hook: {exc}"
        warnings.warn(f"shapebench plugin {info.name!r} {info.error}", PluginWarning, stacklevel=3)
        pm.unregister(module)


_REGISTRY: Registry | None = None


def get_registry() -> Registry:
    """The process-wide registry, discovered on first use."""
    global _REGISTRY
    if _REGISTRY is None:
        _REGISTRY = discover()
    return _REGISTRY
