"""The Dataset interface, and :class:`MeshDataset` for anything made of triangle meshes.

A dataset plugin subclasses :class:`Dataset` (usually :class:`MeshDataset`, which adds the paper's
preprocessing and an on-disk cache) and registers it through ``shapebench_register_datasets``.

A dataset has categories, each either *trained* (methods may train on it) or *novel* (never seen
in training), and three splits of objects: ``train`` (training objects of trained categories),
``trained`` (test objects of trained categories) and ``novel`` (test objects of novel categories).
``load`` returns an object's preprocessed arrays; contexts are drawn from them by the core
(:mod:`shapebench.api.contexts`), never by the dataset or the method, so every method sees the same
points.
"""

from __future__ import annotations

import os
import tempfile
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from shapebench.api.errors import describe, warn_corrupt
from shapebench.api.options import NoOptions
from shapebench.api.types import (
    EVAL_SPLITS,
    Category,
    GroundTruthArray,
    ObjectData,
    ObjectRef,
    Supervision,
)
from shapebench.hashing import stable_hash, stable_seed
from shapebench.preprocess import (
    PREPROCESS_VERSION,
    PreprocessError,
    PreprocessParams,
    prepare_ground_truth,
    prepare_mesh,
)


class ObjectLoadError(RuntimeError):
    """One object could not be loaded or preprocessed; the others are unaffected."""


