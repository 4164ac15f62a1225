"""``shapebench sweep``: a YAML file of methods x datasets x splits x context sizes x seeds.

Each (method, dataset) pair is one ``shapebench run``; its cells are skipped when finished, so a
sweep interrupted by Ctrl-C or ``kill -9`` completes the rest when started again. Trainable
methods train in a process of their own (see :mod:`shapebench.train.training`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from shapebench.api import options as opts
from shapebench.api.errors import ConfigError, ShapebenchError
from shapebench.api.method import TrainerOptions
from shapebench.api.options import check_value, suggest
from shapebench.api.protocol import DEFAULT_CONTEXT, DEFAULT_FRAME, Protocol
from shapebench.config import Settings, read_yaml
from shapebench.evaluation.orchestrate import EvalOutcome, EvalRequest, evaluate
from shapebench.registry.discovery import get_registry
from shapebench.store.failures import StoreFailure
from shapebench.store.tracking import Tracker


@dataclass
class Entry:
    """A method or dataset of a sweep. A dataset's ``label`` names it for a method entry's
    ``datasets``: the labels (or names) of the only datasets that method runs on, so that a
    sweep can be a cross (every method at every training-set size, and the longer budgets at the
    largest size only) instead of a full grid."""

    name: str
    options: dict[str, Any] = field(default_factory=dict)
    data_root: str | None = None
    label: str | None = None
    datasets: list[str] | None = None


@dataclass
class SweepSpec:
    name: str
    methods: list[Entry] | str
    datasets: list[Entry]
    splits: list[str] | None
    contexts: list[int]
    seeds: list[int]
    profile: str | None = None
    metrics: list[str] | None = None
    protocol: Protocol = field(default_factory=Protocol)
    #: The ``launcher:`` block, read by :func:`shapebench.sweeps.cluster.launcher_config`.
    launcher: dict[str, Any] = field(default_factory=dict)


#: The keys of a sweep file, and of a method or dataset entry in it.
_SWEEP_KEYS = (
    "name",
    "profile",
    "methods",
    "datasets",
    "splits",
    "contexts",
    "seeds",
    "metrics",
    "frame",
    "context_normals",
    "protocol",
    "crop_fraction",
    "context_noise",
    "launcher",
)
_ENTRY_KEYS = ("name", "options", "data_root", "label", "datasets")


def _check_entry(item: dict[str, Any], key: str, path: Path) -> None:
    """An entry's values by type, in one line naming the key: a list where the name belongs or
    a list of options would otherwise fail far from the file (or be read as something else)."""
    kinds: tuple[tuple[str, Any], ...] = (
        ("name", str),
        ("options", dict[str, Any] | None),
        ("data_root", str | None),
        ("label", str | None),
    )
    for field_name, kind in kinds:
        if field_name in item:
            check_value(item[field_name], kind, f"{path}: '{field_name}' of a '{key}' entry")


def _entries(value: Any, key: str, path: Path) -> list[Entry]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value:
        raise ConfigError(f"{path}: '{key}' must be a non-empty list")
    out = []
    for item in value:
        if isinstance(item, str):
            out.append(Entry(item))
        elif isinstance(item, dict) and "name" in item:
            unknown = sorted(set(item) - set(_ENTRY_KEYS))
            if unknown:
                raise ConfigError(
                    f"{path}: unknown keys {unknown} in '{key}' entry {item}: "
                    + ", ".join(suggest(k, _ENTRY_KEYS) for k in unknown),
                    f"an entry's keys: {', '.join(_ENTRY_KEYS)}",
                )
            _check_entry(item, key, path)
            only = item.get("datasets")
            if isinstance(only, str):
                only = [only]
            if only is not None and (key != "methods" or not isinstance(only, list) or not only):
                raise ConfigError(
                    f"{path}: 'datasets' of a method entry is a non-empty list of dataset labels "
                    f"(got {only!r} in '{key}')"
                )
            out.append(
                Entry(
                    item["name"],
                    dict(item.get("options") or {}),
                    item.get("data_root"),
                    item.get("label"),
                    [str(d) for d in only] if only is not None else None,
                )
            )
        else:
            raise ConfigError(f"{path}: each of '{key}' is a name or {{name: ..., options: ...}}")
    return out


def pairs(spec: SweepSpec, methods: list[Entry]) -> list[tuple[int, Entry, int, Entry]]:
    """The (dataset index, dataset, method index, method) runs of the sweep, datasets outer: the
    full grid, less the datasets a method entry's ``datasets`` leaves out."""
    return [
        (di, ds, mi, m)
        for di, ds in enumerate(spec.datasets)
        for mi, m in enumerate(methods)
        if m.datasets is None or ds.label in m.datasets or ds.name in m.datasets
    ]


