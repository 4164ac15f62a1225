"""Training trainable methods, one process per training.

Lightning's DDP supports one ``Trainer.fit`` per process (its subprocess launcher re-runs the
command line for every rank), so ``shapebench run`` and ``sweep`` never call ``fit`` themselves:
when a method trains and no checkpoint exists for its key (the key of its
:class:`~shapebench.train.ticket.TrainingTicket`), they start ``python -m shapebench train ...``
as a child process and wait for it. The checkpoint directory
holds ``done.json`` once training finished; an interrupted training leaves its last epoch-end
checkpoint there and the next training of that key resumes from it.

One training per key at a time: the training process holds a lock (:mod:`shapebench.store.locks`)
beside the key's folder; a second process for the same key waits for it, then finds
``done.json`` and trains nothing. A child training dies with the process that started it, so a
killed ``run`` or ``sweep`` leaves no orphan: on Linux the kernel sends it SIGTERM when its parent
dies, from its first instruction on; elsewhere, and for a parent that died before the child was
armed, a watchdog thread does (:mod:`shapebench.train.lifecycle`).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from shapebench.api.dataset import Dataset
from shapebench.api.errors import ShapebenchError
from shapebench.api.method import TrainerOptions, TrainingContext
from shapebench.config import Settings
from shapebench.registry.resolve import ResolvedMethod
from shapebench.store.records import CHECKPOINT_KEY_TAG, TRAINING_DEVICE_TAG, training_tags
from shapebench.store.tracking import Tracker, flatten, training_experiment_name
from shapebench.train.lifecycle import (
    PARENT_ENV,
    die_with_parent,
    stop_requested,
    wait_child,
    watch_parent,
)
from shapebench.train.ticket import TrainingTicket, apply_trainer, checkpoint_key, step_budget

RUN_ID_ENV = "SHAPEBENCH_TRAINING_RUN_ID"
#: Suffixes of PyTorch checkpoints, which read_done checks (checksums, key) before reuse.
TORCH_CHECKPOINTS = (".ckpt", ".pt", ".pth")


def trainer_options(settings: Settings, seed: int, **given: Any) -> TrainerOptions:
    """The profile's ``trainer:`` settings, overridden by the given (command-line) ones."""
    from dataclasses import fields

    values = dict(settings.profile.get("trainer") or {})
    values.update({k: v for k, v in given.items() if v is not None})
    known = {f.name for f in fields(TrainerOptions)}
    values = {k: v for k, v in values.items() if k in known}
    values["seed"] = seed
    return TrainerOptions(**values)


def profile_trainer(settings: Settings, seed: int) -> TrainerOptions:
    """The trainer settings a run gets with no command-line overrides."""
    return trainer_options(settings, seed)


@dataclass(frozen=True)
class ReferenceTraining:
    """How a reference checkpoint of a method is trained: the method at its profile's options,
    the dataset, the profile's trainer on one device, and the key they give."""

    settings: Settings
    method: ResolvedMethod
    dataset: Dataset
    trainer: TrainerOptions
    key: str


def reference_training(
    name: str,
    dataset: str,
    profile: str | None,
    seed: int,
    workspace: Path,
    cache_dir: Path | None = None,
    options: dict[str, Any] | None = None,
) -> ReferenceTraining:
    """The training behind ``name``'s reference at ``profile`` (None: the default) and ``seed``
    on ``dataset``, with the method ``options`` of ``-O`` (None: none; e.g. a larger step
    budget) and no other command-line overrides. One device, as the references are trained
    (``shapebench train --devices 1``): "auto" would count every GPU of a multi-GPU machine, and
    the world size is part of the key. ``workspace`` and ``cache_dir`` (None: the configured
    cache) are the settings' store and cache."""
    from shapebench.config import make_settings
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method

    settings = make_settings(None, cache_dir, profile, workspace)
    registry = get_registry()
    trainer = replace(profile_trainer(settings, seed), devices=1)
    method = apply_trainer(resolve_method(registry, name, settings, options or {}), trainer)
    data = resolve_dataset(registry, dataset, settings, None, {})
    return ReferenceTraining(settings, method, data, trainer, checkpoint_key(method, data, trainer))


def _global_rank() -> int:
    for var in ("RANK", "SLURM_PROCID", "LOCAL_RANK"):
        if os.environ.get(var, "").isdigit():
            return int(os.environ[var])
    return 0


