"""What identifies one training, and where its weights will come from: a :class:`TrainingTicket`.

A trainable method's weights are keyed by everything that changes them (:func:`checkpoint_key`:
the method's training options and code, the training data, and the trainer settings of
:func:`training_identity`, the seed among them). Planning a run computes, once per seed, the
method with its trainer's budget applied, that key, the key's folder in the workspace, the shipped
reference checkpoint of the key (:mod:`shapebench.train.references`) and so where the weights will
come from; the ticket carries them to the cells' keys, the leaderboard row and
:func:`shapebench.train.training.ensure_checkpoint`, which gets the weights without computing any
of it again.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from shapebench.api.dataset import Dataset
from shapebench.api.method import TrainerOptions
from shapebench.config import Settings
from shapebench.hashing import stable_hash
from shapebench.registry.resolve import ResolvedMethod

if TYPE_CHECKING:
    from shapebench.train.references import Reference

#: Where a ticket's weights come from: a shipped reference checkpoint (installed already, or to
#: install), a finished local training in the workspace, or a training still to run.
Origin = Literal["reference", "local", "train"]


def world_size(trainer: TrainerOptions) -> int:
    """How many processes train together (devices x nodes): with the per-device batch, it sets
    the effective batch size, so it changes the trained weights."""
    devices = str(trainer.devices).strip()
    if devices.isdigit():
        count = int(devices)
    elif "," in devices or devices.startswith("["):
        count = len([d for d in devices.strip("[]").split(",") if d.strip()])
    elif trainer.accelerator == "cpu":
        count = 1  # Lightning's "auto" devices on a CPU: one process
    else:
        import torch

        count = max(torch.cuda.device_count(), 1) if torch.cuda.is_available() else 1
    return max(count, 1) * max(int(trainer.num_nodes or 1), 1)


def training_identity(method: ResolvedMethod, trainer: TrainerOptions) -> dict[str, Any]:
    """The trainer settings that change the trained weights; the accelerator does not count
    (a checkpoint trained on a GPU serves a CPU evaluation). The budget is the method's epochs
    or, when it has a step budget, its optimiser steps (an epoch is 9 steps on 66 shapes and
    3,750 on 30,000: a step budget costs the same at any training-set size).

    Empty for a method whose fit no trainer setting changes (``fit_ignores_trainer``, see
    :class:`~shapebench.api.method.Method`: an index of the training data): its key is then the
    same for every seed and trainer, and its leaderboard row shows none of their settings."""
    if method.cls.fit_ignores_trainer:
        return {}
    identity: dict[str, Any] = {
        "epochs": trainer.max_epochs or getattr(method.options, "epochs", None),
        "precision": trainer.precision,
        "world_size": world_size(trainer),
        "seed": trainer.seed,
    }
    steps = step_budget(method, trainer)
    if steps:
        identity["steps"] = steps
    return identity


def step_budget(method: ResolvedMethod, trainer: TrainerOptions) -> int:
    """The optimiser steps a training runs, or 0 when it runs its epochs: ``--max-steps``, else
    the method's ``steps`` option unless ``--max-epochs`` asked for an epoch budget."""
    if trainer.max_steps:
        return int(trainer.max_steps)
    if trainer.max_epochs:
        return 0
    return int(getattr(method.options, "steps", 0) or 0)


def apply_trainer(method: ResolvedMethod, trainer: TrainerOptions) -> ResolvedMethod:
    """``--max-epochs`` and ``--max-steps`` become the method's ``epochs`` and ``steps``
    options when it has them, so the run's params, its leaderboard label and its key all show
    the budget really trained; ``--max-epochs`` alone ends the profile's step budget."""
    changes: dict[str, Any] = {}
    if trainer.max_epochs and hasattr(method.options, "epochs"):
        changes["epochs"] = trainer.max_epochs
    if hasattr(method.options, "steps") and (trainer.max_steps or trainer.max_epochs):
        changes["steps"] = step_budget(method, trainer)
    return method.with_options(**changes) if changes else method


