"""Completions made anywhere, scored like every other row (issue 60): the ``files`` method.

``shapebench export`` writes the contexts of a set of cells and a manifest; a model in any
environment writes one completion per context below ``<export>/completions/`` as the manifest
says; ``shapebench run -m files -O root=<export>`` (or ``shapebench import <export>``, which
reads the dataset, protocol, sizes and seeds from the manifest) scores them. The method is
asked for the completion of each context like any method, and returns the file's: so the rows go
through the same runner, store, tables, paired tests, pictures and report as the built-in rows,
with nothing of their own to keep in step.

Why a method and not a separate import path: a method's rows are cells like any other, keyed,
resumable and compared, and the only new code is reading a file.

What the key holds: the option ``digest`` is filled in by the method with the SHA-256 of the
manifest and of every completion file the manifest expects (``root`` is the folder's path), so a
changed file is a new cell, never a cache hit. The row's name is ``--label`` (of ``run``,
``import`` or a sweep entry), as for any method.

Each context is found by (object, size, the seed a run gives it), and its points are compared
with the exported ones (their SHA-256): a run whose dataset, options, protocol or seeds are not
the manifest's fails those objects naming both sides, never scoring a completion of other
points. A missing, empty, NaN or unreadable file fails its object alone, naming the file. Files
below ``completions/`` that the manifest does not expect are named once, in a warning, and
ignored.
"""

from __future__ import annotations

import hashlib
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import ClassVar

from shapebench.api.errors import ConfigError
from shapebench.api.method import Method
from shapebench.api.options import option
from shapebench.api.types import Completion, Context
from shapebench.exchange.manifest import (
    COMPLETION_SUFFIXES,
    COMPLETIONS_DIR,
    MANIFEST,
    Entry,
    Manifest,
    read_manifest,
)
from shapebench.hashing import array_digest


class ExtraFilesWarning(UserWarning):
    """Files below ``completions/`` that no context expects: named once, then ignored."""


#: The folders (and digests) whose extra files were named already in this process: the
#: method is built more than once per run (its options are resolved, then it completes).
_WARNED: set[tuple[str, str]] = set()
#: How many extra files a warning lists by name.
_LISTED = 5


@dataclass(frozen=True)
class FilesOptions:
    root: str = option(
        "",
        "the export folder (shapebench export --out): its manifest.json, and one completion "
        "per context below its completions/ as the manifest says",
    )
    digest: str = option(
        "",
        "filled in by the method: SHA-256 of the manifest and of the completion files, so that "
        "a changed file makes new cells (leave it empty)",
    )


@dataclass(frozen=True)
class Folder:
    """What the method knows of ``root``: its manifest, and per expected completion the file
    (or files) there."""

    root: Path
    manifest: Manifest
    found: dict[str, list[Path]]
    extra: list[str]
    digest: str


def scan(root: Path) -> Folder:
    """Read the manifest of ``root`` and find the completion files it expects."""
    manifest = read_manifest(root)
    expected = {e.completion for e in manifest.entries}
    found: dict[str, list[Path]] = {}
    extra: list[str] = []
    below = root / COMPLETIONS_DIR
    files = sorted(p for p in below.rglob("*") if p.is_file()) if below.is_dir() else []
    for path in files:
        rel = path.relative_to(root).as_posix()
        stem = rel[: -len(path.suffix)] if path.suffix else rel
        if path.suffix.lower() in COMPLETION_SUFFIXES and stem in expected:
            found.setdefault(stem, []).append(path)
        else:
            extra.append(rel)
    h = hashlib.sha256((root / MANIFEST).read_bytes())
    for stem in sorted(found):
        for path in found[stem]:
            h.update(path.relative_to(root).as_posix().encode() + b"\0")
            h.update(hashlib.sha256(path.read_bytes()).digest())
    return Folder(root, manifest, found, extra, h.hexdigest())


class FilesMethod(Method):
    name = "files"
    display_name = "Completions from files"
    description = (
        "scores completions made outside shapebench, read from an export folder "
        "(-O root=DIR; see docs/byo-completions.md)"
    )
    trains = False
    Options = FilesOptions
    check_needs = "completions from a user's export folder (-O root=DIR); tests/exchange runs it"
    #: The manifest's format, the file formats read, the digests of the folder, and how meshes
    #: become the points every metric reads.
    code_modules: ClassVar[tuple[str, ...]] = (
        "shapebench.exchange.manifest",
        "shapebench.exchange.pcd",
        "shapebench.geometry.meshing",
        "shapebench.geometry.sampling",
        "shapebench.hashing",
    )

    def __init__(self, options: FilesOptions | None = None) -> None:
        super().__init__(options)
        if not self.options.root:
            raise ConfigError(
                "the files method reads completions from an export folder, and none was given",
                "-O root=DIR, the folder of shapebench export --out DIR (or: shapebench import "
                "DIR)",
            )
        root = Path(self.options.root).expanduser()
        if not root.is_dir():
            raise ConfigError(f"the files method's root {root} is not a folder")
        self.folder = scan(root)
        self.options = replace(self.options, digest=self.folder.digest)
        self._entries = {
            (e.object, e.size, e.context_seed): e for e in self.folder.manifest.entries
        }
        self._warn_extra()

    def _warn_extra(self) -> None:
        folder = self.folder
        if not folder.extra or (str(folder.root), folder.digest) in _WARNED:
            return
        _WARNED.add((str(folder.root), folder.digest))
        named = ", ".join(folder.extra[:_LISTED])
        more = len(folder.extra) - _LISTED
        warnings.warn(
            f"{len(folder.extra)} file(s) below {folder.root / COMPLETIONS_DIR} are not "
            f"completions the manifest expects, ignored: {named}"
            + (f" and {more} more" if more > 0 else ""),
            ExtraFilesWarning,
            stacklevel=2,
        )

    def complete(self, context: Context, n_points: int) -> Completion:
        from shapebench_files.reading import read_completion

        entry = self._entry(context)
        root = self.folder.root
        paths = self.folder.found.get(entry.completion, [])
        if not paths:
            raise FileNotFoundError(
                f"no completion {entry.completion}.* in {root} (one of "
                f"{', '.join(COMPLETION_SUFFIXES)})"
            )
        if len(paths) > 1:
            names = ", ".join(p.name for p in paths)
            raise ValueError(f"{len(paths)} completions for {entry.completion}: {names}; keep one")
        path = paths[0]
        completion = read_completion(
            path, n_points, context.seed, path.relative_to(root).as_posix()
        )
        return completion

    def _entry(self, context: Context) -> Entry:
        """The manifest's entry of ``context``, checked against its points; the mismatch, with
        both sides, otherwise."""
        ref, size = context.ref, context.size
        manifest = self.folder.manifest
        entry = self._entries.get((ref.id, size, context.seed))
        where = f"{self.folder.root / MANIFEST}: {manifest.describe()}"
        if entry is None:
            same = [e for e in manifest.entries if e.object == ref.id]
            if not same:
                raise LookupError(f"object {ref.id!r} was not exported ({where})")
            if not any(e.size == size for e in same):
                raise LookupError(f"context size {size} of {ref.id!r} was not exported ({where})")
            raise LookupError(
                f"the run's dataset options or --seeds are not the export's: the context of "
                f"{ref.id!r} (k={size}, method seed {context.seed}) was not exported ({where})"
            )
        if array_digest(context.points) != entry.digest:
            raise LookupError(
                f"the run's protocol or context noise is not the export's: the context of "
                f"{ref.id!r} (k={size}) differs from {entry.context} ({where})"
            )
        return entry
