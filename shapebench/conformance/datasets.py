"""The checks of a dataset: its interface and options (the same options give the same config);
categories and splits that agree; objects that load in the normalised frame, with enough points
for a context; the training arrays it provides."""

from __future__ import annotations

import json
import os
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from shapebench.conformance.framework import (
    CONTEXT_SIZE,
    PASS,
    TINY_DATASET_OPTIONS,
    CheckEnv,
    CheckFailed,
    CheckResult,
    CheckSkipped,
    Component,
    class_path,
    run_check,
    skip_rest,
    tiny_values,
)
from shapebench.conformance.options import (
    check_options_class,
    options_message,
    options_roundtrip,
)

#: Datasets put objects in the unit sphere (largest vertex distance 1); this much slack is allowed.
FRAME_SLACK = 0.05

_DATASET_CHECKS = ("interface", "options", "splits", "load", "supervision")

#: Where ``Dataset.load`` puts each kind of training supervision, and its columns.
_EXTRA = {
    "sdf_samples": ("sdf", 4),
    "occupancy_samples": ("occupancy", 4),
    "complete_points": ("complete_points", 3),
}


def dataset_checks(
    comp: Component, env: CheckEnv, overrides: dict[str, Any], data_root: Any
) -> Iterator[CheckResult]:
    """The checks of a dataset after ``imports``, one result at a time. ``data_root`` (or
    ``SHAPEBENCH_<NAME>_ROOT``) is the local copy a dataset that needs one reads; without it,
    such a dataset's data checks skip."""
    res, cls = run_check("interface", lambda: _dataset_interface(comp, env))
    yield res
    if cls is None:
        yield from skip_rest(_DATASET_CHECKS[1:], "the class did not load")
        return
    root = data_root or os.environ.get(f"SHAPEBENCH_{comp.name.upper().replace('-', '_')}_ROOT")
    root = Path(root) if root else None
    res, dataset = run_check(
        "options", lambda: _dataset_options(cls, comp.name, overrides, env, root)
    )
    yield res
    if res.status != PASS:
        yield from skip_rest(_DATASET_CHECKS[2:], "no usable options")
        return
    if dataset is None:
        yield from skip_rest(_DATASET_CHECKS[2:], "reads a local copy: pass --data-root")
        return
    res, split_refs = run_check("splits", lambda: _splits(dataset))
    yield res
    if split_refs is None:
        yield from skip_rest(_DATASET_CHECKS[3:], "no splits")
        return
    yield run_check("load", lambda: _load(dataset, split_refs))[0]
    yield run_check("supervision", lambda: _supervision(dataset, split_refs))[0]


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
    check_options_class(cls, f"dataset {comp.name!r}")
    return class_path(cls), cls


def _dataset_options(
    cls: type, name: str, overrides: dict[str, Any], env: CheckEnv, root: Path | None
) -> tuple[str, Any]:
    """Round-trip the options; then, when the dataset can be built here (it needs no local copy,
    or one was given), build it twice and demand the same config: a run's cell keys hold it."""
    from shapebench.hashing import stable_hash

    owner = f"dataset {name!r}"
    options_roundtrip(cls.Options, {}, owner)
    declared = getattr(cls, "check_options", None) or tiny_values(cls.Options, TINY_DATASET_OPTIONS)
    tiny = {**declared, **overrides}
    options = options_roundtrip(cls.Options, tiny, owner)
    message = options_message(cls.Options, tiny)
    if cls.needs_data_root and root is None:
        return message + " (its config needs --data-root)", None
    cache = env.workdir / "cache"
    dataset = cls(options, cache, root)
    config = dataset.config()
    try:
        json.dumps(config)
    except TypeError as exc:
        raise CheckFailed(f"config() is not JSON: {exc}") from exc
    again = cls(options_roundtrip(cls.Options, tiny, owner), cache, root)
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