def checkpoint_key(
    method: ResolvedMethod,
    dataset: Dataset,
    trainer: TrainerOptions,
    identity: dict[str, Any] | None = None,
) -> str:
    """Everything that changes the trained weights: the method's training options and code, the
    training data, and the trainer settings of :func:`training_identity` (the seed among them;
    none for a method whose fit ignores the trainer).
    ``identity``: that training identity, when the caller has computed it already."""
    return stable_hash(
        {
            "method": method.training_config(),
            "dataset": dataset.training_fingerprint(),
            "trainer": identity if identity is not None else training_identity(method, trainer),
        }
    )


def checkpoint_dir(settings: Settings, method: ResolvedMethod, key: str) -> Path:
    family = method.cls.checkpoint_family or method.name
    return settings.artifact_root.parent / "checkpoints" / family / key


def find_reference(method: ResolvedMethod, key: str) -> Reference | None:
    """The shipped reference checkpoint of ``method`` for ``key``, or None."""
    from shapebench.train.references import find

    return find(method.cls.checkpoint_family or method.name, key)


@dataclass(frozen=True)
class TrainingTicket:
    """One training: a method on a dataset with one trainer (seed included), as planning found
    it. Built by :func:`training_ticket`, once per seed; nothing downstream recomputes a field."""

    #: The method with the trainer's budget applied (:func:`apply_trainer`).
    method: ResolvedMethod
    dataset: Dataset
    trainer: TrainerOptions
    #: :func:`training_identity`: the trainer settings that change the weights.
    identity: dict[str, Any]
    #: :func:`checkpoint_key`.
    key: str
    #: The key's folder in the workspace (:func:`checkpoint_dir`).
    workdir: Path
    #: The shipped reference checkpoint of ``key``, whether or not it serves (``retrain``).
    reference: Reference | None
    #: Where the weights come from, as the workspace stood at planning.
    origin: Origin
    #: ``reference:<digest>`` when shipped weights serve (the workspace's install, or the
    #: reference to install): what cell keys record; None for a local training.
    weights: str | None
    #: ``--retrain``: train locally even where a reference of the key ships.
    retrain: bool = False

    @property
    def seed(self) -> int:
        return self.trainer.seed

    def cell_checkpoint(self) -> dict[str, Any]:
        """The checkpoint part of the cells' keys (:class:`shapebench.evaluation.plan.RunPlan`'s
        ``checkpoint``): a new dict, which the run completes with the training's run id."""
        checkpoint: dict[str, Any] = {"key": self.key, "training": self.identity}
        if self.weights:  # shipped weights are not those a local training would give
            checkpoint["weights"] = self.weights
        return checkpoint

    @property
    def row_weights(self) -> str | None:
        """What the leaderboard row records of the weights (``make_variant``'s ``weights``): the
        shipped ones, or ``local`` for a local training of a key that has shipped weights (a row
        beside the reference's: its label says so)."""
        if self.weights:
            return self.weights
        return "local" if self.reference is not None else None


def training_ticket(
    method: ResolvedMethod,
    dataset: Dataset,
    trainer: TrainerOptions,
    settings: Settings,
    retrain: bool = False,
) -> TrainingTicket:
    """The ticket of training ``method`` on ``dataset`` with ``trainer``: its key and folder, the
    shipped reference of the key and where the weights will come from, read before any training
    from the workspace's ``done.json``, else from that reference (unless ``retrain``)."""
    method = apply_trainer(method, trainer)
    identity = training_identity(method, trainer)
    key = checkpoint_key(method, dataset, trainer, identity)
    workdir = checkpoint_dir(settings, method, key)
    reference = find_reference(method, key)
    origin, weights = _origin(workdir, reference, retrain)
    return TrainingTicket(
        method, dataset, trainer, identity, key, workdir, reference, origin, weights, retrain
    )


def _origin(workdir: Path, reference: Reference | None, retrain: bool) -> tuple[Origin, str | None]:
    """Where the weights of ``workdir``'s key come (or will come) from, and the ``weights`` cells
    record. ``done.json`` is read, not checked: ``read_done`` checks it when the weights are
    needed (:func:`shapebench.train.training.ensure_checkpoint`)."""
    try:
        record = json.loads((workdir / "done.json").read_text())
    except (OSError, ValueError):
        pass
    else:
        weights = record.get("weights") if isinstance(record, dict) else None
        if not weights:
            return "local", None
        if not retrain:  # --retrain replaces installed reference weights by a local training
            return "reference", weights
    if reference is not None and not retrain:
        return "reference", reference.origin
    return "train", None