def load_sweep(path: Path) -> SweepSpec:
    data = read_yaml(path)
    unknown = sorted(set(data) - set(_SWEEP_KEYS))
    if unknown:
        raise ConfigError(
            f"{path}: unknown keys {unknown}: "
            + ", ".join(suggest(k, _SWEEP_KEYS) for k in unknown),
            f"a sweep file's keys: {', '.join(_SWEEP_KEYS)}",
        )
    for key in ("methods", "datasets"):
        if key not in data:
            raise ConfigError(f"{path}: '{key}' is required")
    methods = (
        data["methods"] if data["methods"] == "all" else _entries(data["methods"], "methods", path)
    )
    scalars: tuple[tuple[str, type | tuple[type, ...]], ...] = (
        ("name", str),
        ("profile", str),
        ("frame", str),
        ("context_normals", bool),
        ("protocol", str),
        ("crop_fraction", (int, float)),
        ("context_noise", (int, float)),
    )
    for key, kind in scalars:
        value = data.get(key)
        if value is not None and _wrong_type(value, kind):
            kind_name = kind.__name__ if isinstance(kind, type) else "number"
            raise ConfigError(
                f"{path}: '{key}' must be a {kind_name}, got {value!r}",
                f"e.g. {key}: {_EXAMPLES[key]}",
            )
    spec = SweepSpec(
        name=data.get("name") or path.stem,
        methods=methods,
        datasets=_entries(data["datasets"], "datasets", path),
        splits=_list_of(data, "splits", str, None, path),
        contexts=_list_of(data, "contexts", int, [50, 100, 300, 1000], path),
        seeds=_list_of(data, "seeds", int, [0], path),
        profile=data.get("profile"),
        metrics=_list_of(data, "metrics", str, None, path),
        protocol=Protocol(
            context_normals=bool(data.get("context_normals", False)),
            frame=data.get("frame") or DEFAULT_FRAME,
            context=data.get("protocol") or DEFAULT_CONTEXT,
            crop_fraction=float(data.get("crop_fraction") or 0.0),
            context_noise=float(data.get("context_noise") or 0.0),
        ),
        launcher=_launcher_block(data.get("launcher"), path),
    )
    if methods != "all":
        known = {d.label for d in spec.datasets if d.label} | {d.name for d in spec.datasets}
        for m in methods:
            missing = sorted(set(m.datasets or ()) - known)
            if missing:
                raise ConfigError(
                    f"{path}: method {m.name!r} names datasets {missing} that the sweep does not "
                    f"have; give a dataset entry 'label: {missing[0]}' (labels and names: "
                    f"{sorted(known)})"
                )
    return spec


#: What a sweep file's scalar and list keys look like, for the errors that name a wrong type.
_EXAMPLES = {
    "name": "my-sweep",
    "profile": "quick",
    "frame": "unit-diameter",
    "context_normals": "true",
    "protocol": "crop",
    "crop_fraction": "0.5",
    "context_noise": "0.005",
    "splits": "[trained, novel]",
    "contexts": "[50, 100, 300, 1000]",
    "seeds": "[0, 1, 2]",
    "metrics": "[chamfer-l2, fscore]",
}


def _wrong_type(value: Any, kind: type | tuple[type, ...]) -> bool:
    """Whether ``value`` is not a ``kind`` (YAML's true/false are bools, not numbers)."""
    if kind is bool:
        return not isinstance(value, bool)
    return isinstance(value, bool) or not isinstance(value, kind)


def _list_of(data: dict, key: str, kind: type, default: Any, path: Path) -> Any:
    """``data[key]`` as a non-empty list of ``kind`` (``default`` when absent, a single value as a
    list of one); one clear error
    naming the key otherwise (a bool is not an int here, though Python says it is)."""
    value = data.get(key)
    if value is None:
        return default
    if isinstance(value, kind) and not isinstance(value, bool):
        value = [value]  # one value for a list, as 'methods: gauss' is
    if (
        not isinstance(value, list)
        or not value
        or not all(isinstance(v, kind) and not isinstance(v, bool) for v in value)
    ):
        raise ConfigError(
            f"{path}: '{key}' must be a non-empty list of {kind.__name__}s, got {value!r}",
            f"e.g. {key}: {_EXAMPLES[key]}",
        )
    return value


