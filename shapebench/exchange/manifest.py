"""The manifest of an export: what the contexts are, and where each completion is expected.

``manifest.json`` sits at the top of an export folder. It names the dataset as the store does
(name, version, options, ``fingerprint``: which objects; ``data_fingerprint``: the arrays and
the context draws), the context protocol and its parameters, the frame every coordinate is in,
the cells (splits, context sizes, run seeds) and one entry per context: where its points are
(``contexts/...npy`` and ``.ply``), the seed a method is given with it (``context_seed``, the
:attr:`~shapebench.api.types.Context.seed` of a run), how many points a completion should have
(``n_points``, the size of the ground truth), the SHA-256 of its points, and the path, without
its suffix, where its completion is expected (``completions/...``: any of
:data:`COMPLETION_SUFFIXES`).

It is written with sorted keys and no time stamp, so that two exports of the same cells are
byte-identical; it is read back by the ``files`` method and by ``shapebench import``, which
refuse a manifest that does not describe the run's contexts. Plugins may import this module
(the ``files`` method does): it depends on :mod:`shapebench.api` alone.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, is_dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np

from shapebench.api.dataset import Dataset
from shapebench.api.errors import ConfigError
from shapebench.api.protocol import Protocol

MANIFEST = "manifest.json"
#: Bump when the layout or the manifest's meaning changes.
FORMAT = "shapebench-exchange-v1"
CONTEXTS_DIR = "contexts"
COMPLETIONS_DIR = "completions"
#: The frame of every exported and completed coordinate: the one methods work in.
FRAME = (
    "the dataset's own frame, the coordinates Method.complete() receives and returns: for the "
    "mesh datasets (synthetic, shapenet, meshes) and shapenet55 the unit-radius frame (centre "
    "of mass at the origin, max vertex distance 1); for pcn and the scan datasets, theirs (see "
    "'shapebench datasets'). Completions are returned in it, unscaled"
)
#: What a completion may be: point clouds (``.npy``, ``.pcd``, ``.xyz``, a ``.ply`` of
#: vertices) or meshes (``.obj``, ``.off``, a ``.ply`` with faces).
COMPLETION_SUFFIXES = (".npy", ".ply", ".pcd", ".xyz", ".obj", ".off")


def _plain(value: Any) -> Any:
    """A JSON-writable copy of an option value (paths, enums, numpy scalars)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        items = [_plain(v) for v in value]
        return sorted(items, key=str) if isinstance(value, (set, frozenset)) else items
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, Enum):
        return _plain(value.value)
    if isinstance(value, np.generic):
        return value.item()
    return value


def safe_part(name: str) -> str:
    """A file-name part for an object id or category (ids may hold ``/``)."""
    return str(name).replace("/", "__").replace("\\", "__")


def entry_stem(split: str, category: str, object_id: str, size: int, seed: int) -> str:
    """``<split>/<category>/<object>/n<size>-s<seed>``: where a context's files live below
    ``contexts/`` and its completion below ``completions/``."""
    return f"{split}/{safe_part(category)}/{safe_part(object_id)}/n{size}-s{seed}"


@dataclass(frozen=True)
class Entry:
    """One exported context and the completion expected for it."""

    split: str
    category: str
    object: str
    size: int
    seed: int
    context_seed: int
    n_points: int
    digest: str
    context: str
    completion: str
    normals: str | None = None

    def as_json(self) -> dict[str, Any]:
        out = {
            "split": self.split,
            "category": self.category,
            "object": self.object,
            "size": self.size,
            "seed": self.seed,
            "context_seed": self.context_seed,
            "n_points": self.n_points,
            "digest": self.digest,
            "context": self.context,
            "context_ply": self.context[: -len(".npy")] + ".ply",
            "completion": self.completion,
        }
        if self.normals:
            out["normals"] = self.normals
        return out