def read_done(workdir: Path) -> dict[str, Any] | None:
    """The record of the finished training in ``workdir``, or None when there is none or it is
    damaged: a ``done.json`` that does not parse, or whose checkpoint no longer loads or holds
    another key, is reported and removed, so that the key trains again."""
    from shapebench.train.checkpoints import CorruptFileWarning, checkpoint_problem

    done = workdir / "done.json"
    if not done.exists():
        return None
    try:
        record = json.loads(done.read_text())
        path = Path(record["path"])
        if path.suffix in TORCH_CHECKPOINTS:
            problem = checkpoint_problem(path, workdir.name)
        else:  # a method's own format: only the method can tell whether it is sound
            problem = None if path.exists() else f"checkpoint {path} no longer exists"
    except (ValueError, KeyError, TypeError) as exc:
        problem = f"{done} is damaged ({type(exc).__name__}: {exc})"
    if problem is None:
        return record
    warnings.warn(f"{problem}; training it again", CorruptFileWarning, stacklevel=2)
    done.unlink(missing_ok=True)
    (workdir / "last.ckpt").unlink(missing_ok=True)
    return None


def lock_path(workdir: Path) -> Path:
    """The lock beside a checkpoint key's folder, held while that key trains."""
    return workdir.with_name(workdir.name + ".lock")


def train_here(ticket: TrainingTicket, settings: Settings, quiet: bool = False) -> dict[str, Any]:
    """Train ``ticket`` in this process (the ``shapebench train`` command); return the
    checkpoint record.

    Resumes from the key's last epoch-end checkpoint when an earlier training was interrupted;
    waits for, then reuses, a training of the same key running in another process. A shipped
    reference checkpoint of the key (:mod:`shapebench.train.references`) is used instead of
    training unless the ticket's ``retrain``.
    """
    from shapebench.store.locks import wait_lock

    if stop_requested() is not None:  # asked to stop while starting; the interrupt was lost
        raise KeyboardInterrupt
    method, dataset, key, workdir = ticket.method, ticket.dataset, ticket.key, ticket.workdir
    workdir.mkdir(parents=True, exist_ok=True)
    run_id = os.environ.get(RUN_ID_ENV)
    lead = _global_rank() == 0 and not run_id  # not a rank Lightning launched
    lock = None
    if lead:
        watch_parent()

        def waiting(holder: str) -> None:
            print(
                f"waiting for {holder}, which is training {method.name} on {dataset.name} "
                f"(checkpoint key {key})",
                file=sys.stderr,
            )

        lock = wait_lock(lock_path(workdir), waiting)
    try:
        if lead:
            record = _done_or_reference(ticket, settings)
            if record is not None:  # trained by the process we waited for, or shipped
                return record
        return _train_locked(ticket, settings, quiet, run_id)
    finally:
        if lock is not None:
            lock.release()


def _train_locked(ticket: TrainingTicket, settings: Settings, quiet: bool, run_id: str | None):
    from shapebench.train.callbacks import TrainingInterrupted
    from shapebench.train.checkpoints import LAST

    method, dataset, trainer = ticket.method, ticket.dataset, ticket.trainer
    key, workdir = ticket.key, ticket.workdir

    tracker = None
    if _global_rank() == 0 and not run_id:
        tracker = Tracker(settings)
        exp = tracker.experiment_id(training_experiment_name(dataset.name))
        tracker.describe_experiment(
            exp,
            f"shapebench trainings on {dataset.name}: one run per checkpoint key (method "
            "options and code, training data, epochs or steps, precision, devices, seed), with "
            "its loss curves; the evaluations that use a checkpoint link to its run in their "
            "description.",
        )
        # We hold the key's lock: a RUNNING training of this key was left by a killed process.
        tracker.abandon_stale(exp, key, tag=CHECKPOINT_KEY_TAG)
        resumed = (workdir / LAST).exists()
        tags = training_tags(method.name, dataset.name, key, resumed=resumed)
        steps = step_budget(method, trainer)
        label = method.name + (
            f" steps={steps}"
            if steps
            else f" epochs={method.options.epochs}"
            if hasattr(method.options, "epochs")
            else ""
        )
        run_id = tracker.start_run(
            exp, f"train {label} on {dataset.name} seed={trainer.seed}", tags
        )
        tracker.log_params(run_id, _training_params(ticket))
        os.environ[RUN_ID_ENV] = run_id  # inherited by the ranks Lightning launches
    instance = method.instantiate()
    try:
        if stop_requested() is not None:  # asked to stop while starting; the interrupt was lost
            raise KeyboardInterrupt
        path = instance.fit(
            TrainingContext(dataset, trainer, workdir, settings.tracking_uri, run_id, quiet)
        )
    except BaseException as exc:
        if tracker is not None:
            interrupted = isinstance(exc, (TrainingInterrupted, KeyboardInterrupt))
            tracker.end_after(run_id, exc, "KILLED" if interrupted else "FAILED")
        raise
    finally:
        if tracker is not None:  # the run id was this training's: the next one (train
            os.environ.pop(RUN_ID_ENV, None)  # --seeds 0,1) starts a run of its own
    record = {"key": key, "path": str(path), "run_id": run_id}  # weights: local (no "weights")
    if tracker is not None:
        _log_fit_summary(tracker, run_id, workdir)
    if _global_rank() == 0:
        tmp = workdir / "done.json.tmp"
        tmp.write_text(json.dumps(record))
        tmp.replace(workdir / "done.json")
        if tracker is not None:
            tracker.end(run_id)
    return record