def _launcher_block(value: Any, path: Path) -> dict[str, Any]:
    if value is None:
        return {}
    if isinstance(value, str):
        return {"name": value}
    if not isinstance(value, dict):
        raise ConfigError(
            f"{path}: 'launcher' is a name or a mapping like "
            "{name: slurm, partition: gpu, time: 120}"
        )
    # Checked when the file is read, whichever launcher runs it: a wrong key or type is named
    # here, not ignored by an inline run or found when the cluster jobs are submitted.
    from shapebench.sweeps.cluster import launcher_config

    try:
        launcher_config(dict(value), {}, None)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc.message}", exc.hint) from None
    return dict(value)


def sweep_methods(spec: SweepSpec) -> list[Entry]:
    """The sweep's method entries, ``methods: all`` expanded; unknown names fail here, before
    any work, not halfway through the sweep."""
    registry = get_registry()
    methods = spec.methods
    if methods == "all":
        methods = [Entry(n) for n in registry.names("method")]
    for m in methods:
        registry.get("method", m.name)
    for ds in spec.datasets:
        registry.get("dataset", ds.name)
    # An entry's options (and -D's) are checked against the plugin's here too, before any work:
    # a typo or a wrong type would otherwise fail that entry's runs after the others had run.
    for kind, entries in (("method", methods), ("dataset", spec.datasets)):
        for e in entries:
            if e.options:
                cls = registry.load(kind, e.name)
                opts.build(cls.Options, e.options, f"{kind} {e.name!r} of sweep {spec.name!r}")
    return list(methods)


def only_methods(spec: SweepSpec, names: Iterable[str]) -> SweepSpec:
    """``spec`` keeping only the method entries named in ``names`` (``shapebench sweep -m``;
    each name may be a comma-separated list); no names keep every entry. What is kept runs
    exactly as in the whole sweep: the same cells, keys and rows, so a sweep can be run in parts
    (MSC's entries today, the others on another machine) and its tables built from them all."""
    wanted = {n.strip() for name in names for n in name.split(",") if n.strip()}
    if not wanted:
        return spec
    entries = sweep_methods(spec)
    present = {e.name for e in entries}
    unknown = sorted(wanted - present)
    if unknown:
        raise ConfigError(
            f"sweep {spec.name!r} has no entry of method {', '.join(map(repr, unknown))}",
            f"its methods: {', '.join(sorted(present))}",
        )
    return replace(spec, methods=[e for e in entries if e.name in wanted])


def only_seeds(spec: SweepSpec, seeds: Iterable[int]) -> SweepSpec:
    """``spec`` keeping only the run seeds in ``seeds`` (``shapebench sweep --seeds``); none keep
    every seed. Like ``only_methods``, what is kept runs exactly as in the whole sweep (the same
    cells and keys), so a three-seed sweep can be run one seed at a time, or its first seed
    alone for a quick look, and its tables built from whatever is finished."""
    wanted = set(seeds)
    if not wanted:
        return spec
    unknown = sorted(wanted - set(spec.seeds))
    if unknown:
        raise ConfigError(
            f"sweep {spec.name!r} has no seed {', '.join(map(str, unknown))}",
            f"its seeds: {', '.join(map(str, spec.seeds))}",
        )
    return replace(spec, seeds=[s for s in spec.seeds if s in wanted])


def narrow_sweep(
    spec: SweepSpec,
    methods: Iterable[str] = (),
    seeds: Iterable[int] = (),
    dataset_options: dict[str, Any] | None = None,
) -> SweepSpec:
    """``spec`` as ``shapebench sweep -m ... --seeds ... -D ...`` narrows it. The submitting
    process and each of its cluster jobs call this one function, so that a job's cell indices
    address the same cells as they did where they were planned."""
    spec = only_seeds(only_methods(spec, methods), seeds)
    return with_dataset_options(spec, dataset_options or {})


def with_dataset_options(spec: SweepSpec, options: dict[str, Any]) -> SweepSpec:
    """``spec`` with ``options`` (``shapebench sweep -D key=value``) given to every dataset entry,
    over the entry's own: the command line wins, as for ``shapebench run``. A smaller benchmark
    (``-D test_per_category=4``) keeps every checkpoint key: training data options are the only
    ones a key holds."""
    if not options:
        return spec
    datasets = [replace(d, options={**d.options, **options}) for d in spec.datasets]
    return replace(spec, datasets=datasets)


def request(
    spec: SweepSpec,
    method: Entry,
    dataset: Entry,
    force: bool = False,
    quiet: bool = False,
    retrain: bool = False,
    **narrow: Any,
) -> EvalRequest:
    """The ``shapebench run`` of one method on one dataset of the sweep; ``narrow`` (splits,
    contexts, seeds) restricts it to some of its cells, as a cluster job does."""
    return EvalRequest(
        method=method.name,
        dataset=dataset.name,
        splits=narrow.get("splits", spec.splits),
        contexts=narrow.get("contexts", spec.contexts),
        seeds=narrow.get("seeds", spec.seeds),
        method_opts=method.options,
        dataset_opts=dataset.options,
        data_root=dataset.data_root,
        metrics=spec.metrics,
        force=force,
        quiet=quiet,
        protocol=spec.protocol,
        label=method.label,
        retrain=retrain,
    )