@dataclass(frozen=True)
class Manifest:
    """An export's manifest (see the module docstring)."""

    dataset: str
    dataset_version: str
    dataset_options: dict[str, Any]
    fingerprint: str
    data_fingerprint: str
    protocol: Protocol
    splits: list[str]
    contexts: list[int]
    seeds: list[int]
    entries: list[Entry]
    #: Objects that could not be loaded: ``{"split", "object", "reason"}``, none exported.
    failed: list[dict[str, str]] = field(default_factory=list)
    shapebench_version: str = ""

    @classmethod
    def for_dataset(
        cls,
        dataset: Dataset,
        protocol: Protocol,
        splits: list[str],
        contexts: list[int],
        seeds: list[int],
        entries: list[Entry],
        failed: list[dict[str, str]],
    ) -> Manifest:
        from shapebench import __version__

        options = dataset.options
        plain = _plain(asdict(options)) if is_dataclass(options) else {}
        return cls(
            dataset.name,
            dataset.version,
            plain,
            dataset.fingerprint(),
            dataset.data_fingerprint(),
            protocol,
            list(splits),
            list(contexts),
            list(seeds),
            entries,
            failed,
            __version__,
        )

    def as_json(self) -> dict[str, Any]:
        p = self.protocol
        return {
            "format": FORMAT,
            "shapebench_version": self.shapebench_version,
            "dataset": {
                "name": self.dataset,
                "version": self.dataset_version,
                "options": self.dataset_options,
                "fingerprint": self.fingerprint,
                "data_fingerprint": self.data_fingerprint,
            },
            "protocol": {
                "name": p.name,
                "context": p.context,
                "crop_fraction": p.crop_fraction,
                "context_noise": p.context_noise,
                "context_normals": p.context_normals,
                "description": p.describe_context(),
            },
            # The coordinates methods see; scores may be reported in another frame (--frame).
            "frame": {"name": "dataset", "description": FRAME},
            "cells": {"splits": self.splits, "contexts": self.contexts, "seeds": self.seeds},
            "layout": {
                "contexts": f"{CONTEXTS_DIR}/<split>/<category>/<object>/n<size>-s<seed>.npy "
                "(float32 (k, 3)) and .ply; -normals.npy with --context-normals",
                "completions": f"{COMPLETIONS_DIR}/<split>/<category>/<object>/n<size>-s<seed>"
                f"{{{','.join(COMPLETION_SUFFIXES)}}}",
            },
            "entries": [e.as_json() for e in self.entries],
            "failed": self.failed,
        }

    def text(self) -> str:
        """The file's text: sorted keys, no time stamp (two exports are byte-identical)."""
        return json.dumps(self.as_json(), sort_keys=True, indent=1) + "\n"

    def describe(self) -> str:
        """The manifest's side of a mismatch, in words."""
        return (
            f"dataset {self.dataset!r} (data fingerprint {self.data_fingerprint}), contexts "
            f"{self.protocol.name}, sizes {','.join(map(str, self.contexts))}, seeds "
            f"{','.join(map(str, self.seeds))}"
        )

    def check_matches(self, dataset: Dataset, protocol: Protocol, where: Path) -> None:
        """Refuse, naming both sides, a dataset or protocol whose contexts are not those this
        manifest describes (``where``: the folder, for the message)."""
        ours = (dataset.name, dataset.data_fingerprint())
        if ours != (self.dataset, self.data_fingerprint):
            raise ConfigError(
                f"{where / MANIFEST} was exported from dataset {self.dataset!r} (data "
                f"fingerprint {self.data_fingerprint}); this run's is {dataset.name!r} (data "
                f"fingerprint {ours[1]})",
                "export again with this dataset and its options (shapebench export), or run "
                "with the manifest's (shapebench import reads them from it)",
            )
        theirs = (self.protocol.name, self.protocol.context_normals)
        if (protocol.name, protocol.context_normals) != theirs:
            said = "+normals" if self.protocol.context_normals else ""
            run = "+normals" if protocol.context_normals else ""
            raise ConfigError(
                f"{where / MANIFEST} holds {self.protocol.name}{said} contexts; this run's "
                f"are {protocol.name}{run}",
                "export again with this protocol, or run with the manifest's",
            )


def _protocol(raw: dict[str, Any]) -> Protocol:
    return Protocol(
        context_normals=bool(raw.get("context_normals", False)),
        context=str(raw.get("context", "sparse")),
        crop_fraction=float(raw.get("crop_fraction", 0.0)),
        context_noise=float(raw.get("context_noise", 0.0)),
    )


def read_manifest(folder: Path | str) -> Manifest:
    """The manifest of the export folder ``folder``; one :class:`ConfigError` line naming the
    file and what is wrong with it otherwise."""
    path = Path(folder) / MANIFEST
    try:
        raw = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(
            f"{path} does not exist: a folder of completions holds the manifest.json of its export",
            "run shapebench export --out DIR, write the completions under DIR/completions as "
            "the manifest says, and pass DIR",
        ) from None
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path} cannot be read as JSON ({exc})") from None
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        found = raw.get("format") if isinstance(raw, dict) else type(raw).__name__
        raise ConfigError(f"{path} is not a shapebench export manifest ({FORMAT}): {found!r}")
    try:
        ds, cells = raw["dataset"], raw["cells"]
        entries = [
            Entry(
                split=str(e["split"]),
                category=str(e["category"]),
                object=str(e["object"]),
                size=int(e["size"]),
                seed=int(e["seed"]),
                context_seed=int(e["context_seed"]),
                n_points=int(e["n_points"]),
                digest=str(e["digest"]),
                context=str(e["context"]),
                completion=str(e["completion"]),
                normals=e.get("normals"),
            )
            for e in raw["entries"]
        ]
        return Manifest(
            dataset=str(ds["name"]),
            dataset_version=str(ds["version"]),
            dataset_options=dict(ds["options"]),
            fingerprint=str(ds["fingerprint"]),
            data_fingerprint=str(ds["data_fingerprint"]),
            protocol=_protocol(raw["protocol"]),
            splits=[str(s) for s in cells["splits"]],
            contexts=[int(c) for c in cells["contexts"]],
            seeds=[int(s) for s in cells["seeds"]],
            entries=entries,
            failed=list(raw.get("failed", [])),
            shapebench_version=str(raw.get("shapebench_version", "")),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"{path} is damaged: {type(exc).__name__}: {exc}") from None
