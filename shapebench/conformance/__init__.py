"""The plugin conformance kit: what ``shapebench check`` runs and :mod:`~.testing` asserts.

Each method, dataset and metric a plugin registers is put through the rules of its interface on a
tiny built-in dataset (the ``synthetic`` dataset, a few thousand points per object, built in a
temporary folder, never in the user's cache):

* every component: its modules import without torch or Lightning, in a fresh interpreter
  (:mod:`~.imports`); the class implements its interface, and its options parse from
  ``KEY=VALUE`` strings and round-trip through the config that runs log (:mod:`~.options`);
* a method (:mod:`~.methods`): completes 50-point contexts into finite ``(n, 3)`` arrays of a
  sensible size, also when the points are duplicated or all the same (or raises, a failed
  object), gives identical points for the same seed, uses one Lightning namespace; a trainable
  method trains for a few steps and a fresh instance reloads its checkpoint;
* a dataset (:mod:`~.datasets`): gives categories and splits, objects that load in the
  normalised frame, and the training arrays it provides;
* a metric (:mod:`~.metrics`): its card is valid, and its value is zero on identical clouds and
  positive otherwise (for a higher-is-better metric: better on identical clouds than on
  different ones).

The checks are generators of one :class:`~.framework.CheckResult` per check
(:mod:`~.framework`: results, the runner of one check, the scratch :class:`~.framework.CheckEnv`);
:mod:`~.runner` selects the components and runs their checks, the command line prints them and
:mod:`~.testing` turns failures into assertion errors. Imports :mod:`shapebench.registry` and
the rooms below it; only ``cli/`` imports this room.

This package re-exports the public names of its modules: it is what the old paths of the module
that was split, ``shapebench.registry.check`` and 0.1's ``shapebench.check``, import (with a
warning, see ``shapebench/_moved.py``).
"""

from __future__ import annotations

from shapebench.conformance.datasets import FRAME_SLACK
from shapebench.conformance.framework import (
    CONTEXT_SIZE,
    FAIL,
    N_CONTEXTS,
    PASS,
    SKIP,
    TINY_DATASET_OPTIONS,
    CheckEnv,
    CheckFailed,
    CheckResult,
    CheckSkipped,
    Component,
    ComponentReport,
    failure_lines,
    summary,
    tiny_values,
)
from shapebench.conformance.imports import HEAVY_MODULES
from shapebench.conformance.methods import (
    MAX_POINTS_FACTOR,
    MAX_RADIUS,
    TINY_METHOD_OPTIONS,
    completion_problem,
    method_check_options,
)
from shapebench.conformance.runner import (
    check_component,
    class_component,
    component,
    distribution_components,
    distributions,
    installed_components,
    run_checks,
    select_components,
)

__all__ = [
    "CONTEXT_SIZE",
    "FAIL",
    "FRAME_SLACK",
    "HEAVY_MODULES",
    "MAX_POINTS_FACTOR",
    "MAX_RADIUS",
    "N_CONTEXTS",
    "PASS",
    "SKIP",
    "TINY_DATASET_OPTIONS",
    "TINY_METHOD_OPTIONS",
    "CheckEnv",
    "CheckFailed",
    "CheckResult",
    "CheckSkipped",
    "Component",
    "ComponentReport",
    "check_component",
    "class_component",
    "completion_problem",
    "component",
    "distribution_components",
    "distributions",
    "failure_lines",
    "installed_components",
    "method_check_options",
    "run_checks",
    "select_components",
    "summary",
    "tiny_values",
]