def worker_order(methods: list[Entry], worker: int) -> list[Entry]:
    """The order in which local worker ``worker`` visits the sweep's methods. Worker 0 takes the
    file's order and worker 1 the reverse, so two workers (the default) meet once, in the
    middle: a worker that reaches a cell the other is computing leaves it and waits for it at
    the end of that split, and in the file's order rotated by one the second worker trailed the
    first through every method, each split ending in such a wait (the standard tables' seed-0
    sweep waited 8 times, a third of one worker's time). Workers 2, 3, ... start on the
    ``worker``-th method, in the file's order."""
    if not methods or worker == 0:
        return list(methods)
    if worker == 1:
        return list(reversed(methods))
    k = worker % len(methods)
    return methods[k:] + methods[:k]


def run_sweep(
    spec: SweepSpec,
    settings: Settings,
    force: bool,
    quiet: bool,
    trainer_for_seed: Callable[[int], TrainerOptions],
    on_error: Callable[[str, str, ShapebenchError], None] | None = None,
    offset: int = 0,
    retrain: bool = False,
) -> Iterator[EvalOutcome]:
    """Evaluate every method on every dataset of ``spec``, in the order :func:`worker_order`
    gives worker ``offset`` of a local launcher (0: the file's); ``retrain`` trains locally
    where a reference checkpoint is shipped."""
    methods = worker_order(sweep_methods(spec), offset)
    tracker = Tracker(settings)  # so does an unreachable server
    failures: list[str] = []
    for _, ds, _, m in pairs(spec, methods):
        try:
            yield evaluate(
                request(spec, m, ds, force, quiet, retrain), settings, trainer_for_seed, tracker
            )
        except StoreFailure:
            raise  # the store failed under every method alike: the rest could not be recorded
        except ShapebenchError as exc:  # one method failing must not stop the others
            failures.append(f"{m.name} on {ds.name}: {exc.message}")
            if on_error is not None:
                on_error(m.name, ds.name, exc)
    if failures:
        raise ShapebenchError(
            f"{len(failures)} of the sweep's method x dataset runs failed: " + "; ".join(failures),
            "the other cells finished and are kept; fix the cause and rerun the same command",
        )


def sweep_size(spec: SweepSpec, settings: Settings) -> int:
    """How many cells the sweep has (methods x each dataset's splits x sizes x seeds), for its
    progress line; a dataset that cannot be resolved counts 0 (its error comes with its run)."""
    from shapebench.registry.resolve import resolve_dataset

    methods = sweep_methods(spec)
    total = 0
    for ds in spec.datasets:
        try:
            dataset = resolve_dataset(get_registry(), ds.name, settings, ds.data_root, ds.options)
        except ShapebenchError:
            continue
        splits = spec.splits or list(dataset.eval_splits)
        runs = sum(1 for _, d, _, _ in pairs(spec, methods) if d is ds)
        total += runs * len(splits) * len(set(spec.contexts)) * len(spec.seeds)
    return total


class SweepProgress:
    """``12/48 cells (4 already done), 3m12s elapsed (1m02s training), about 9m left`` after each
    run of a sweep. The estimate extrapolates the evaluation time per cell computed so far; time
    spent training is left out of it (one training can take longer than all the cells it
    serves), so trainings still to come are not in the estimate either."""

    def __init__(self, total: int) -> None:
        import time

        self.total = total
        self.done = self.cached = 0
        self.training = 0.0
        self.start = time.monotonic()

    def update(self, outcome: EvalOutcome) -> str:
        import time

        self.done += len(outcome.cells)
        self.cached += sum(1 for c in outcome.cells if c.skipped)
        self.training += outcome.train_seconds
        elapsed = time.monotonic() - self.start
        evaluating = max(elapsed - self.training, 0.0)
        computed = self.done - self.cached
        left = max(self.total - self.done, 0)
        eta = f", about {_duration(evaluating / computed * left)} left" if computed and left else ""
        already = f" ({self.cached} already done)" if self.cached else ""
        training = f" ({_duration(self.training)} training)" if self.training >= 1 else ""
        return (
            f"sweep progress: {self.done}/{self.total} cells{already}, "
            f"{_duration(elapsed)} elapsed{training}{eta}"
        )


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"
