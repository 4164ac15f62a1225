"""Plugin checks: what ``shapebench check`` runs and :mod:`shapebench.registry.testing` asserts.

Each method, dataset and metric a plugin registers is put through the rules of its interface on a
tiny built-in dataset (the ``synthetic`` dataset, a few thousand points per object, built in a
temporary folder, never in the user's cache):

* every component: its modules import without torch or Lightning (in a fresh interpreter), the
  class implements its interface, and its options parse from ``KEY=VALUE`` strings and
  round-trip through the config that runs log;
* a method: completes 50-point contexts into finite ``(n, 3)`` arrays of a sensible size, also
  when the points are duplicated or all the same (or raises, a failed object), gives
  identical points for the same seed, uses one Lightning namespace; a trainable method trains
  for a few steps and a fresh instance reloads its checkpoint;
* a dataset: gives categories and splits, objects that load in the normalised frame, and the
  training arrays it provides;
* a metric: its card is valid, and its value is zero on identical clouds and positive otherwise
  (for a higher-is-better metric: better on identical clouds than on different ones).

The checks are generators of one :class:`CheckResult` per check; the command line prints them
and :mod:`shapebench.registry.testing` turns failures into assertion errors.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shapebench.api.errors import ShapebenchError, UnknownNameError
from shapebench.registry.discovery import KINDS, Registration, Registry, get_registry

PASS, FAIL, SKIP = "pass", "fail", "skip"

#: The context size methods are checked at: the smallest of the paper's protocol.
CONTEXT_SIZE = 50
#: How many contexts (from different objects) a method completes.
N_CONTEXTS = 3
#: Points further than this from the origin are not a completion of a unit-sphere shape.
MAX_RADIUS = 10.0
#: A completion has at least the context's size and at most this many times ``n_points``.
MAX_POINTS_FACTOR = 10
#: Datasets put objects in the unit sphere (largest vertex distance 1); this much slack is allowed.
FRAME_SLACK = 0.05
#: Modules no plugin may import when it is imported (``shapebench --help`` imports every plugin).
HEAVY_MODULES = ("torch", "pytorch_lightning", "lightning")

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

#: Method options applied where the options have that field, for methods that declare no
#: ``check_options``: one epoch of small batches, coarse meshes.
TINY_METHOD_OPTIONS: dict[str, Any] = {"epochs": 1, "batch_shapes": 4, "mesh_resolution": 32}

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


def _class_path(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _run(name: str, fn: Callable[[], Any]) -> tuple[CheckResult, Any]:
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
            status, message, tb = FAIL, f"raised {_describe(exc)}", traceback.format_exc()
    printed = out.getvalue() + "".join(f"warning: {w.message}\n" for w in caught)
    seconds = time.perf_counter() - start
    return CheckResult(name, status, message or "", tb, printed, seconds), value


def _traceback_of_cause(exc: BaseException) -> str:
    cause = exc.__cause__
    if cause is None:
        return ""
    return "".join(traceback.format_exception(type(cause), cause, cause.__traceback__))


def _describe(exc: BaseException) -> str:
    message = exc.message if isinstance(exc, ShapebenchError) else str(exc)
    return f"{type(exc).__name__}: {message}"


def _skip_rest(names: Iterable[str], why: str) -> Iterator[CheckResult]:
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


def method_check_options(cls: type) -> dict[str, Any]:
    """The tiny options a method is checked with: its ``check_options``, else
    :data:`TINY_METHOD_OPTIONS` where it has those fields."""
    declared = getattr(cls, "check_options", None)
    if declared:
        return dict(declared)
    options_cls = getattr(cls, "Options", None)
    if options_cls is None or not dataclasses.is_dataclass(options_cls):
        return {}
    return tiny_values(options_cls, TINY_METHOD_OPTIONS)


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
    yield _run("imports", lambda: _check_imports(comp))[0]
    checks = {"method": _method_checks, "dataset": _dataset_checks, "metric": _metric_checks}
    yield from checks[comp.kind](comp, env, dict(options or {}), data_root)


def check_component(
    comp: Component,
    env: CheckEnv,
    options: dict[str, Any] | None = None,
    data_root: Path | str | None = None,
) -> ComponentReport:
    return ComponentReport(comp, list(run_checks(comp, env, options, data_root)))


_IMPORT_PROBE = """
import importlib, json, sys
heavy = {heavy!r}
found = []
for module in {modules!r}:
    importlib.import_module(module)
    found.append([module, [m for m in heavy if m in sys.modules]])