#: The numbers of a fit's ``summary.json`` that a training run records as ``summary/<name>``.
SUMMARY_NUMBERS = ("wall_seconds", "device_hours", "training_shapes", "epochs", "optimizer_steps")


def _log_fit_summary(tracker: Tracker, run_id: str, workdir: Path) -> None:
    """The cost of a fit that did not log its own (one that is not a Lightning training, such as
    an index built from the data): the ``summary.json`` it left in its folder (see
    :class:`~shapebench.api.method.Method`), recorded on its training run as a Lightning training
    records its summary, so that the leaderboard's cost columns read it."""
    try:
        summary = json.loads((workdir / "summary.json").read_text())
    except (OSError, ValueError):
        return
    logged = tracker.run_summary(run_id)
    if not isinstance(summary, dict) or (logged and "summary/wall_seconds" in logged[0]):
        return  # none, or logged by the fit itself (Lightning's logger)
    metrics = {
        f"summary/{k}": float(summary[k])
        for k in SUMMARY_NUMBERS
        if isinstance(summary.get(k), (int, float))
    }
    tracker.log_metrics(run_id, metrics, step=int(summary.get("optimizer_steps", 0) or 0))
    if summary.get("device"):
        tracker.set_tags(run_id, {TRAINING_DEVICE_TAG: str(summary["device"])})


def _training_params(ticket: TrainingTicket) -> dict[str, Any]:
    return flatten(
        "",
        {
            "method": ticket.method.config(),
            "trainer": asdict(ticket.trainer),
            "training": ticket.identity,
            "dataset": ticket.dataset.config(),
        },
    )


def _reusable(record: dict[str, Any] | None, workdir: Path, retrain: bool) -> dict[str, Any] | None:
    """``record`` unless ``retrain`` asks to replace reference weights by a local training (the
    reference's copy is then removed)."""
    if record is not None and retrain and record.get("weights"):
        (workdir / "done.json").unlink(missing_ok=True)
        Path(record["path"]).unlink(missing_ok=True)
        return None
    return record


def _done_or_reference(ticket: TrainingTicket, settings: Settings) -> dict[str, Any] | None:
    """With the key's lock held: the record of a finished training (or install) of the ticket's
    key, else its shipped reference checkpoint installed (unless ``retrain``), else None (train
    it)."""
    record = _reusable(read_done(ticket.workdir), ticket.workdir, ticket.retrain)
    if record is not None:
        return record
    if ticket.retrain or ticket.reference is None:
        return None
    return _use_reference(ticket, settings)


def _use_reference(ticket: TrainingTicket, settings: Settings) -> dict[str, Any]:
    """Install the ticket's reference as the checkpoint of its key and log it as a training run
    (its cost and loss terms are those of the reference training); the caller holds the key's
    lock."""
    from shapebench.train.references import install

    reference, method, dataset = ticket.reference, ticket.method, ticket.dataset
    key, workdir = ticket.key, ticket.workdir

    info = reference.info
    summary = info.get("summary") or {}
    print(
        f"{method.name}: using the reference checkpoint for key {key} ({reference.folder}; "
        f"trained with '{info.get('command', '?')}' in {summary.get('wall_seconds', 0):.0f} s "
        f"on {summary.get('device', '?')}); --retrain trains it here instead",
        file=sys.stderr,
        flush=True,
    )
    path = install(reference, workdir)
    tracker = Tracker(settings)
    exp = tracker.experiment_id(training_experiment_name(dataset.name))
    device = str(summary.get("device", ""))
    tags = training_tags(method.name, dataset.name, key, reference=reference.origin, device=device)
    run_id = tracker.start_run(
        exp, f"reference {method.name} on {dataset.name} seed={ticket.seed}", tags
    )
    tracker.log_params(run_id, _training_params(ticket))
    metrics = {
        f"summary/{k}": float(summary[k])
        for k in ("wall_seconds", "device_hours", "training_shapes", "epochs", "optimizer_steps")
        if isinstance(summary.get(k), (int, float))
    }
    metrics.update(
        {
            f"summary/final_{k.removeprefix('train/')}": float(v)
            for k, v in (summary.get("final") or {}).items()
        }
    )
    tracker.log_metrics(run_id, metrics, step=int(summary.get("optimizer_steps", 0)))
    described = json.dumps(info, indent=1, sort_keys=True)
    tracker.set_note(
        run_id,
        "Reference checkpoint shipped with shapebench, not trained here."
        f"\n\n```json\n{described}\n```",
    )
    tracker.end(run_id)
    record = {"key": key, "path": str(path), "run_id": run_id, "weights": reference.origin}
    tmp = workdir / "done.json.tmp"
    tmp.write_text(json.dumps(record))
    tmp.replace(workdir / "done.json")
    return record