class Dataset(ABC):
    """A collection of objects to complete.

    Class attributes: ``name`` (public name), ``display_name``, ``description`` (one line),
    ``Options`` (a dataclass, see :mod:`shapebench.api.options`), ``provides`` (the supervision
    kinds it
    can produce for training), ``default_metric`` (what leaderboards rank by), ``eval_splits``
    (the splits a run evaluates by default), ``validation_splits`` (splits of objects disjoint
    from the test objects, for choosing options; evaluated only when named) and
    ``needs_data_root`` (whether ``--data-root`` is required, for datasets read from a user's
    local copy).
    """

    name: ClassVar[str] = ""
    display_name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    Options: ClassVar[type] = NoOptions
    provides: ClassVar[frozenset[Supervision]] = frozenset({Supervision.SURFACE_POINTS})
    default_metric: ClassVar[str] = "chamfer-l2"
    eval_splits: ClassVar[tuple[str, ...]] = EVAL_SPLITS
    #: Splits for choosing options, disjoint from every test split (``VALIDATION``): a run
    #: evaluates them only when it names them, so no default table ever reports them.
    validation_splits: ClassVar[tuple[str, ...]] = ()
    #: Whether ``surface_normals`` are the surface's normals; a dataset of bare points says False
    #: and ``--context-normals`` is refused on it.
    has_normals: ClassVar[bool] = True
    #: Whether objects have a ground truth. Without one (real partial scans), ``gt_points`` is
    #: empty, only metrics that compare the completion with its input apply
    #: (:attr:`~shapebench.api.metric.Metric.needs_ground_truth` False) and the others are
    #: refused by name; methods complete :meth:`points_to_complete` points.
    has_ground_truth: ClassVar[bool] = True
    #: The ground-truth arrays beyond ``gt_points`` that :meth:`load` can build when asked
    #: (:class:`~shapebench.api.types.GroundTruthArray`: oriented points, occupancy queries).
    #: Datasets of meshes build them all; datasets of bare points none, and the metrics needing
    #: them (normal consistency, IoU) are recorded as not applicable there.
    provides_ground_truth: ClassVar[frozenset[GroundTruthArray]] = frozenset()
    #: Option overrides that make the dataset tiny for ``shapebench check`` and
    #: :mod:`shapebench.conformance.testing` (few objects, few points).
    check_options: ClassVar[dict[str, Any]] = {}
    needs_data_root: ClassVar[bool] = False

    def __init__(self, options: Any, cache_dir: Path, data_root: Path | None = None) -> None:
        self.options = options
        self.cache_dir = Path(cache_dir)
        self.data_root = data_root

    @property
    def version(self) -> str:
        """The data/protocol version; change it whenever the produced arrays change."""
        return "1"

    def identity(self, training: bool, selection: bool = True) -> dict[str, Any]:
        """What the produced data depends on; hashed into the fingerprints.

        Options marked ``metadata={"training_only": True}`` (sizes of training samples, training
        objects) count only for ``training=True``, so changing them retrains methods but never
        changes test objects or contexts. Options marked ``metadata={"selection": True}`` choose
        *which* objects form the splits (test fraction, objects per category, split files) but not
        how one object is processed: they count only for ``selection=True``, so changing them
        changes the evaluated set (and the cell keys) without re-preprocessing any object.
        Options marked ``metadata={"evaluation_only": True}`` (how many test objects a category
        gives, when the training objects do not depend on it) count only for ``training=False``,
        so changing them changes the evaluated set but keeps every checkpoint key: a larger test
        set reuses the trained weights. Override to add what options cannot show (the contents
        of a user's split files, a preprocessing version); put selection-only additions under
        ``if selection``.
        """
        return {
            "name": self.name,
            "version": self.version,
            "options": _options(self.options, training, selection),
        }

    def fingerprint(self) -> str:
        """Identifies the evaluation set (cell keys, run tags): the data and which objects."""
        return stable_hash(self.identity(training=False))

    def data_fingerprint(self) -> str:
        """Identifies the arrays of each object, whichever objects are selected: the cache root,
        the preprocessing seeds and the context draws, so a split option never invalidates them."""
        return stable_hash(self.identity(training=False, selection=False))

    def config(self) -> dict[str, Any]:
        """What identifies the evaluation data, for run params and cell keys."""
        return {**self.identity(training=False), "fingerprint": self.fingerprint()}

    def training_fingerprint(self) -> str:
        """Identifies everything training sees (checkpoint keys)."""
        return stable_hash(self.identity(training=True))

    def training_data_fingerprint(self) -> str:
        """Identifies each object's training arrays, whichever objects are selected."""
        return stable_hash(self.identity(training=True, selection=False))

    def selection_notes(self, split: str) -> list[str]:
        """Why objects of ``split`` were left out, one line each, for what ``run`` prints before
        evaluating (a per-category cap, categories without test objects...). Empty by default."""
        return []

    @abstractmethod
    def categories(self) -> list[Category]:
        """Every category with its ``trained``/``novel`` split."""

    @abstractmethod
    def objects(self, split: str) -> list[ObjectRef]:
        """The objects of ``split`` (``train``, ``trained`` or ``novel``), in a stable order."""

    @abstractmethod
    def load(
        self, ref: ObjectRef, need: frozenset[Supervision | GroundTruthArray] = frozenset()
    ) -> ObjectData:
        """The preprocessed arrays of one object; raise :class:`ObjectLoadError` if impossible.

        Always: visible surface points and normals, and the ground truth. ``need`` asks for
        training supervision as well, in ``ObjectData.extra``: ``"sdf"`` (``(m, 4)`` rows of
        x, y, z, sdf) for SDF_SAMPLES, ``"occupancy"`` (x, y, z, 1 if inside) for
        OCCUPANCY_SAMPLES, ``"complete_points"`` for COMPLETE_POINTS; and ground-truth arrays for
        metrics, under their :class:`GroundTruthArray` value, for those in
        :attr:`provides_ground_truth` (others are ignored).
        """

    def ground_truth_points(self, ref: ObjectRef) -> np.ndarray:
        """The ground-truth points of one object, as :meth:`load` gives them
        (``ObjectData.gt_points``), for a user that needs nothing else of it; raise
        :class:`ObjectLoadError` if impossible. The default loads the object; a dataset that can
        make them more cheaply than the whole object overrides it (:class:`MeshDataset`: without
        the visible points' ray casting)."""
        return self.load(ref).gt_points

    @property
    def cache_root(self) -> Path:
        """Where this exact data version's arrays are cached."""
        return self.cache_dir / self.name / self.data_fingerprint()

    def cache_path(self, ref: ObjectRef) -> Path:
        """The cached arrays of one object (written atomically by :func:`save_npz_atomic`)."""
        return self.cache_root / "objects" / (ref.id.replace("/", "__") + ".npz")

    def points_to_complete(self, data: ObjectData) -> int:
        """How many points a method is asked for when completing ``data``: as many as the
        ground truth has (a dataset without ground truth overrides it)."""
        return len(data.gt_points)

    def max_context_size(self) -> int | None:
        """An upper bound on any object's visible points, known without loading (or None)."""
        return None


def _options(options: Any, training: bool, selection: bool = True) -> dict[str, Any]:
    if options is None or not is_dataclass(options):
        return {}
    return {
        f.name: getattr(options, f.name)
        for f in fields(options)
        if (training or not f.metadata.get("training_only"))
        and not (training and f.metadata.get("evaluation_only"))
        and (selection or not f.metadata.get("selection"))
    }