print(json.dumps(found))
"""


def _check_imports(comp: Component) -> str:
    """Import the component's modules in a fresh interpreter (this one may hold torch already):
    ``shapebench --help`` imports every plugin, so none may import torch or Lightning."""
    modules = comp.modules()
    if not modules:
        raise CheckSkipped(
            f"{comp.name} is defined in {comp.cls and comp.cls.__module__}, "
            "which another interpreter cannot import"
        )
    code = _IMPORT_PROBE.format(heavy=HEAVY_MODULES, modules=modules)
    env = dict(os.environ)
    # The same modules as this process sees (a test's sys.path, a target install).
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300
    )
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise CheckFailed(f"importing {', '.join(modules)} failed: {last}")
    found = json.loads(proc.stdout.strip().splitlines()[-1])
    seen: list[str] = []
    for module, heavy in found:
        new = [m for m in heavy if m not in seen]
        if new:
            raise CheckFailed(
                f"importing {module} imports {', '.join(new)}: import it inside the methods that "
                "use it (shapebench --help imports every plugin)"
            )
        seen = heavy
    return f"{', '.join(modules)} import without {', '.join(HEAVY_MODULES)}"


def _options_roundtrip(options_cls: type, values: dict[str, Any], owner: str) -> Any:
    """Build options from ``values``, write them as ``-O KEY=VALUE`` strings (JSON values, as a
    training child process receives them), parse those back, and demand the same options."""
    from shapebench.api import options as opts

    built = opts.build(options_cls, values, owner)
    again = opts.build(options_cls, opts.parse_assignments(_as_assignments(built), "-O"), owner)
    if again != built:
        diff = [
            f.name
            for f in dataclasses.fields(built)
            if getattr(built, f.name) != getattr(again, f.name)
        ]
        raise CheckFailed(
            f"option(s) {', '.join(diff)} change when written as KEY=VALUE and parsed back: "
            + ", ".join(f"{k}={getattr(built, k)!r} -> {getattr(again, k)!r}" for k in diff)
        )
    return built


def _as_assignments(options: Any) -> list[str]:
    from shapebench.api import options as opts

    out = []
    for key, value in opts.as_dict(options).items():
        try:
            out.append(f"{key}={json.dumps(value)}")
        except TypeError as exc:
            raise CheckFailed(
                f"option {key}={value!r} is not a JSON value (a number, string, bool, None or a "
                "list of them): runs log options as JSON and pass them to training processes"
            ) from exc
    return out


def _check_options_class(cls: type, owner: str) -> None:
    from shapebench.api import options as opts

    options_cls = getattr(cls, "Options", None)
    if not (isinstance(options_cls, type) and dataclasses.is_dataclass(options_cls)):
        raise CheckFailed(f"{owner}: Options must be a dataclass, got {options_cls!r}")
    none = dataclasses.MISSING
    missing = [
        f.name
        for f in dataclasses.fields(options_cls)
        if f.default is none and f.default_factory is none
    ]
    if missing:
        raise CheckFailed(f"{owner}: option(s) {', '.join(missing)} have no default")
    opts.describe(options_cls)  # what `shapebench methods` prints: type names, help texts


# -- methods ----------------------------------------------------------------------------------

_METHOD_CHECKS = (
    "interface",
    "options",
    "train",
    "checkpoint",
    "complete",
    "degenerate",
    "deterministic",
    "lightning",
)


def _method_checks(
    comp: Component, env: CheckEnv, overrides: dict[str, Any], data_root: Any
) -> Iterator[CheckResult]:
    before = {m for m in ("lightning", "pytorch_lightning") if m in sys.modules}
    yield from _method_steps(comp, env, overrides)
    yield _run("lightning", lambda: _lightning(before))[0]


def _method_steps(
    comp: Component, env: CheckEnv, overrides: dict[str, Any]
) -> Iterator[CheckResult]:
    """Every check of a method but ``lightning``, which looks at what these imported."""
    res, cls = _run("interface", lambda: _method_interface(comp))
    yield res
    if cls is None:
        yield from _skip_rest(_METHOD_CHECKS[1:-1], "the class did not load")
        return
    owner = f"method {comp.name!r}"
    res, options = _run("options", lambda: _method_options(cls, owner, overrides))
    yield res
    if options is None:
        yield from _skip_rest(_METHOD_CHECKS[2:-1], "no usable options")
        return
    path = trained = None
    if cls.trains:
        res, path = _run("train", lambda: _train(cls, options, env, comp.name))
        yield res
        res, trained = _run("checkpoint", lambda: _reload(cls, options, path))
        yield res
        if trained is None:
            yield from _skip_rest(
                ("complete", "degenerate", "deterministic"), "no trained instance"
            )
            return
    else:
        yield from _skip_rest(("train", "checkpoint"), "does not train")
    res, outputs = _run(
        "complete", lambda: _complete(trained if trained is not None else cls(options), env)
    )
    yield res
    if outputs is None:
        yield CheckResult("degenerate", SKIP, "nothing completed")
    else:
        method = trained if trained is not None else cls(options)
        yield _run("degenerate", lambda: _degenerate(method, env))[0]
    if outputs is None:
        yield CheckResult("deterministic", SKIP, "nothing completed")
    else:
        yield _run("deterministic", lambda: _deterministic(cls, options, path, env, outputs))[0]


def _method_interface(comp: Component) -> tuple[str, type]:
    from shapebench.api.method import Method
    from shapebench.api.types import Supervision

    cls = comp.load()
    if not (isinstance(cls, type) and issubclass(cls, Method)):
        raise CheckFailed(f"{cls!r} is not a subclass of shapebench.Method")
    abstract = sorted(getattr(cls, "__abstractmethods__", ()))
    if abstract:
        raise CheckFailed(f"{cls.__name__} does not implement {', '.join(abstract)}")
    if cls.trains:
        for hook in ("fit", "load_checkpoint"):
            if getattr(cls, hook) is getattr(Method, hook):
                raise CheckFailed(f"{cls.__name__} declares trains=True but has no {hook}()")
    bad = [s for s in cls.supervision if not isinstance(s, Supervision)]
    if bad:
        raise CheckFailed(f"supervision holds {bad!r}: use shapebench.Supervision members")
    size = cls.batch_size
    if not isinstance(size, int) or isinstance(size, bool) or size < 1:
        raise CheckFailed(f"batch_size={size!r} must be a positive integer")
    _check_options_class(cls, f"method {comp.name!r}")
    kind = "trainable " if cls.trains else ""
    return f"{kind}{_class_path(cls)}", cls


def _method_options(cls: type, owner: str, overrides: dict[str, Any]) -> tuple[str, Any]:
    from shapebench.api import options as opts

    _options_roundtrip(cls.Options, {}, owner)
    tiny = {**method_check_options(cls), **overrides}
    options = _options_roundtrip(cls.Options, tiny, owner)
    # The config a run logs holds the options as the instance resolved them (recipe defaults
    # filled in); built again from that config, the method must resolve the same options.
    effective = cls(options).options
    logged = json.loads(json.dumps(opts.as_dict(effective)))
    again = cls(opts.build(cls.Options, logged, owner)).options
    if again != effective:
        raise CheckFailed(
            "the options a run logs do not build the same method again: "
            f"{opts.as_dict(effective)} -> {opts.as_dict(again)}"
        )
    return _options_message(cls.Options, tiny), options


def _options_message(options_cls: type, tiny: dict[str, Any]) -> str:
    n = len(dataclasses.fields(options_cls))
    if not n:
        return "no options"
    shown = ", ".join(f"{k}={v}" for k, v in tiny.items()) or "the defaults"
    return f"{n} option(s) parse and round-trip through the config; checked with {shown}"


def _trainer(options: Any) -> Any:
    from shapebench.api.method import TrainerOptions

    epochs = getattr(options, "epochs", None)
    return TrainerOptions(
        accelerator="cpu", devices=1, max_epochs=epochs or 1, seed=0, checkpoint_minutes=0.0
    )


def _train(cls: type, options: Any, env: CheckEnv, name: str) -> tuple[str, Path]:
    from shapebench.api.method import TrainingContext

    dataset = env.tiny_dataset()
    workdir = env.workdir / "train" / name
    workdir.mkdir(parents=True, exist_ok=True)
    trainer = _trainer(options)
    path = cls(options).fit(TrainingContext(dataset, trainer, workdir, "", None, quiet=True))
    if path is None or not Path(path).exists():
        raise CheckFailed(f"fit() returned {path!r}, which does not exist: return the checkpoint")
    n = len(dataset.objects("train"))
    return (
        f"{trainer.max_epochs} epoch(s) on {n} objects of the tiny synthetic dataset -> "
        f"{Path(path).name}",
        Path(path),
    )


def _reload(cls: type, options: Any, path: Path | None) -> tuple[str, Any]:
    if path is None:
        raise CheckSkipped("training failed")
    instance = cls(options)
    instance.load_checkpoint(Path(path))
    return f"a fresh instance loads {Path(path).name}", instance


def _complete_all(method: Any, contexts: list, n_points: int) -> list[Any]:
    """Outputs per context, in chunks of the method's ``batch_size`` like a run."""
    chunk = max(1, int(getattr(method, "batch_size", 1)))
    out: list[Any] = []
    for i in range(0, len(contexts), chunk):
        part = contexts[i : i + chunk]
        got = method.complete_batch(part, n_points)
        if not isinstance(got, list) or len(got) != len(part):
            raise CheckFailed(
                f"complete_batch returned {_size(got)} results for {len(part)} "
                "contexts: return one per context, in order"
            )
        out += got
    return out


