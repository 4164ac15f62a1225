"""A leaderboard row: one method *variant*, with a readable label.

Two runs of one method belong to the same row only when everything that changes their results
except the seed is equal: the resolved options, the plugin's version and code, the training
settings and data (trainable methods), a user-given checkpoint, and what the protocol lets the
method see. The :class:`Variant` key hashes exactly that; the label shows, benchopt style, what
differs from the profile's defaults (``gauss[sigma=0.05]``, ``pcn[epochs=3]``), or the
``--label`` given at run time.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from shapebench.api.protocol import Protocol
from shapebench.config import default_profile
from shapebench.hashing import stable_hash


@dataclass(frozen=True)
class Variant:
    key: str
    label: str
    overrides: dict[str, Any]


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, (list, tuple, dict)):
        return json.dumps(value, separators=(",", ":"))
    return str(value)


def auto_label(name: str, overrides: dict[str, Any]) -> str:
    """``name[k=v,...]`` with the overrides sorted by key; ``name`` when there are none."""
    flags = [k for k, v in overrides.items() if v is True and k.startswith("+")]
    pairs = [f"{k}={_fmt(v)}" for k, v in sorted(overrides.items()) if k not in flags]
    label = f"{name}[{','.join(pairs)}]" if pairs else name
    return label + "".join(sorted(flags))


def make_variant(
    name: str,
    method_config: dict[str, Any],
    option_overrides: dict[str, Any],
    protocol: Protocol,
    profile: str,
    training: dict[str, Any] | None = None,
    training_overrides: dict[str, Any] | None = None,
    train_data: str | None = None,
    checkpoint_file: str | None = None,
    checkpoint_name: str | None = None,
    label: str | None = None,
    weights: str | None = None,
) -> Variant:
    """The row a run belongs to. ``training`` is the training identity without the seed (seeds
    are samples of one row, not rows); ``train_data`` the dataset's training fingerprint;
    ``checkpoint_file`` the digest of a checkpoint given by path (``run --checkpoint``),
    ``checkpoint_name`` how the row names it;
    ``weights`` is ``"local"`` for a local training of a key that has shipped weights
    (:mod:`shapebench.train.references`): a row of its own, labelled ``weights=local``, so
    that a retrained seed never sits beside the shipped training of the same seed. The shipped
    weights themselves (``reference:<digest>``, recorded in each cell's key) belong to the plain
    row: the same configuration, trained on another machine, as the other seeds of that row may
    be."""
    identity = {
        "method": method_config,
        "training": training,
        "train_data": train_data,
        "checkpoint_file": checkpoint_file,
        "context_normals": protocol.context_normals,
    }
    if not protocol.is_default_context:  # crop or noisy contexts: a row of their own
        identity["context"] = protocol.name
    if weights == "local":  # the row beside the reference's (see below); other rows keep their keys
        identity["weights"] = weights
    key = stable_hash(identity)
    overrides: dict[str, Any] = dict(option_overrides)
    overrides.update(training_overrides or {})
    if profile != default_profile():
        overrides["profile"] = profile
    if checkpoint_file:
        overrides["checkpoint"] = checkpoint_name or checkpoint_file
    if protocol.context_normals:
        overrides["+normals"] = True
    if protocol.context == "crop":
        overrides["crop"] = protocol.crop_fraction
    if protocol.context == "depth":
        overrides["protocol"] = "depth"
    if protocol.context_noise:
        overrides["noise"] = protocol.context_noise
    if weights == "local":
        overrides["weights"] = "local"
    return Variant(key, label or auto_label(name, overrides), overrides)
