"""Finding ShapeNetCore models on disk, in the v1 or the v2 layout, and explaining a bad root.

v1: ``<root>/<synset>/<model>/model.obj``;
v2: ``<root>/<synset>/<model>/models/model_normalized.obj``.
The layout is detected per model (a tree may mix both); v2 wins when a folder holds both.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from shapebench.api.errors import DataNotFoundError
from shapebench_shapenet.catalog import ShapeNetCategory, catalog

V1_FILE = "model.obj"
V2_FILE = "models/model_normalized.obj"
LAYOUT_FILES = {"v2": V2_FILE, "v1": V1_FILE}

OBTAIN = (
    "ShapeNetCore is obtained by registering at https://shapenet.org and accepting its terms of "
    "use, then downloading ShapeNetCore v1 or v2 and extracting it. Expected layout: "
    f"v1 ROOT/<synset>/<model>/{V1_FILE}, v2 ROOT/<synset>/<model>/{V2_FILE} (e.g. ROOT/03001627/"
    "<model> for chairs). Point shapebench to ROOT with --data-root ROOT or "
    "SHAPEBENCH_SHAPENET_ROOT=ROOT."
)


@dataclass(frozen=True)
class Model:
    synset: str
    model: str
    layout: str  # "v1" or "v2"

    @property
    def id(self) -> str:
        return f"{self.synset}/{self.model}"


def model_file(root: Path, synset: str, model: str) -> tuple[Path, str] | None:
    """The mesh file of one model and its layout, or None if the folder has neither."""
    folder = Path(root) / synset / model
    for layout, rel in LAYOUT_FILES.items():
        path = folder / rel
        if path.is_file():
            return path, layout
    return None


def scan(
    root: Path | None, categories: list[ShapeNetCategory], required: bool = False
) -> dict[str, list[Model]]:
    """The models of ``categories`` under ``root``: synset -> models sorted by id.

    Model folders without a mesh file (a few v2 models ship only their JSON) are left out.
    Raises :class:`DataNotFoundError` when the root holds none of the paper's synsets or none of
    ``categories``, or (``required``: they were asked for by name) lacks one of them.
    """
    if root is None:
        raise DataNotFoundError("dataset 'shapenet' needs a local copy of ShapeNetCore", OBTAIN)
    root = Path(root)
    if not root.is_dir():
        raise DataNotFoundError(f"ShapeNetCore root {root} does not exist", OBTAIN)
    present = {c.synset for c in catalog() if (root / c.synset).is_dir()}
    if not present:
        raise DataNotFoundError(
            f"no ShapeNetCore synset folder (such as 03001627/ for chairs) in {root}"
            + _diagnose(root),
            OBTAIN,
        )
    absent = [c for c in categories if c.synset not in present]
    if required and absent:
        raise DataNotFoundError(
            "ShapeNet categor"
            + ("y " if len(absent) == 1 else "ies ")
            + ", ".join(f"{c.name} ({c.synset}/)" for c in absent)
            + f" not found in {root}",
            "drop it from -D categories=..., or download it with the rest of ShapeNetCore",
        )
    out: dict[str, list[Model]] = {}
    for cat in categories:
        if cat.synset not in present:
            continue
        models = []
        with os.scandir(root / cat.synset) as entries:
            names = sorted(e.name for e in entries if e.is_dir() and not e.name.startswith("."))
        for name in names:
            found = model_file(root, cat.synset, name)
            if found is not None:
                models.append(Model(cat.synset, name, found[1]))
        if models:
            out[cat.synset] = models
    if not out:
        asked = ", ".join(f"{c.name} ({c.synset})" for c in categories)
        raise DataNotFoundError(
            f"none of the selected ShapeNet categories has models in {root}: {asked}",
            f"present synsets: {', '.join(sorted(present))}. {OBTAIN}",
        )
    return out


def _diagnose(root: Path) -> str:
    """Why a root without synset folders may still be close: nested copy or unextracted zips."""
    notes = []
    try:
        children = sorted(p for p in root.iterdir() if not p.name.startswith("."))
    except OSError:
        return ""
    synsets = {c.synset for c in catalog()}
    nested = [p for p in children if p.is_dir() and any((p / s).is_dir() for s in synsets)]
    if nested:
        notes.append(f"; did you mean --data-root {nested[0]}?")
    zips = [p.name for p in children if p.suffix.lower() == ".zip"]
    if zips:
        notes.append(f"; found {len(zips)} zip file(s) ({zips[0]}, ...): extract them first")
    return "".join(notes)