def ensure_checkpoint(
    ticket: TrainingTicket,
    settings: Settings,
    data_root: Path | None,
    quiet: bool = False,
) -> dict[str, Any]:
    """The weights of ``ticket``: the checkpoint of an identical training, else the shipped
    reference checkpoint of its key (unless ``retrain``), else a training in a child process."""
    from shapebench.store.locks import wait_lock

    method, dataset, trainer = ticket.method, ticket.dataset, ticket.trainer
    key, workdir, retrain = ticket.key, ticket.workdir, ticket.retrain
    record = _reusable(read_done(workdir), workdir, retrain)
    if record is not None:
        return record
    if not retrain and ticket.reference is not None:  # installed here, no child
        workdir.mkdir(parents=True, exist_ok=True)
        lock = wait_lock(lock_path(workdir), lambda holder: None)
        try:  # another process may have installed (or trained) it while we waited
            record = _done_or_reference(ticket, settings)
        finally:
            lock.release()
        if record is not None:
            return record
    cmd = [
        sys.executable,
        "-m",
        "shapebench",
        "train",
        "--method",
        method.name,
        "--dataset",
        dataset.name,
        "--profile",
        settings.profile_name,
        "--tracking-uri",
        settings.tracking_uri,
        "--cache-dir",
        str(settings.cache_dir),
        "--workspace",
        str(settings.artifact_root.parent),
    ]
    cmd += [a for k, v in asdict(method.options).items() for a in ("-O", f"{k}={json.dumps(v)}")]
    cmd += [a for k, v in asdict(dataset.options).items() for a in ("-D", f"{k}={json.dumps(v)}")]
    for k, v in asdict(trainer).items():
        if v is not None:
            cmd += [f"--{k.replace('_', '-')}", str(v)]
    if data_root:
        cmd += ["--data-root", str(data_root)]
    if quiet:
        cmd.append("--quiet")
    if retrain:
        cmd.append("--retrain")
    # Why a (possibly long) training starts now, before its own output.
    if (workdir / "last.ckpt").exists():
        why = f"the training of key {key} in {workdir.parent} is unfinished: resuming it"
    else:
        why = f"no checkpoint for key {key} in {workdir.parent}"
    print(
        f"training {method.name} on {dataset.name}: {why}",
        file=sys.stderr,
        flush=True,
    )
    env = {k: v for k, v in os.environ.items() if k != RUN_ID_ENV}
    # `python -m` would put the working directory first on sys.path: a checkout of shapebench in
    # it would then train with other code than this process evaluates with (and under another
    # key). PYTHONSAFEPATH (Python >= 3.11) keeps the child's imports those of this process.
    env["PYTHONSAFEPATH"] = "1"
    env[PARENT_ENV] = str(os.getpid())
    returncode = wait_child(subprocess.Popen(cmd, env=env, preexec_fn=die_with_parent()))
    record = read_done(workdir)
    if returncode == 0 and record is None:
        raise ShapebenchError(
            f"training {method.name} on {dataset.name} finished, but not under the checkpoint "
            f"key {key} this process expects: the training process resolved another "
            "configuration or imported other code",
            "run shapebench from a directory that does not hold another copy of shapebench, or "
            f"train alone: {' '.join(cmd[2:])}",
        )
    if returncode != 0 or record is None:
        raise ShapebenchError(
            f"training {method.name} on {dataset.name} failed (exit status {returncode})",
            f"run it alone to see the details: {' '.join(cmd[2:])}",
        )
    return record