@dataclass(frozen=True)
class MeshOptions:
    """Options every mesh dataset shares: how many points preprocessing produces."""

    surface_candidates: int = field(
        default=20_000,
        metadata={"help": "surface samples tested for visibility (the paper: 200k)"},
    )
    gt_points: int = field(
        default=30_000, metadata={"help": "ground-truth points per object (the paper: 30k)"}
    )
    viewpoints: int = field(
        default=100, metadata={"help": "viewpoints around each object for visibility"}
    )
    seed: int = field(default=0, metadata={"help": "seed of the object split and sampling"})
    sdf_samples: int = field(
        default=500_000,
        metadata={"help": "SDF training samples per object (DeepSDF: 500k)", "training_only": True},
    )
    occupancy_samples: int = field(
        default=100_000,
        metadata={"help": "occupancy samples per object (OccNet: 100k)", "training_only": True},
    )
    complete_points: int = field(
        default=16_384,
        metadata={"help": "complete-surface points per object (PCN: 16384)", "training_only": True},
    )


class MeshDataset(Dataset):
    """A dataset whose objects are triangle meshes; preprocessing and caching are done here.

    Subclasses implement :meth:`categories`, :meth:`objects` and :meth:`mesh`. Arrays are cached in
    ``<cache_dir>/<name>/<fingerprint>/<object>.npz``, written atomically, so an interrupted
    preparation resumes where it stopped.
    """

    Options: ClassVar[type] = MeshOptions
    provides_ground_truth: ClassVar[frozenset[GroundTruthArray]] = frozenset(GroundTruthArray)

    @abstractmethod
    def mesh(self, ref: ObjectRef):  # -> trimesh.Trimesh
        """The raw mesh of one object, in its source frame."""

    def max_context_size(self) -> int | None:
        return self.options.surface_candidates

    def identity(self, training: bool, selection: bool = True) -> dict[str, Any]:
        return {**super().identity(training, selection), "preprocess": PREPROCESS_VERSION}

    def preprocess_params(self) -> PreprocessParams:
        o = self.options
        return PreprocessParams(
            surface_candidates=o.surface_candidates, gt_points=o.gt_points, viewpoints=o.viewpoints
        )

    def load(
        self, ref: ObjectRef, need: frozenset[Supervision | GroundTruthArray] = frozenset()
    ) -> ObjectData:
        path = self.cache_path(ref)
        arrays = self._cached(path)
        if arrays is None:
            arrays = self._build(ref, path)
        extra = {k: v for k, v in arrays.items() if k not in _BASE_ARRAYS}
        for kind in need:
            if kind in _EXTRA_ARRAYS:
                extra[_EXTRA_ARRAYS[kind]] = self._extra(ref, kind)
            elif isinstance(kind, GroundTruthArray):
                extra[kind.value] = self._ground_truth(ref, kind)
        return ObjectData(
            ref, arrays["surface_points"], arrays["surface_normals"], arrays["gt_points"], extra
        )

    def ground_truth_points(self, ref: ObjectRef) -> np.ndarray:
        """The cached object's ground truth; when the object is not cached yet, the same points
        made without its visible points and not cached (the whole object is prepared by the
        first :meth:`load`). An object whose visible points would fail to prepare (none visible)
        still has its ground truth here. A subclass whose :meth:`load` changes the ground truth
        overrides this too (or returns ``self.load(ref).gt_points``)."""
        arrays = self._cached(self.cache_path(ref))
        if arrays is not None:
            return arrays["gt_points"]
        try:
            mesh = self.mesh(ref)
            return prepare_ground_truth(mesh, self.preprocess_params(), self._preprocess_rng(ref))
        except Exception as exc:
            raise ObjectLoadError(_preprocess_failure(exc)) from exc

    @staticmethod
    def _cached(path: Path) -> dict[str, np.ndarray] | None:
        """The cached arrays at ``path``, None when not cached (or damaged); raise
        :class:`ObjectLoadError` when preprocessing already failed for this exact data version."""
        failed = path.with_suffix(".error.txt")
        if failed.exists():
            raise ObjectLoadError(failed.read_text())
        return _read_npz(path)

    def _extra(self, ref: ObjectRef, kind: Supervision) -> np.ndarray:
        """A training array, built from the normalised mesh on first use and cached on its own."""
        from shapebench.preprocess.samples import complete_points, occupancy_samples, sdf_samples

        o = self.options
        build = {
            Supervision.SDF_SAMPLES: lambda unit, rng: sdf_samples(unit, o.sdf_samples, rng),
            Supervision.OCCUPANCY_SAMPLES: lambda unit, rng: occupancy_samples(
                unit, o.occupancy_samples, rng
            ),
            Supervision.COMPLETE_POINTS: lambda unit, rng: complete_points(
                unit, o.complete_points, rng
            ),
        }[kind]
        name = _EXTRA_ARRAYS[kind]
        return self._mesh_array(
            ref, name, self.training_cache_root, self.training_data_fingerprint(), build
        )

    def _ground_truth(self, ref: ObjectRef, kind: GroundTruthArray) -> np.ndarray:
        """A ground-truth array for metrics, built from the normalised mesh on first use and
        cached beside the object's arrays (seeded by the data fingerprint: the same points for
        every method, run and machine)."""
        from shapebench.preprocess.samples import IOU_POINTS, occupancy_samples, oriented_points

        if kind is GroundTruthArray.ORIENTED_POINTS:

            def build(unit, rng):
                return oriented_points(unit, self.options.gt_points, rng)
        else:

            def build(unit, rng):
                return occupancy_samples(unit, IOU_POINTS, rng)

        root = self.cache_root / "ground-truth"
        return self._mesh_array(ref, kind.value, root, self.data_fingerprint(), build)

    def _mesh_array(self, ref: ObjectRef, name: str, root: Path, fingerprint: str, build):
        """The array ``name`` of one object, cached in ``root``; on first use ``build(unit mesh,
        rng)`` makes it, the generator seeded by (name, ``fingerprint``, object)."""
        path = root / (ref.id.replace("/", "__") + f".{name}.npz")
        cached = _read_npz(path)
        if cached is not None:
            return cached[name]
        try:
            unit = self._unit_mesh(ref)
        except Exception as exc:
            raise ObjectLoadError(f"cannot build {name}: {type(exc).__name__}: {exc}") from exc
        rng = np.random.default_rng(stable_seed(name, fingerprint, ref.id))
        array = build(unit, rng)
        save_npz_atomic(path, {name: array})
        return array

    def _unit_mesh(self, ref: ObjectRef):
        """The object's mesh in the benchmark frame (the normalisation preprocessing applied)."""
        from shapebench.preprocess.normalize import normalize

        unit, _, _ = normalize(self.mesh(ref))
        return unit

    @property
    def training_cache_root(self) -> Path:
        return self.cache_dir / self.name / self.training_data_fingerprint() / "training"

    def _preprocess_rng(self, ref: ObjectRef) -> np.random.Generator:
        """The generator an object's preprocessing draws from: seeded by the data version and the
        object, so every machine and run prepares the same arrays."""
        return np.random.default_rng(stable_seed("preprocess", self.data_fingerprint(), ref.id))

    def _build(self, ref: ObjectRef, path: Path) -> dict[str, np.ndarray]:
        try:
            mesh = self.mesh(ref)
            arrays = prepare_mesh(mesh, self.preprocess_params(), self._preprocess_rng(ref))
        except Exception as exc:
            reason = _preprocess_failure(exc)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.with_suffix(".error.txt").write_text(reason)
            raise ObjectLoadError(reason) from exc
        save_npz_atomic(path, arrays)
        return arrays