def _size(value: Any) -> str:
    return str(len(value)) if hasattr(value, "__len__") else repr(value)


def _complete(method: Any, env: CheckEnv) -> tuple[str, list[Any]]:
    import numpy as np

    contexts, n_points = env.contexts()
    before = [c.points.copy() for c in contexts]
    outputs = _complete_all(method, contexts, n_points)
    for ctx, points in zip(contexts, before, strict=True):
        if not np.array_equal(ctx.points, points):
            raise CheckFailed(
                f"complete() changed the context points of {ctx.ref.id} in place: "
                "every method is given the same arrays"
            )
    raised = []
    sizes = []
    for ctx, out in zip(contexts, outputs, strict=True):
        if isinstance(out, Exception):
            raised.append(f"{ctx.ref.id}: {_describe(out)}")
            continue
        problem = completion_problem(out, n_points)
        if problem:
            raise CheckFailed(f"{ctx.ref.id}: {problem}")
        sizes.append(len(out.points))
    if not sizes:
        raise CheckFailed(f"every context failed: {'; '.join(raised)}")
    message = (
        f"{len(sizes)} context(s) of {CONTEXT_SIZE} points -> finite (n, 3) points, "
        f"n = {', '.join(map(str, sorted(set(sizes))))} (asked for {n_points})"
    )
    if raised:  # a tiny trained network may find no surface on some object: reported, allowed
        message += f"; {len(raised)} failed: {'; '.join(raised)}"
    return message, outputs


