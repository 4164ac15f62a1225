"""Train (or take) the reference checkpoints shapebench ships for the synthetic benchmark.

    .venv/bin/python scripts/reference_checkpoints.py [--methods igr,msc] [--seeds 0,1,2]
        [--profile quick|standard] [--workspace DIR] [--storage float32|float16] [--export-only]
        [--keep-stale] [-O KEY=VALUE ...]

For every trainable method of the default sweep (``configs/sweeps/default.yaml``), or those
``--methods`` names, at the default profile (or ``--profile``) and each of ``--seeds`` (0), it
computes the checkpoint key the current code gives, trains it with ``shapebench train -m M -d
synthetic --retrain [--seed S] [--profile P] --workspace DIR`` unless DIR already holds a finished
training of that key (``--export-only``: never train), and writes the weights (no optimiser
state) and ``reference.json`` (key, command, versions, machine, wall time, final loss terms) to
``shapebench/reference_checkpoints/<family>/<key>/``. Folders of a family and profile whose key
is no longer among those exported are removed unless ``--keep-stale`` (so ship every seed of a
family in one call); another profile's are kept. Methods sharing a checkpoint (``msc`` and
``msc-noopt``) are trained once. ``-O`` ships a reference of other method options (a larger step
budget, say: ``-O steps=14400``), keyed by them like ``shapebench train -O`` and installed
wherever a run asks for that key. See :mod:`shapebench.train.references`.

A training is exported only if it ran at the commit the tree is at now, with no uncommitted
changes (the tags of its MLflow run): the key digests the method's code, not every module a
training goes through, and a shipped OccNet reference once turned out to be weights that no
commit trains. ``--allow-dirty`` exports anyway and records the training's commit as it was.

No shipped file may exceed 5 MB (``MAX_BYTES``): an export over it is removed and refused, and
``--storage float16`` ships the weights rounded to half precision instead (recorded in
``reference.json``; installing restores float32 tensors holding the rounded values).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATASET = "synthetic"


def versions() -> dict[str, str]:
    from importlib.metadata import version

    out = {"python": platform.python_version()}
    for dist in ("shapebench", "torch", "pytorch-lightning", "numpy"):
        try:
            out[dist] = version(dist)
        except Exception:  # not installed under that name
            continue
    return out


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()}"


def tree_problem(head: str) -> str | None:
    """Why nothing may ship from a tree at ``head`` (``git_commit()``'s value: a sha, ``-dirty``
    appended if modified, or ``unknown``), or None."""
    if head == "unknown" or head.endswith("-dirty"):
        return f"the source tree is at {head}: commit first"
    return None


def provenance_problem(tags: dict[str, str], head: str) -> str | None:
    """Why a training whose MLflow run carries ``tags`` must not ship from a tree at ``head``,
    or None."""
    if problem := tree_problem(head):
        return problem
    commit = tags.get("mlflow.source.git.commit")
    if commit is None:
        return "its training run records no git commit"
    if tags.get("git.dirty") == "True":
        return f"it was trained from a modified tree at {commit[:8]}"
    if commit != head:
        return f"it was trained at {commit[:8]}, the tree is at {head[:8]}"
    return None


def training_tags(settings, run_id: str) -> dict[str, str]:
    from mlflow.tracking import MlflowClient

    return MlflowClient(tracking_uri=settings.tracking_uri).get_run(run_id).data.tags


def main(argv: list[str] | None = None) -> None:
    from shapebench.train.references import MAX_BYTES, STORAGES  # no torch at import

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--methods",
        default=None,
        help="comma-separated (default: every trainable method of the default sweep)",
    )
    parser.add_argument("--seeds", default="0", help="comma-separated training seeds to ship [0]")
    parser.add_argument("--profile", default=None, help="the profile to ship [the default]")
    parser.add_argument("--workspace", default=str(Path(tempfile.gettempdir()) / "shapebench-refs"))
    parser.add_argument(
        "--storage",
        default="float32",
        choices=STORAGES,
        help="float32 (as trained) or float16 (weights rounded to half precision, for files "
        f"that would exceed {MAX_BYTES / 1e6:g} MB)",
    )
    parser.add_argument(
        "-O",
        dest="options",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="method option, as `shapebench train -O` (repeatable; part of the key)",
    )
    parser.add_argument("--export-only", action="store_true", help="never train")
    parser.add_argument("--keep-stale", action="store_true")
    parser.add_argument(
        "--note",
        default="",
        help="recorded in reference.json, e.g. how the workspace's trainings were run",
    )
    parser.add_argument(
        "--allow-dirty",
        action="store_true",
        help="export trainings made from another or a modified tree (recorded in reference.json)",
    )
    args = parser.parse_args(argv)

    from shapebench.api.options import parse_assignments
    from shapebench.config import make_settings
    from shapebench.store.provenance import git_commit
    from shapebench.sweeps.spec import load_sweep, sweep_methods
    from shapebench.train.references import INFO_FILE, SHIPPED, export
    from shapebench.train.ticket import checkpoint_dir
    from shapebench.train.training import read_done, reference_training

    os.environ["SHAPEBENCH_REFERENCE_CHECKPOINTS"] = "none"  # train, never install
    settings = make_settings(None, None, args.profile, args.workspace)
    default = load_sweep(ROOT / "configs" / "sweeps" / "default.yaml")
    names = args.methods.split(",") if args.methods else [m.name for m in sweep_methods(default)]
    target = SHIPPED
    head = git_commit()
    early = tree_problem(head)
    if early and not args.allow_dirty:  # before minutes of training, not after
        raise SystemExit(f"not exporting: {early} (--allow-dirty to export anyway)")
    done_keys: dict[str, set[str]] = {}
    # Train everything first, export after: an export rewrites tracked files, and a training
    # started after it would be tagged as made from a modified tree.
    finished = []
    seeds = [int(seed) for seed in args.seeds.split(",")]
    options = parse_assignments(args.options, "-O")
    for name, seed in [(name, seed) for name in names for seed in seeds]:
        training = reference_training(
            name, DATASET, args.profile, seed, Path(args.workspace), options=options
        )
        method, key = training.method, training.key
        if not method.cls.trains or method.cls.fit_ignores_trainer:
            continue  # nothing to ship: such a fit (an index) is built by the first run
        family = method.cls.checkpoint_family or method.name
        if key in done_keys.setdefault(family, set()):
            continue  # msc-noopt: msc's checkpoint
        workdir = checkpoint_dir(settings, method, key)
        # one device: the key reference_training gives (the world size is part of every key)
        command = ["shapebench", "train", "-m", name, "-d", DATASET, "--devices", "1", "--retrain"]
        if seed:
            command += ["--seed", str(seed)]
        if args.profile:
            command += ["--profile", args.profile]
        for option in args.options:
            command += ["-O", option]
        record = read_done(workdir)
        if record is None and args.export_only:
            print(f"{name}: no finished training of key {key} in {workdir.parent}; skipped")
            continue
        if record is None:
            print(f"{name}: training key {key} ({' '.join(command)})", flush=True)
            start = time.perf_counter()
            # ``python -m shapebench`` is the ``shapebench`` console script of this interpreter.
            run = [sys.executable, "-m", "shapebench", *command[1:]]
            subprocess.run([*run, "--workspace", args.workspace, "--quiet"], check=True)
            print(f"{name}: trained in {time.perf_counter() - start:.0f} s", flush=True)
            record = read_done(workdir)
        done_keys[family].add(key)
        finished.append((name, seed, key, family, workdir, record, command))
    for name, seed, key, family, workdir, record, command in finished:
        tags = training_tags(settings, record["run_id"]) if record.get("run_id") else {}
        problem = provenance_problem(tags, head)  # head: our own exports dirty the tree
        if problem and not args.allow_dirty:
            raise SystemExit(f"{name}: not exported: {problem} (--allow-dirty to export anyway)")
        summary = json.loads((workdir / "summary.json").read_text())
        info = {
            "key": key,
            "method": name,
            "family": family,
            "dataset": DATASET,
            "profile": settings.profile_name,
            "seed": seed,
            "command": " ".join(command),
            "summary": summary,
            "versions": versions(),
            "machine": machine(),
            "git_commit": head,
            "trained_at": tags.get("mlflow.source.git.commit", "unknown")
            + ("-dirty" if tags.get("git.dirty") == "True" else ""),
            "exported": datetime.now(UTC).isoformat(timespec="seconds"),
        }
        if options:  # what the key was computed with: tests recompute it from reference.json
            info["options"] = options
        if args.note:
            info["note"] = args.note
        ref = export(Path(record["path"]), target / family / key, info, args.storage)
        if ref.info["bytes"] > MAX_BYTES:
            shutil.rmtree(ref.folder)
            raise SystemExit(
                f"{name}: not exported: {ref.info['bytes'] / 1e6:.1f} MB is over the "
                f"{MAX_BYTES / 1e6:g} MB a shipped file may take (--storage float16 halves it)"
            )
        print(
            f"{name}: {ref.checkpoint} ({ref.info['bytes'] / 1e6:.2f} MB), "
            f"trained in {summary['wall_seconds']:.0f} s on {summary['device']}"
        )
    if args.keep_stale:
        return
    for family, keys in done_keys.items():
        if not keys:  # nothing of this family exported (e.g. --export-only, no training): keep
            continue
        for folder in sorted((target / family).iterdir()):
            info = folder / INFO_FILE
            profile = json.loads(info.read_text()).get("profile") if info.exists() else None
            if profile != settings.profile_name:
                continue  # another profile's reference
            if folder.is_dir() and folder.name not in keys:
                shutil.rmtree(folder)
                print(f"removed stale reference {folder}")


if __name__ == "__main__":
    main()
