"""What ``shapebench check`` checks and how: the components it selects (those of a distribution,
those named, or every installed one), and the checks of each, one result at a time."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from shapebench.api.errors import ShapebenchError, UnknownNameError
from shapebench.conformance.datasets import dataset_checks
from shapebench.conformance.framework import (
    FAIL,
    SKIP,
    CheckEnv,
    CheckResult,
    Component,
    ComponentReport,
    run_check,
)
from shapebench.conformance.imports import check_imports
from shapebench.conformance.methods import method_checks
from shapebench.conformance.metrics import metric_checks
from shapebench.registry.discovery import KINDS, Registry

# -- finding components -----------------------------------------------------------------------


def component(registry: Registry, kind: str, name: str) -> Component:
    """The registered ``kind`` called ``name``; :class:`UnknownNameError` if there is none."""
    reg = registry.get(kind, name)
    return Component(kind, name, f"{reg.plugin.distribution} {reg.plugin.version}", reg)


def class_component(kind: str, cls: type) -> Component:
    """A class given directly (a plugin's test suite checking its class before registering)."""
    name = getattr(cls, "name", "") or cls.__name__
    return Component(kind, name, cls.__module__, None, cls)


def distributions(registry: Registry) -> list[str]:
    """The installed distributions that register plugins."""
    return sorted({p.distribution for p in registry.plugins})


def _norm(name: str) -> str:
    return name.lower().replace("_", "-").replace(".", "-")


#: How the registry words a plugin's own failure (not one of its components'): see discover().
_PLUGIN_ERRORS = ("failed to import", "hook ", "implements an unknown hook", "disabled")


def distribution_components(registry: Registry, dist: str) -> list[Component]:
    """Every method, dataset and metric the installed distribution ``dist`` registers.

    A plugin of it that failed to import is a :class:`Component` of kind ``plugin`` (its check
    fails with the error)."""
    plugins = [p for p in registry.plugins if _norm(p.distribution) == _norm(dist)]
    if not plugins:
        hint = "run 'shapebench plugins' to see the installed distributions"
        raise UnknownNameError("distribution", dist, distributions(registry), hint)
    out = []
    for plugin in plugins:
        if plugin.error and plugin.error.startswith(_PLUGIN_ERRORS):
            out.append(Component("plugin", plugin.name, f"{plugin.distribution} {plugin.version}"))
        for kind in KINDS:
            for name in plugin.provides[kind]:
                out.append(Component(kind, name, f"{plugin.distribution} {plugin.version}"))
    order = {kind: i for i, kind in enumerate(("plugin", *KINDS))}
    return sorted(out, key=lambda c: (order[c.kind], c.name))


def installed_components(registry: Registry) -> list[Component]:
    """Every component of every installed distribution."""
    return [c for d in distributions(registry) for c in distribution_components(registry, d)]


def select_components(
    registry: Registry,
    distribution: str | None = None,
    methods: Iterable[str] = (),
    datasets: Iterable[str] = (),
    metrics: Iterable[str] = (),
) -> list[Component]:
    """What ``shapebench check`` checks: the components of ``distribution`` and those named;
    every installed one when nothing is named. Unknown names raise :class:`UnknownNameError`."""
    named = [("method", n) for n in methods] + [("dataset", n) for n in datasets]
    comps = [component(registry, kind, n) for kind, n in named]
    comps += [component(registry, "metric", n) for n in metrics]
    if distribution:
        return distribution_components(registry, distribution) + comps
    return comps or installed_components(registry)


# -- running the checks of a component --------------------------------------------------------


def run_checks(
    comp: Component,
    env: CheckEnv,
    options: dict[str, Any] | None = None,
    data_root: Path | str | None = None,
) -> Iterator[CheckResult]:
    """The checks of ``comp``, one result at a time. ``options`` override its check options
    (``-O``/``-D``); ``data_root`` is the local copy a dataset that needs one reads."""
    if comp.kind == "plugin":
        error = next(p.error for p in env.registry.plugins if p.name == comp.name) or ""
        yield CheckResult("imports", SKIP if error.startswith("disabled") else FAIL, error)
        return
    if comp.registration is None and comp.cls is None:
        try:
            comp.registration = env.registry.get(comp.kind, comp.name)
        except ShapebenchError as exc:
            yield CheckResult("interface", FAIL, exc.message)
            return
    yield run_check("imports", lambda: check_imports(comp))[0]
    checks = {"method": method_checks, "dataset": dataset_checks, "metric": metric_checks}
    yield from checks[comp.kind](comp, env, dict(options or {}), data_root)


def check_component(
    comp: Component,
    env: CheckEnv,
    options: dict[str, Any] | None = None,
    data_root: Path | str | None = None,
) -> ComponentReport:
    """Every check of ``comp`` (see :func:`run_checks`), as one report."""
    return ComponentReport(comp, list(run_checks(comp, env, options, data_root)))