def _preprocess_failure(exc: Exception) -> str:
    """The one line recorded for an object whose mesh could not be read or preprocessed."""
    if isinstance(exc, (ObjectLoadError, PreprocessError)):
        return str(exc)
    return f"cannot read or preprocess mesh: {type(exc).__name__}: {exc}"


_BASE_ARRAYS = ("surface_points", "surface_normals", "gt_points")
_EXTRA_ARRAYS = {
    Supervision.SDF_SAMPLES: "sdf",
    Supervision.OCCUPANCY_SAMPLES: "occupancy",
    Supervision.COMPLETE_POINTS: "complete_points",
}


def _read_npz(path: Path) -> dict[str, np.ndarray] | None:
    """The arrays of ``path``; None when it is missing, or damaged (truncated, or a member whose
    CRC-32 does not match, which numpy's zip reader checks): a damaged file is reported in one
    line naming it and deleted, and the caller rebuilds it."""
    try:
        # Our own handle: np.load leaks the one it opens when the archive is truncated.
        with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}  # reading each member to its end checks its CRC
    except FileNotFoundError:
        return None
    except Exception as exc:  # BadZipFile, EOFError, ValueError: not a complete archive
        reason = describe(exc)
    warn_corrupt(path, reason, "deleting it and preprocessing the object again")
    path.unlink(missing_ok=True)
    return None


def save_npz_atomic(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` to ``path`` so that a crash never leaves a half-written file: a
    temporary file of its own, flushed to disk (a rename may otherwise reach the disk before the
    data and leave an empty file after a power loss), then renamed."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp.npz")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
