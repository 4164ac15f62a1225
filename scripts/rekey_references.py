"""Move shipped reference checkpoints to the keys of a new key definition, when only the
definition changed and not what was trained.

    .venv/bin/python scripts/rekey_references.py [--dry-run]

The case it handles: dataset options marked ``evaluation_only`` (the synthetic benchmark's
``test_per_category``, the ShapeNet layouts' ``max_test_per_category``) used to be part of
every checkpoint key although no training object depends on them, so ``-D
test_per_category=10`` retrained every method. They left the training key; the weights did not
change, only the name they are filed under.

For every shipped reference it resolves the reference's method at its profile and seed, and
computes the key twice: as the code gives it now, and with the evaluation-only options put back
into the dataset's training identity (the old definition). Only a reference whose stamped key
equals the old-definition key is moved: its weights stamped with the new key, its folder
renamed, ``reference.json``'s key, digest and size updated, and a ``rekeyed`` entry recording
the old key, the commit and why. Any other reference is reported and left alone: its method's
code or options changed, so it needs retraining (scripts/reference_checkpoints.py).
"""

from __future__ import annotations

import argparse
import json
import shutil
from dataclasses import fields, replace
from pathlib import Path

WHY = (
    "the training key no longer holds the dataset's evaluation-only options "
    "(test_per_category), which no training object depends on; the weights are unchanged"
)


def old_definition_key(method, dataset, trainer) -> str:
    """The key as it was computed before evaluation-only options left the training identity."""
    from shapebench.hashing import stable_hash
    from shapebench.train.training import checkpoint_key

    identity = dataset.identity(training=True)
    options = dict(identity["options"])
    for f in fields(dataset.options):
        if f.metadata.get("evaluation_only"):
            options[f.name] = getattr(dataset.options, f.name)
    fingerprint = stable_hash({**identity, "options": options})

    class OldDefinition:  # the dataset, seen through the old training fingerprint
        def training_fingerprint(self) -> str:
            return fingerprint

    return checkpoint_key(method, OldDefinition(), trainer)  # type: ignore[arg-type]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dry-run", action="store_true", help="report, change nothing")
    args = parser.parse_args(argv)

    import tempfile

    import torch

    from shapebench.config import make_settings
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method
    from shapebench.store.provenance import git_commit
    from shapebench.train.checkpoints import load_safely, verify_checkpoint
    from shapebench.train.references import CHECKPOINT_FILE, INFO_FILE, SHIPPED, file_sha256
    from shapebench.train.training import apply_trainer, checkpoint_key, profile_trainer

    registry = get_registry()
    head = git_commit()
    left = 0
    with tempfile.TemporaryDirectory() as tmp:
        for info_path in sorted(SHIPPED.glob(f"*/*/{INFO_FILE}")):
            folder = info_path.parent
            info = json.loads(info_path.read_text())
            settings = make_settings(None, Path(tmp) / "cache", info["profile"], tmp)
            method = resolve_method(registry, info["method"], settings, {})
            dataset = resolve_dataset(registry, info["dataset"], settings, None, {})
            # one device, as the references were trained
            trainer = replace(profile_trainer(settings, seed=info["seed"]), devices=1)
            method = apply_trainer(method, trainer)
            new = checkpoint_key(method, dataset, trainer)
            if info["key"] == new:
                print(f"{folder}: already at its key")
                continue
            old = old_definition_key(method, dataset, trainer)
            if info["key"] != old:
                print(
                    f"{folder}: key {info['key']} is neither {new} (now) nor {old} (the old "
                    "definition): its method changed, retrain it"
                )
                left += 1
                continue
            target = folder.with_name(new)
            print(f"{folder.parent.name}: {old} -> {new}")
            if args.dry_run:
                continue
            checkpoint = load_safely(folder / CHECKPOINT_FILE)
            checkpoint["shapebench"] = {**checkpoint["shapebench"], "key": new}
            torch.save(checkpoint, folder / CHECKPOINT_FILE)
            info.update(
                key=new,
                sha256=file_sha256(folder / CHECKPOINT_FILE),
                bytes=(folder / CHECKPOINT_FILE).stat().st_size,
                rekeyed={"from": old, "at": head, "why": WHY},
            )
            info_path.write_text(json.dumps(info, indent=1, sort_keys=True) + "\n")
            shutil.move(folder, target)
            verify_checkpoint(target / CHECKPOINT_FILE, new)
    return 1 if left else 0


if __name__ == "__main__":
    raise SystemExit(main())
