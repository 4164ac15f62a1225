"""User-supplied split files for ShapeNet (``-D split_dir=DIR``).

``DIR`` holds ``test.txt`` or ``test.json`` (required) and ``train.txt`` or ``train.json``
(optional; without it no training split exists). A ``.txt`` file lists one ``<synset>/<model>``
per line (blank lines and ``#`` comments ignored). A ``.json`` file is a list of
``"<synset>/<model>"`` strings, a ``{"<synset>": ["<model>", ...]}`` mapping, or DeepSDF's split
format ``{"ShapeNetV2": {"<synset>": ["<model>", ...]}}``, so DeepSDF's published splits work as
they are. Test models of trained categories form the ``trained`` split, test models of novel
categories the ``novel`` split; train models of novel categories are ignored (they are novel).
"""

from __future__ import annotations

import json
from pathlib import Path

from shapebench.api.errors import ConfigError

SPLIT_NAMES = ("train", "test")


def read_split_dir(split_dir: str | Path) -> dict[str, set[str]]:
    """``{"train": ids, "test": ids}`` with ids ``<synset>/<model>``; train may be empty."""
    folder = Path(split_dir).expanduser()
    if not folder.is_dir():
        raise ConfigError(f"split_dir {folder} is not a folder", _FORMAT)
    out: dict[str, set[str]] = {}
    for name in SPLIT_NAMES:
        candidates = [folder / f"{name}{ext}" for ext in (".txt", ".json")]
        found = [p for p in candidates if p.is_file()]
        if len(found) > 1:
            raise ConfigError(f"both {found[0]} and {found[1]} exist; keep one", _FORMAT)
        if not found:
            if name == "test":
                raise ConfigError(f"split_dir {folder} has no test.txt or test.json", _FORMAT)
            out[name] = set()
            continue
        out[name] = _read(found[0])
    overlap = out["train"] & out["test"]
    if overlap:
        raise ConfigError(
            f"{len(overlap)} model(s) are in both the train and the test split of {folder}, "
            f"e.g. {sorted(overlap)[0]}",
            _FORMAT,
        )
    return out


_FORMAT = (
    "split_dir holds test.txt|test.json and optionally train.txt|train.json: text files list one "
    "<synset>/<model> per line; JSON files hold such a list, {synset: [model, ...]} or DeepSDF's "
    '{"ShapeNetV2": {synset: [model, ...]}}'
)


def _read(path: Path) -> set[str]:
    if path.suffix == ".txt":
        lines = (line.split("#", 1)[0].strip() for line in path.read_text().splitlines())
        ids = [line for line in lines if line]
    else:
        try:
            ids = list(_json_ids(json.loads(path.read_text())))
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"cannot read split file {path}: {exc}", _FORMAT) from exc
    bad = [i for i in ids if i.count("/") != 1]
    if bad:
        raise ConfigError(f"split file {path}: {bad[0]!r} is not <synset>/<model>", _FORMAT)
    return set(ids)


def _json_ids(data):
    if isinstance(data, list):
        for item in data:
            if not isinstance(item, str):
                raise TypeError(f"expected strings in the list, got {item!r}")
            yield item
    elif isinstance(data, dict):
        for key, value in data.items():
            if isinstance(value, dict):  # DeepSDF: {"ShapeNetV2": {synset: [...]}}
                yield from _json_ids(value)
            elif isinstance(value, list):
                yield from (f"{key}/{m}" for m in value)
            else:
                raise TypeError(f"expected a list of models under {key!r}")
    else:
        raise TypeError("expected a list or an object at the top level")
