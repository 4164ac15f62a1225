"""The hooks a shapebench plugin can implement.

A plugin is a module (or object) named by an entry point in the ``shapebench`` group of its
distribution's metadata::

    [project.entry-points.shapebench]
    mymethod = "shapebench_mymethod.plugin"

The module holds functions decorated with :data:`hookimpl` whose names match the specifications
below. Each hook receives a ``register`` callback, so one plugin can contribute any number of
methods, datasets or metrics::

    from shapebench import hookimpl

    @hookimpl
    def shapebench_register_methods(register):
        register("mymethod", "shapebench_mymethod.method:MyMethod")

``register(name, target)`` takes the public name and either the class itself or a
``"module:Class"`` import path. The import path is loaded only when the name is used, which keeps
``shapebench --help`` and ``shapebench plugins`` fast: a plugin module must not import torch (or
anything else heavy) at import time.

The built-in methods, datasets and metrics register through these same hooks, from entry points in
shapebench's own ``pyproject.toml``.
"""

from __future__ import annotations

from collections.abc import Callable

import pluggy

PROJECT_NAME = "shapebench"
ENTRY_POINT_GROUP = "shapebench"

hookspec = pluggy.HookspecMarker(PROJECT_NAME)
hookimpl = pluggy.HookimplMarker(PROJECT_NAME)

#: ``register(name, target)``: target is a subclass of the interface or a "module:Class" path.
Register = Callable[[str, object], None]


@hookspec
def shapebench_register_methods(register: Register) -> None:
    """Register completion methods: subclasses of :class:`shapebench.api.method.Method`.

    Args:
        register: call ``register(name, target)`` once per method; ``name`` is what
            ``--method`` takes, ``target`` the class or a ``"module:Class"`` path.
    """


@hookspec
def shapebench_register_datasets(register: Register) -> None:
    """Register datasets: subclasses of :class:`shapebench.api.dataset.Dataset`.

    Args:
        register: call ``register(name, target)`` once per dataset; ``name`` is what
            ``--dataset`` takes, ``target`` the class or a ``"module:Class"`` path.
    """


@hookspec
def shapebench_register_metrics(register: Register) -> None:
    """Register metrics: subclasses of :class:`shapebench.api.metric.Metric`.

    Every installed metric whose ``by_default`` is true is computed by every run; the others
    (e.g. ``emd``) when a run asks for them by name (``--metric``). The class is checked when it
    is first used: a class that cannot be imported or built, or whose ``card()`` raises or
    returns an invalid :class:`~shapebench.api.metric.MetricCard`, disables that metric with a
    warning naming the plugin, and the other metrics still run.

    Args:
        register: call ``register(name, target)`` once per metric; ``name`` is what
            ``--metric`` takes (use the class's ``name``: runs log values under it),
            ``target`` the class or a ``"module:Class"`` path.
    """
