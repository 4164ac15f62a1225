"""Move shipped reference checkpoints to the keys the code gives now, when only the key changed
and not what the training computes.

    .venv/bin/python scripts/rekey_references.py --from-commit C --why "..." [--dry-run]

A checkpoint key covers the method's options, its code digest and the training data's identity
(:func:`shapebench.train.ticket.checkpoint_key`). Some changes move a key without changing a
single trained weight, and retraining for them would waste hours:

* dataset options that no training object depends on left the training identity (the synthetic
  benchmark's ``test_per_category``; commit ``de4150c``);
* code moved between files (PCN's halved Chamfer, which PoinTr trains with, moved to
  ``shapebench.train.losses``: PoinTr's digest no longer covers PCN's package).

For every shipped reference whose stamped key differs from the key the code gives now, the script
computes the key commit ``C`` gave for the same method, profile and seed (``C``'s tree, unpacked
with ``git archive`` and imported in a child interpreter). Only a reference whose stamped key
equals that key is moved: its weights stamped with the new key, its folder renamed,
``reference.json``'s key, digest and size updated, and an entry appended to ``rekeyed`` (the old
key, the commit, ``--why``). Any other reference is reported and left alone: its training changed
after ``C`` too, so it needs retraining (scripts/reference_checkpoints.py).

That the training is unchanged is the caller's claim, and ``--why`` records it: check it first
(a few steps of training at ``C`` and now, compared tensor by tensor).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def keys_now(requests: list[dict]) -> list[str]:
    """The checkpoint key of each {method, dataset, profile, seed}, by the code imported here
    (one device, as the references are trained)."""
    # Spelled out rather than shapebench.train.training.reference_training: keys_at runs this in
    # an earlier commit's tree, which may predate that helper.
    from shapebench.config import make_settings
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method
    from shapebench.train.training import profile_trainer

    try:
        from shapebench.train.ticket import apply_trainer, checkpoint_key
    except ImportError:  # a tree from before the training ticket: they were in train/training.py
        from shapebench.train.training import apply_trainer, checkpoint_key

    registry = get_registry()
    keys = []
    with tempfile.TemporaryDirectory() as tmp:
        for r in requests:
            settings = make_settings(None, Path(tmp) / "cache", r["profile"], tmp)
            method = resolve_method(registry, r["method"], settings, {})
            dataset = resolve_dataset(registry, r["dataset"], settings, None, {})
            trainer = replace(profile_trainer(settings, seed=r["seed"]), devices=1)
            keys.append(checkpoint_key(apply_trainer(method, trainer), dataset, trainer))
    return keys


def keys_at(commit: str, requests: list[dict]) -> list[str]:
    """:func:`keys_now` as commit ``commit``'s code gives them: its tree unpacked into a temporary
    folder, put first on the child interpreter's path (before this checkout's editable install;
    the installed entry points name the same modules)."""
    archive = subprocess.run(
        ["git", "archive", "--format=tar", commit], cwd=ROOT, capture_output=True, check=True
    ).stdout
    with tempfile.TemporaryDirectory() as tree:
        with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
            tar.extractall(tree, filter="data")
        path = os.pathsep.join(str(Path(tree) / p) for p in (".", "plugins", "datasets"))
        env = {**os.environ, "PYTHONPATH": path, "SHAPEBENCH_REFERENCE_CHECKPOINTS": "none"}
        child = subprocess.run(
            [sys.executable, str(Path(__file__).resolve()), "--keys-of", json.dumps(requests)],
            cwd=tree,
            env=env,
            capture_output=True,
            text=True,
        )
        if child.returncode:
            raise SystemExit(f"computing the keys at {commit} failed:\n{child.stderr[-2000:]}")
        return json.loads(child.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--from-commit", help="the commit whose keys the references hold")
    parser.add_argument("--why", help="why the training is unchanged (recorded)")
    parser.add_argument("--dry-run", action="store_true", help="report, change nothing")
    parser.add_argument(
        "--methods",
        help="comma-separated: move only these methods' references (the others' training "
        "may have changed along with their key: retrain those)",
    )
    parser.add_argument("--keys-of", help=argparse.SUPPRESS)  # the child of keys_at
    args = parser.parse_args(argv)
    if args.keys_of:
        print(json.dumps(keys_now(json.loads(args.keys_of))))
        return 0
    if not args.from_commit or not (args.why or args.dry_run):
        parser.error("--from-commit is required, and --why unless --dry-run")

    import torch

    from shapebench.store.provenance import git_commit
    from shapebench.train.checkpoints import load_safely, verify_checkpoint
    from shapebench.train.references import CHECKPOINT_FILE, INFO_FILE, SHIPPED, file_sha256

    folders = sorted(p.parent for p in SHIPPED.glob(f"*/*/{INFO_FILE}"))
    infos = [json.loads((f / INFO_FILE).read_text()) for f in folders]
    if args.methods:
        chosen = set(args.methods.split(","))
        kept = [n for n, info in enumerate(infos) if info["method"] in chosen]
        folders, infos = [folders[n] for n in kept], [infos[n] for n in kept]
    requests = [{k: i[k] for k in ("method", "dataset", "profile", "seed")} for i in infos]
    now = keys_now(requests)
    moved = [n for n, (info, new) in enumerate(zip(infos, now, strict=True)) if info["key"] != new]
    before = dict(zip(moved, keys_at(args.from_commit, [requests[n] for n in moved]), strict=True))
    head = git_commit()
    left = 0
    for n, (folder, info, new) in enumerate(zip(folders, infos, now, strict=True)):
        if n not in moved:
            print(f"{folder.parent.name}/{folder.name}: at its key")
            continue
        if info["key"] != before[n]:
            print(
                f"{folder.parent.name}/{folder.name}: neither {new} (now) nor {before[n]} (at "
                f"{args.from_commit}): its training changed, retrain it"
            )
            left += 1
            continue
        old = info["key"]
        print(f"{folder.parent.name}: {old} -> {new}")
        if args.dry_run:
            continue
        checkpoint = load_safely(folder / CHECKPOINT_FILE)
        checkpoint["shapebench"] = {**checkpoint["shapebench"], "key": new}
        torch.save(checkpoint, folder / CHECKPOINT_FILE)
        history = info.get("rekeyed") or []
        history = [history] if isinstance(history, dict) else history
        info.update(
            key=new,
            sha256=file_sha256(folder / CHECKPOINT_FILE),
            bytes=(folder / CHECKPOINT_FILE).stat().st_size,
            rekeyed=[*history, {"from": old, "at": head, "why": args.why}],
        )
        (folder / INFO_FILE).write_text(json.dumps(info, indent=1, sort_keys=True) + "\n")
        target = folder.with_name(new)
        shutil.move(folder, target)
        verify_checkpoint(target / CHECKPOINT_FILE, new)
    return 1 if left else 0


if __name__ == "__main__":
    raise SystemExit(main())
