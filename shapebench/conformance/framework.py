"""What every check shares: results, the runner of one check, the components and the scratch
environment.

A check is a function that returns a message (or ``(message, value)`` to hand a value to later
checks), raises :class:`CheckFailed` for a broken rule and :class:`CheckSkipped` when it cannot
run here; :func:`run_check` runs it and turns the outcome into a :class:`CheckResult`, with what
the component printed and warned kept aside. :class:`CheckEnv` is the scratch folder the checks
build their tiny dataset and trainings in. :func:`summary` and :func:`failure_lines` are what
``shapebench check`` prints last.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import shutil
import tempfile
import time
import traceback
import warnings
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shapebench.api.errors import ShapebenchError
from shapebench.registry.discovery import Registration, Registry, get_registry

PASS, FAIL, SKIP = "pass", "fail", "skip"

#: The context size methods are checked at: the smallest of the paper's protocol.
CONTEXT_SIZE = 50
#: How many contexts (from different objects) a method completes.
N_CONTEXTS = 3

#: Dataset options that make a dataset tiny, applied where the options have that field.
TINY_DATASET_OPTIONS: dict[str, Any] = {
    "test_per_category": 1,
    "train_per_category": 1,
    "max_test_per_category": 1,
    "surface_candidates": 3000,
    "gt_points": 2000,
    "sdf_samples": 4000,
    "occupancy_samples": 4000,
    "complete_points": 512,
}


# -- results ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class CheckResult:
    """The outcome of one check of one component."""

    #: The check's name (``imports``, ``options``, ``complete``...).
    check: str
    #: ``"pass"``, ``"fail"`` or ``"skip"``.
    status: str
    #: What was found: why it failed or was skipped, or what passed.
    reason: str = ""
    #: The traceback of an unexpected exception (shown with ``--debug``).
    traceback: str = ""
    #: What the component printed and warned during the check.
    output: str = ""
    seconds: float = 0.0

    @property
    def failed(self) -> bool:
        return self.status == FAIL


@dataclass
class Component:
    """A method, dataset or metric to check: registered under a name, or a class given directly."""

    kind: str
    name: str
    #: Where it comes from: ``"<distribution> <version>"``, or the class's module.
    origin: str
    registration: Registration | None = None
    cls: type | None = None

    @property
    def title(self) -> str:
        return f"{self.kind} {self.name} ({self.origin})"

    def load(self) -> type:
        if self.cls is None:
            assert self.registration is not None
            self.cls = self.registration.load()
        return self.cls

    def modules(self) -> list[str]:
        """The modules importing it imports: the plugin's entry point, then the class's."""
        out = []
        if self.registration is not None:
            out.append(self.registration.plugin.module)
            target = self.registration.target
            if isinstance(target, str):
                out.append(target.partition(":")[0])
            elif isinstance(target, type):
                out.append(target.__module__)
        elif self.cls is not None and _importable(self.cls):
            out.append(self.cls.__module__)
        return list(dict.fromkeys(out))


@dataclass
class ComponentReport:
    component: Component
    results: list[CheckResult] = field(default_factory=list)

    @property
    def failures(self) -> list[CheckResult]:
        return [r for r in self.results if r.failed]


class CheckFailed(Exception):
    """A check found a rule broken; the message says which."""


class CheckSkipped(Exception):
    """A check cannot run here; the message says why."""


def _importable(cls: type) -> bool:
    return cls.__module__ != "__main__" and "<locals>" not in cls.__qualname__


def class_path(cls: type) -> str:
    """``module:QualName``, as a plugin registers a class."""
    return f"{cls.__module__}:{cls.__qualname__}"


def run_check(name: str, fn: Callable[[], Any]) -> tuple[CheckResult, Any]:
    """Run one check; return its result and the value ``fn`` returned with its message.

    ``fn`` returns a message, or ``(message, value)`` to hand a value to later checks. What the
    component prints or warns is kept in the result, so that it does not interleave with the
    report.
    """
    out = io.StringIO()
    start = time.perf_counter()
    value = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
                got = fn()
            message, value = got if isinstance(got, tuple) else (got, None)
            status, tb = PASS, ""
        except CheckFailed as exc:
            status, message, tb = FAIL, str(exc), _traceback_of_cause(exc)
        except CheckSkipped as exc:
            status, message, tb = SKIP, str(exc), ""
        except Exception as exc:  # the component's own error: a failure of this check
            status, message, tb = FAIL, f"raised {describe(exc)}", traceback.format_exc()
    printed = out.getvalue() + "".join(f"warning: {w.message}\n" for w in caught)
    seconds = time.perf_counter() - start
    return CheckResult(name, status, message or "", tb, printed, seconds), value


def _traceback_of_cause(exc: BaseException) -> str:
    cause = exc.__cause__
    if cause is None:
        return ""
    return "".join(traceback.format_exception(type(cause), cause, cause.__traceback__))


def describe(exc: BaseException) -> str:
    """``"ValueError: <message>"``: an exception in one line of a check's reason."""
    message = exc.message if isinstance(exc, ShapebenchError) else str(exc)
    return f"{type(exc).__name__}: {message}"


