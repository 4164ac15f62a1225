"""The objects of a run: loaded once and kept across its cells (:class:`ObjectCache`), and checked
against the context sizes asked for before any cell is computed (:func:`check_context_sizes`)."""

from __future__ import annotations

from collections import OrderedDict

from shapebench.api.contexts import ContextStore
from shapebench.api.dataset import Dataset, ObjectLoadError
from shapebench.api.errors import ShapebenchError
from shapebench.api.protocol import Protocol
from shapebench.api.types import GroundTruthArray, ObjectData, ObjectRef


class ObjectCache:
    """Keeps recently loaded objects in memory across the cells of a run."""

    def __init__(
        self, dataset: Dataset, capacity: int = 64, need: frozenset[GroundTruthArray] = frozenset()
    ) -> None:
        self.dataset = dataset
        self.capacity = capacity
        #: Ground-truth arrays the run's metrics read, among those the dataset can build.
        self.need = need & dataset.provides_ground_truth
        self._items: OrderedDict[str, ObjectData | ObjectLoadError] = OrderedDict()

    def get(self, ref: ObjectRef) -> ObjectData:
        item = self._items.get(ref.id)
        if item is None:
            try:
                item = self.dataset.load(ref, self.need) if self.need else self.dataset.load(ref)
            except ObjectLoadError as exc:
                item = exc
            self._items[ref.id] = item
            if len(self._items) > self.capacity:
                self._items.popitem(last=False)
        else:
            self._items.move_to_end(ref.id)
        if isinstance(item, ObjectLoadError):
            raise item
        return item


def check_context_sizes(
    refs: list[ObjectRef],
    cache: ObjectCache,
    sizes: list[int],
    quiet: bool,
    label: str,
    protocol: Protocol,
    store: ContextStore,
) -> None:
    """Load (and if needed preprocess) every object; refuse sizes some object cannot provide
    (visible surface points; under ``--protocol crop`` or ``depth`` the partial cloud the store
    samples contexts from: what a crop leaves, what the camera sees)."""
    from shapebench.progress import progress_bar

    partial = protocol.context in ("crop", "depth")
    fewest: tuple[int, str] | None = None
    with progress_bar(len(refs), f"preparing {label}", quiet) as bar:
        for ref in refs:
            try:
                data = cache.get(ref)
                if partial:
                    n = len(store.partial_points(data, protocol))
                else:
                    n = len(data.surface_points)
                if fewest is None or n < fewest[0]:
                    fewest = (n, ref.id)
            except ObjectLoadError:
                pass  # counted as a failure in every cell
            bar.update()
    if fewest is None or max(sizes) <= fewest[0]:
        return
    n, obj = fewest
    if not partial:
        raise ShapebenchError(
            f"context size {max(sizes)} is larger than the {n} visible surface points of "
            f"object {obj!r} ({label})",
            f"use context sizes up to {n}, or sample more surface points "
            "(-D surface_candidates=...)",
        )
    if protocol.context == "depth":
        what = f"object {obj!r} shows its depth camera"
    else:
        what = f"a crop of {protocol.crop_fraction:g} leaves of object {obj!r}"
    raise ShapebenchError(
        f"context size {max(sizes)} is larger than the {n} ground-truth points {what} ({label})",
        f"use context sizes up to {n}, or more ground-truth points (-D gt_points=...)",
    )