def _degenerate(method: Any, env: CheckEnv) -> str:
    """Contexts real data produces that a method may not expect: half the points duplicates of
    the other half (a scan fused twice), and every point the same (a scanner's dead pixel). A
    method may complete them or raise (the run records that object as failed, with the reason);
    it may not return NaN or points far outside the unit sphere."""
    import numpy as np

    contexts, n_points = env.contexts()
    ctx = contexts[0]
    half = ctx.points[: (len(ctx.points) + 1) // 2]
    cases = {
        "duplicated": np.concatenate([half, half])[: len(ctx.points)],
        "identical": np.repeat(ctx.points[:1], len(ctx.points), axis=0),
    }
    said = []
    for name, points in cases.items():
        normals = None
        if ctx.normals is not None:  # the normals of the points the rows were copied from
            rows = (
                np.arange(len(points)) % len(half)
                if name == "duplicated"
                else np.zeros(len(points), dtype=int)
            )
            normals = ctx.normals[rows]
        case = dataclasses.replace(ctx, points=points.astype(np.float32), normals=normals)
        (out,) = _complete_all(method, [case], n_points)
        if isinstance(out, Exception):
            said.append(f"{name}: raised ({_describe(out)}), recorded as a failed object")
            continue
        problem = completion_problem(out, n_points)
        if problem:
            raise CheckFailed(f"a context of {len(points)} {name} points: {problem}")
        said.append(f"{name}: {len(out.points)} finite points")
    return f"contexts of {len(ctx.points)} points, " + "; ".join(said)


def completion_problem(completion: Any, n_points: int) -> str | None:
    """Why ``completion`` is not a usable completion for ``n_points`` ground-truth points."""
    import numpy as np

    from shapebench.api.types import Completion

    if not isinstance(completion, Completion):
        return f"returned {type(completion).__name__}, not a Completion"
    clouds = [("points", completion.points)]
    clouds += [(f"samples[{i}]", s) for i, s in enumerate(completion.samples or [])]
    for what, cloud in clouds:
        pts = np.asarray(cloud)
        if pts.ndim != 2 or pts.shape[1] != 3:
            return f"{what} has shape {pts.shape}, expected (n, 3)"
        if not np.issubdtype(pts.dtype, np.floating):
            return f"{what} has dtype {pts.dtype}, expected float32"
        bad = int((~np.isfinite(pts)).any(axis=1).sum())
        if bad:
            where = "" if what == "points" else f" of {what}"
            return f"{bad} of {len(pts)} points{where} are NaN/inf"
        if len(pts) < CONTEXT_SIZE or len(pts) > MAX_POINTS_FACTOR * n_points:
            return (
                f"{what} has {len(pts)} points for n_points={n_points}: expected between "
                f"{CONTEXT_SIZE} and {MAX_POINTS_FACTOR * n_points}"
            )
        far = float(np.linalg.norm(pts, axis=1).max())
        if far > MAX_RADIUS:
            return (
                f"{what} has a point {far:.3g} from the origin: shapes are in the unit sphere, "
                "completions should be too"
            )
    return None


def _deterministic(
    cls: type, options: Any, path: Path | None, env: CheckEnv, first: list[Any]
) -> str:
    import numpy as np

    contexts, n_points = env.contexts()
    method = cls(options)
    if path is not None:
        method.load_checkpoint(Path(path))
    second = _complete_all(method, contexts, n_points)
    for ctx, a, b in zip(contexts, first, second, strict=True):
        if isinstance(a, Exception) or isinstance(b, Exception):
            if type(a) is not type(b) or str(a) != str(b):
                raise CheckFailed(
                    f"{ctx.ref.id}: the same seed gave {_outcome(a)}, then {_outcome(b)}"
                )
            continue
        pa, pb = np.asarray(a.points), np.asarray(b.points)
        if pa.shape != pb.shape:
            raise CheckFailed(f"{ctx.ref.id}: the same seed gave {pa.shape} then {pb.shape} points")
        if not np.array_equal(pa, pb):
            differ = int((pa != pb).any(axis=1).sum())
            raise CheckFailed(
                f"{ctx.ref.id}: the same seed gave different points ({differ} of {len(pa)} "
                f"differ, by up to {float(np.abs(pa - pb).max()):.3g}): draw random numbers from "
                "a generator seeded with context.seed"
            )
    return f"a fresh instance gives identical points for the same {len(contexts)} contexts"


def _outcome(value: Any) -> str:
    return _describe(value) if isinstance(value, Exception) else f"{len(value.points)} points"


def _lightning(before: set[str]) -> str:
    """Whether the method's checks (training included) imported the ``lightning`` package.

    ``before`` is what of it this process had imported before them: in ``shapebench check``
    nothing, so a method importing it is caught; in a test process that imported it already, the
    check cannot tell and skips."""
    if "lightning" in before:
        raise CheckSkipped("this process had imported the lightning package before the check")
    if "lightning" in sys.modules:
        raise CheckFailed(
            "imported the lightning package (lightning.pytorch): shapebench uses "
            "pytorch_lightning, and objects of the two namespaces cannot be mixed"
        )
    if "pytorch_lightning" in sys.modules and "pytorch_lightning" not in before:
        return "uses pytorch_lightning, not lightning.pytorch"
    return "does not import lightning.pytorch"


# -- datasets ---------------------------------------------------------------------------------

_DATASET_CHECKS = ("interface", "options", "splits", "load", "supervision")

#: Where ``Dataset.load`` puts each kind of training supervision, and its columns.
_EXTRA = {
    "sdf_samples": ("sdf", 4),
    "occupancy_samples": ("occupancy", 4),
    "complete_points": ("complete_points", 3),
}


def _dataset_checks(
    comp: Component, env: CheckEnv, overrides: dict[str, Any], data_root: Any
) -> Iterator[CheckResult]:
    res, cls = _run("interface", lambda: _dataset_interface(comp, env))
    yield res
    if cls is None:
        yield from _skip_rest(_DATASET_CHECKS[1:], "the class did not load")
        return
    root = data_root or os.environ.get(f"SHAPEBENCH_{comp.name.upper().replace('-', '_')}_ROOT")
    root = Path(root) if root else None
    res, dataset = _run("options", lambda: _dataset_options(cls, comp.name, overrides, env, root))
    yield res
    if res.status != PASS:
        yield from _skip_rest(_DATASET_CHECKS[2:], "no usable options")
        return
    if dataset is None:
        yield from _skip_rest(_DATASET_CHECKS[2:], "reads a local copy: pass --data-root")
        return
    res, split_refs = _run("splits", lambda: _splits(dataset))
    yield res
    if split_refs is None:
        yield from _skip_rest(_DATASET_CHECKS[3:], "no splits")
        return
    yield _run("load", lambda: _load(dataset, split_refs))[0]
    yield _run("supervision", lambda: _supervision(dataset, split_refs))[0]


def _dataset_interface(comp: Component, env: CheckEnv) -> tuple[str, type]:
    from shapebench.api.dataset import Dataset
    from shapebench.api.types import EVAL_SPLITS, TRAIN, Supervision

    cls = comp.load()
    if not (isinstance(cls, type) and issubclass(cls, Dataset)):
        raise CheckFailed(f"{cls!r} is not a subclass of shapebench.Dataset")
    abstract = sorted(getattr(cls, "__abstractmethods__", ()))
    if abstract:
        raise CheckFailed(f"{cls.__name__} does not implement {', '.join(abstract)}")
    if not cls.name:
        raise CheckFailed(f"{cls.__name__} has no name: it names the dataset's cache folder")
    splits = cls.eval_splits
    if not splits or not all(isinstance(s, str) and s and s != TRAIN for s in splits):
        raise CheckFailed(
            f"eval_splits={splits!r}: name the evaluation splits, e.g. "
            f"{EVAL_SPLITS} (train is for training only)"
        )
    bad = [s for s in cls.provides if not isinstance(s, Supervision)]
    if bad:
        raise CheckFailed(f"provides holds {bad!r}: use shapebench.Supervision members")
    metrics = env.registry.names("metric")
    if cls.default_metric not in metrics:
        raise CheckFailed(
            f"default_metric={cls.default_metric!r} is not an installed metric "
            f"({', '.join(metrics)})"
        )
    _check_options_class(cls, f"dataset {comp.name!r}")
    return _class_path(cls), cls


def _dataset_options(
    cls: type, name: str, overrides: dict[str, Any], env: CheckEnv, root: Path | None
) -> tuple[str, Any]:
    """Round-trip the options; then, when the dataset can be built here (it needs no local copy,
    or one was given), build it twice and demand the same config: a run's cell keys hold it."""
    from shapebench.hashing import stable_hash

    owner = f"dataset {name!r}"
    _options_roundtrip(cls.Options, {}, owner)
    declared = getattr(cls, "check_options", None) or tiny_values(cls.Options, TINY_DATASET_OPTIONS)
    tiny = {**declared, **overrides}
    options = _options_roundtrip(cls.Options, tiny, owner)
    message = _options_message(cls.Options, tiny)
    if cls.needs_data_root and root is None:
        return message + " (its config needs --data-root)", None
    cache = env.workdir / "cache"
    dataset = cls(options, cache, root)
    config = dataset.config()
    try:
        json.dumps(config)
    except TypeError as exc:
        raise CheckFailed(f"config() is not JSON: {exc}") from exc
    again = cls(_options_roundtrip(cls.Options, tiny, owner), cache, root)
    if stable_hash(again.config()) != stable_hash(config):
        raise CheckFailed(
            "the same options give another config (and fingerprint) on a second "
            "instance: the identity must depend on the options only"
        )
    return message + f"; fingerprint {config.get('fingerprint', '?')}", dataset


def _splits(dataset: Any) -> tuple[str, dict[str, list]]:
    from shapebench.api.types import NOVEL, TRAIN, TRAINED, Category, ObjectRef

    cats = dataset.categories()
    if not isinstance(cats, list) or not cats:
        raise CheckFailed(f"categories() returned {cats!r}: a non-empty list of Category")
    allowed = {TRAINED, NOVEL, *dataset.eval_splits}
    bad = [c for c in cats if not isinstance(c, Category) or c.split not in allowed]
    if bad:
        raise CheckFailed(
            f"categories() holds {bad[0]!r}: Category(name, split) with split one "
            f"of {', '.join(sorted(allowed))}"
        )
    names = [c.name for c in cats]
    if len(set(names)) != len(names):
        raise CheckFailed("categories() names a category twice")
    split_of = {c.name: c.split for c in cats}
    refs: dict[str, list] = {}
    seen: dict[str, str] = {}
    for split in dict.fromkeys((TRAIN, *dataset.eval_splits)):
        refs[split] = got = dataset.objects(split)
        if not isinstance(got, list) or not all(isinstance(r, ObjectRef) for r in got):
            raise CheckFailed(f"objects({split!r}) must return a list of ObjectRef")
        for ref in got:
            if ref.id in seen:
                raise CheckFailed(f"object id {ref.id!r} is in both {seen[ref.id]} and {split}")
            seen[ref.id] = split
            if ref.category not in split_of:
                raise CheckFailed(
                    f"objects({split!r}) holds {ref.id} of category "
                    f"{ref.category!r}, not in categories()"
                )
            # Methods train on trained categories only; novel ones are never seen in training.
            want = {TRAIN: TRAINED, TRAINED: TRAINED, NOVEL: NOVEL}.get(split)
            if want and split_of[ref.category] != want:
                raise CheckFailed(
                    f"objects({split!r}) holds {ref.id} of category "
                    f"{ref.category!r}, which is not a {want} category"
                )
    if not any(refs[s] for s in dataset.eval_splits):
        raise CheckFailed("every evaluation split is empty")
    by_split = Counter(split_of.values())
    cat_counts = ", ".join(f"{n} {s}" for s, n in sorted(by_split.items()))
    counts = ", ".join(f"{s} {len(r)}" for s, r in refs.items())
    return f"{len(cats)} categories ({cat_counts}); objects: {counts}", refs


def _load(dataset: Any, refs: dict[str, list]) -> str:
    from shapebench.api.contexts import ContextStore
    from shapebench.api.types import ObjectData

    store = ContextStore(dataset.cache_root, dataset.fingerprint())
    loaded = []
    for split, got in refs.items():
        if not got:
            continue
        data = dataset.load(got[0])
        if not isinstance(data, ObjectData) or data.ref != got[0]:
            raise CheckFailed(f"load({got[0].id!r}) must return the ObjectData of that object")
        problem = _arrays_problem(data)
        if problem:
            raise CheckFailed(f"{got[0].id}: {problem}")
        store.context(data, CONTEXT_SIZE, run_seed=0)
        loaded.append(
            f"{split} {got[0].id} ({len(data.surface_points)} visible, "
            f"{len(data.gt_points)} GT points)"
        )
    return "loaded " + "; ".join(loaded)


def _arrays_problem(data: Any) -> str | None:
    import numpy as np

    arrays = {
        "surface_points": data.surface_points,
        "surface_normals": data.surface_normals,
        "gt_points": data.gt_points,
    }
    for name, array in arrays.items():
        a = np.asarray(array)
        if a.ndim != 2 or a.shape[1] != 3 or not len(a):
            return f"{name} has shape {a.shape}, expected (n, 3) with n > 0"
        if not np.isfinite(a).all():
            return f"{name} holds NaN/inf"
    if len(data.surface_normals) != len(data.surface_points):
        return "surface_normals and surface_points differ in length"
    if len(data.surface_points) < CONTEXT_SIZE:
        return (
            f"only {len(data.surface_points)} visible points: a {CONTEXT_SIZE}-point context "
            "cannot be drawn"
        )
    lengths = np.linalg.norm(data.surface_normals, axis=1)
    if np.abs(lengths - 1).max() > 1e-2:
        return "surface_normals are not unit vectors"
    for name in ("surface_points", "gt_points"):
        far = float(np.linalg.norm(arrays[name], axis=1).max())
        if far > 1 + FRAME_SLACK:
            return (
                f"{name} has a point {far:.3g} from the origin: objects must be normalised to the "
                "unit sphere (largest vertex distance 1)"
            )
    return None


def _supervision(dataset: Any, refs: dict[str, list]) -> str:
    import numpy as np

    from shapebench.api.types import TRAIN, Supervision

    kinds = [s for s in dataset.provides if s is not Supervision.SURFACE_POINTS]
    if not kinds:
        return "provides surface points only"
    if not refs.get(TRAIN):
        raise CheckSkipped("no train objects")
    ref = refs[TRAIN][0]
    data = dataset.load(ref, frozenset(kinds))
    shown = []
    for kind in sorted(kinds, key=str):
        key, cols = _EXTRA[kind.value]
        array = data.extra.get(key)
        if array is None:
            raise CheckFailed(f"load({ref.id!r}, need={{{kind}}}) gave no extra[{key!r}]")
        a = np.asarray(array)
        if a.ndim != 2 or a.shape[1] != cols or not len(a) or not np.isfinite(a).all():
            raise CheckFailed(
                f"extra[{key!r}] of {ref.id} has shape {a.shape} or NaNs: "
                f"expected finite (m, {cols})"
            )
        shown.append(f"{key} {a.shape}")
    return f"{ref.id}: " + ", ".join(shown)


# -- metrics ----------------------------------------------------------------------------------

_METRIC_CHECKS = ("card", "identical", "different")


def _metric_checks(
    comp: Component, env: CheckEnv, overrides: dict[str, Any], data_root: Any
) -> Iterator[CheckResult]:
    res, metric = _run("card", lambda: _card(comp))
    yield res
    if metric is None:
        yield from _skip_rest(_METRIC_CHECKS[1:], "no valid card")
        return
    res, best = _run("identical", lambda: _identical(metric, env))
    yield res
    yield _run("different", lambda: _different(metric, env, best))[0]


def _card(comp: Component) -> tuple[str, Any]:
    from shapebench.api.metric import check_metric

    if comp.registration is not None and comp.registration.error is not None:
        raise CheckFailed(comp.registration.reason or comp.registration.error.message)
    try:
        cls = comp.load()
    except ShapebenchError as exc:
        raise CheckFailed(comp.registration.reason if comp.registration else exc.message) from exc
    try:
        card = check_metric(cls)
    except ValueError as exc:
        raise CheckFailed(str(exc)) from exc
    return card.describe(), cls()


def _metric_object(env: CheckEnv) -> Any:
    """An object of the tiny dataset, or points on a sphere without it."""
    import numpy as np

    from shapebench.api.types import ObjectData, ObjectRef

    try:
        contexts, _ = env.contexts()
        return env.tiny_dataset().load(contexts[0].ref)
    except CheckSkipped:
        rng = np.random.default_rng(0)
        v = rng.normal(size=(2000, 3))
        v = (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)
        return ObjectData(ObjectRef("sphere/0", "sphere"), v, v, v.copy())


def _surface_object(metric: Any) -> Any:
    """For a metric that reads ground-truth arrays (``needs``): a sphere's mesh, with those
    arrays built by the code datasets use, and the mesh itself (``ObjectData.cache["mesh"]``)."""
    import numpy as np
    import trimesh

    from shapebench.api.types import GroundTruthArray, ObjectData, ObjectRef
    from shapebench.preprocess.samples import IOU_POINTS, occupancy_samples, oriented_points

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.8)
    rng = np.random.default_rng(0)
    gt = oriented_points(mesh, 4000, rng)
    extra = {GroundTruthArray.ORIENTED_POINTS.value: gt}
    if GroundTruthArray.OCCUPANCY in metric.needs:
        extra[GroundTruthArray.OCCUPANCY.value] = occupancy_samples(mesh, IOU_POINTS // 10, rng)
    data = ObjectData(ObjectRef("sphere/0", "sphere"), gt[:, :3], gt[:, 3:], gt[:, :3], extra)
    data.cache["check.mesh"] = mesh
    return data


def _score(metric: Any, data: Any, points: Any, mesh: Any = None) -> float:
    from shapebench.api.types import Completion, Context

    context = Context(data.ref, data.surface_points[:CONTEXT_SIZE], None, 0)
    value = metric.compute(Completion(points, mesh=mesh), data, context)
    try:
        value = float(value)
    except (TypeError, ValueError) as exc:
        raise CheckFailed(f"compute() returned {value!r}, not a float") from exc
    if not math.isfinite(value):
        raise CheckFailed(f"compute() returned {value}")
    return value


def _identical(metric: Any, env: CheckEnv) -> tuple[str, float]:
    import numpy as np

    mesh = None
    if getattr(metric, "needs", None):  # a surface metric: a mesh and its ground-truth arrays
        data = _surface_object(metric)
        mesh = data.cache["check.mesh"]
    else:
        data = _metric_object(env)
    prediction, what = data.gt_points.copy(), "identical to the ground truth"
    if not getattr(metric, "needs_ground_truth", True):  # input-referenced (fidelity)
        prediction = np.concatenate([prediction, data.surface_points[:CONTEXT_SIZE]])
        what = "holding its context points (the metric reads the input, not the ground truth)"
    value = _score(metric, data, prediction, mesh)
    if not metric.higher_is_better and abs(value) > 1e-9:
        raise CheckFailed(f"{value:.3g} on a prediction {what}: expected 0")
    return f"{value:g} on a prediction {what}", (value, data)


def _different(metric: Any, env: CheckEnv, best: tuple[float, Any] | None) -> str:
    if best is None:
        raise CheckSkipped("no value on identical clouds")
    identical, data = best
    # Shrunk and shifted: every point moves, in both directions of a Chamfer distance. The same
    # ObjectData as above, as in a run, where its cache serves every completion of the object.
    moved = (data.gt_points * 0.7 + 0.05).astype("float32")
    mesh = data.cache.get("check.mesh")
    if mesh is not None:
        mesh = mesh.copy()
        mesh.apply_scale(0.7)
        mesh.apply_translation([0.05, 0.05, 0.05])
    value = _score(metric, data, moved, mesh)
    if metric.higher_is_better and not value < identical:
        raise CheckFailed(
            f"{value:.3g} on a different prediction, not below the {identical:g} "
            "of an identical one (higher is better)"
        )
    if not metric.higher_is_better and not value > 0:
        raise CheckFailed(f"{value:.3g} on a prediction unlike the ground truth: expected > 0")
    return f"{value:.4g} on a shrunk and shifted prediction"


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