def skip_rest(names: Iterable[str], why: str) -> Iterator[CheckResult]:
    """A skipped result for each of ``names``: the checks that cannot run after one failed."""
    for name in names:
        yield CheckResult(name, SKIP, why)


# -- the environment checks share -------------------------------------------------------------


class CheckEnv:
    """A scratch folder for the checks (the tiny dataset's cache, trainings), removed on close,
    and the registry components are looked up in. Use it as a context manager."""

    def __init__(self, registry: Registry | None = None, workdir: Path | None = None) -> None:
        self.registry = registry if registry is not None else get_registry()
        self._own = workdir is None
        self.workdir = Path(workdir or tempfile.mkdtemp(prefix="shapebench-check-"))
        self._dataset: Any = None
        self._contexts: list | None = None

    def __enter__(self) -> CheckEnv:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._own:
            shutil.rmtree(self.workdir, ignore_errors=True)

    def tiny_dataset(self) -> Any:
        """The ``synthetic`` dataset with :data:`TINY_DATASET_OPTIONS`, cached in the workdir."""
        if self._dataset is None:
            from shapebench.api import options as opts

            try:
                cls = self.registry.load("dataset", "synthetic")
            except ShapebenchError as exc:
                raise CheckSkipped(
                    f"needs the built-in synthetic dataset, which is unavailable: {exc.message}"
                ) from exc
            options = opts.build(
                cls.Options, tiny_values(cls.Options, TINY_DATASET_OPTIONS), "dataset 'synthetic'"
            )
            self._dataset = cls(options, self.workdir / "cache")
        return self._dataset

    def contexts(self) -> tuple[list, int]:
        """:data:`N_CONTEXTS` contexts of :data:`CONTEXT_SIZE` points drawn as runs draw them
        (from objects of both evaluation splits), and the ground truth's size."""
        if self._contexts is None:
            from shapebench.api.contexts import ContextStore
            from shapebench.api.types import NOVEL, TRAINED

            ds = self.tiny_dataset()
            refs = [r for split in (TRAINED, NOVEL) for r in ds.objects(split)[:2]]
            data = [ds.load(ref) for ref in refs[:N_CONTEXTS]]
            store = ContextStore(ds.cache_root, ds.fingerprint())
            self._contexts = [store.context(d, CONTEXT_SIZE, run_seed=0) for d in data]
            self._n_points = len(data[0].gt_points)
        return self._contexts, self._n_points


def tiny_values(options_cls: type, table: dict[str, Any]) -> dict[str, Any]:
    """The entries of ``table`` that ``options_cls`` has a field for."""
    names = {f.name for f in dataclasses.fields(options_cls)}
    return {k: v for k, v in table.items() if k in names}


# -- reporting --------------------------------------------------------------------------------

_WORDS = ((PASS, "passed"), (FAIL, "failed"), (SKIP, "skipped"))


def summary(results: Iterable[CheckResult], seconds: float) -> str:
    """``"41 passed, 1 failed, 9 skipped in 80.2s"``, like pytest's last line."""
    counts = Counter(r.status for r in results)
    parts = [f"{counts[status]} {word}" for status, word in _WORDS if counts[status]]
    return f"{', '.join(parts) or 'no checks'} in {seconds:.1f}s"


def failure_lines(reports: Iterable[ComponentReport]) -> list[str]:
    """One line per failed check: ``method bad complete: <reason>``."""
    return [
        f"{rep.component.kind} {rep.component.name} {r.check}: {r.reason}"
        for rep in reports
        for r in rep.failures
    ]
