"""What a cluster job runs, on the node: the callables that submitit pickles and a job unpickles.

:mod:`shapebench.sweeps.cluster` submits them from the login node (and reports on them). A
pickled job names its callable by this module's path (``shapebench.sweeps.jobs.CellsJob``, ...),
so a job imports this module, not the submission code. Each rebuilds the sweep from a
:class:`JobContext` exactly as the submitting process saw it:

- :class:`CellsJob` computes some cells of the sweep (one array task), and is requeued by
  submitit when pre-empted;
- :class:`TrainingJob` is one training, run by every rank ``srun`` starts; pre-empted, it writes
  ``last.ckpt`` and requeues its job (:func:`requeue_after`), which resumes from it;
- :class:`PrepareJob` is one shard of ``prepare --launcher slurm``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from shapebench.api.errors import ShapebenchError
from shapebench.config import Settings, make_settings
from shapebench.sweeps.plan import CellTask, TrainingTask

#: SLURM's pre-emption warning (``--signal=USR1@90``): also what Lightning listens to. submitit
#: reads this variable when imported, in the submitting process and in every job.
PREEMPT_SIGNAL = "USR1"


@dataclass
class JobContext:
    """What every job needs to rebuild the sweep exactly as the submitting process saw it."""

    sweep_file: str
    profile: str | None
    tracking_uri: str
    cache_dir: str
    workspace: str
    trainer: dict[str, Any]
    frame: str | None = None
    context_normals: bool | None = None
    per_job_store: bool = False
    threads: int | None = None
    #: ``shapebench sweep -m``: the method entries the submitting process kept (cells are
    #: addressed by their index among them)
    methods: tuple[str, ...] = ()
    #: ``shapebench sweep --seeds``: the run seeds the submitting process kept.
    seeds: tuple[int, ...] = ()
    #: ``shapebench sweep -D``: dataset options over every dataset entry's.
    dataset_options: dict[str, Any] = field(default_factory=dict)

    def settings(self) -> Settings:
        settings = make_settings(self.tracking_uri, self.cache_dir, self.profile, self.workspace)
        if self.per_job_store:
            store = Path(self.workspace) / "stores" / f"job-{job_id()}.db"
            store.parent.mkdir(parents=True, exist_ok=True)
            settings = replace(settings, tracking_uri=f"sqlite:///{store}")
        return settings

    def spec(self) -> Any:
        from shapebench.api.protocol import Protocol
        from shapebench.sweeps.spec import load_sweep, narrow_sweep

        spec = narrow_sweep(
            load_sweep(Path(self.sweep_file)), self.methods, self.seeds, self.dataset_options
        )
        if self.frame is not None or self.context_normals is not None:
            spec = replace(
                spec,
                protocol=Protocol(
                    context_normals=(
                        spec.protocol.context_normals
                        if self.context_normals is None
                        else self.context_normals
                    ),
                    frame=self.frame or spec.protocol.frame,
                ),
            )
        return spec

    def trainer_for_seed(self, settings: Settings) -> Callable[[int], Any]:
        from shapebench.train.training import trainer_options

        return lambda seed: trainer_options(settings, seed, **self.trainer)

    def start(self) -> None:
        if self.threads:
            from shapebench.sweeps.launchers import use_threads

            use_threads(self.threads)


def job_id() -> str:
    """This job's id: SLURM's (``<array>_<task>`` in an array), submitit's local one, or the pid."""
    if os.environ.get("SLURM_ARRAY_JOB_ID"):
        return f"{os.environ['SLURM_ARRAY_JOB_ID']}_{os.environ.get('SLURM_ARRAY_TASK_ID', 0)}"
    return (
        os.environ.get("SLURM_JOB_ID")
        or os.environ.get("SUBMITIT_LOCAL_JOB_ID")
        or str(os.getpid())
    )


class CellsJob:
    """A job computing some cells of the sweep, one after another (an array task)."""

    def __init__(self, ctx: JobContext, cells: list[CellTask]) -> None:
        self.ctx = ctx
        self.cells = cells

    def __call__(self) -> list[str]:
        from shapebench.evaluation.orchestrate import evaluate
        from shapebench.store.tracking import Tracker
        from shapebench.sweeps.spec import request, sweep_methods

        self.ctx.start()
        settings = self.ctx.settings()
        spec = self.ctx.spec()
        methods = sweep_methods(spec)
        tracker = Tracker(settings)
        done, failed = [], []
        for cell in self.cells:
            req = request(
                spec,
                methods[cell.method_index],
                spec.datasets[cell.dataset_index],
                quiet=True,
                splits=[cell.split],
                contexts=[cell.size],
                seeds=[cell.seed],
            )
            print(f"[shapebench] {cell.name} (cell key {cell.key})", flush=True)
            try:
                outcome = evaluate(req, settings, self.ctx.trainer_for_seed(settings), tracker)
            except ShapebenchError as exc:  # the job's other cells go on
                failed.append(f"{cell.name}: {exc.message}")
                print(f"[shapebench] failed: {exc.message}", file=sys.stderr, flush=True)
                continue
            done += [c.run_id for c in outcome.cells]
        if failed:
            raise ShapebenchError(
                f"{len(failed)} of {len(self.cells)} cells failed: " + "; ".join(failed)
            )
        return done

    def checkpoint(self) -> Any:
        """Pre-empted: submitit requeues the same cells; finished ones are skipped then."""
        import submitit

        return submitit.helpers.DelayedSubmission(CellsJob(self.ctx, self.cells))


class TrainingJob:
    """A training, run by every rank ``srun`` starts (Lightning reads the ranks from SLURM)."""

    def __init__(self, ctx: JobContext, task: TrainingTask) -> None:
        self.ctx = ctx
        self.task = task

    def __call__(self) -> str:
        from shapebench.evaluation.orchestrate import resolve_request
        from shapebench.sweeps.spec import request, sweep_methods
        from shapebench.train.callbacks import TrainingInterrupted
        from shapebench.train.ticket import training_ticket
        from shapebench.train.training import train_here

        self.ctx.start()
        settings = self.ctx.settings()
        spec = self.ctx.spec()
        entry = sweep_methods(spec)[self.task.method_index]
        dataset_entry = spec.datasets[self.task.dataset_index]
        resolved = resolve_request(request(spec, entry, dataset_entry, quiet=True), settings)
        trainer = self.ctx.trainer_for_seed(settings)(self.task.seed)
        ticket = training_ticket(resolved.method, resolved.dataset, trainer, settings)
        key = ticket.key
        if key != self.task.key:
            raise ShapebenchError(
                f"{self.task.name}: the job computes checkpoint key {key}, the sweep was planned "
                f"with {self.task.key}: the code, the sweep file or the data changed since "
                "submission",
                "resubmit the sweep",
            )
        try:
            record = train_here(ticket, settings, quiet=True)
        except TrainingInterrupted as exc:
            if exc.signal_name == f"SIG{PREEMPT_SIGNAL}":
                requeue_after(exc)
            raise
        return str(record["path"])


def requeue_after(exc: BaseException) -> None:
    """Pre-empted: rank 0 requeues this job (it resumes from the checkpoint just written), and
    the job ends without a result, as submitit's own requeue does."""
    rank = os.environ.get("SLURM_PROCID", "0")
    job = os.environ.get("SLURM_JOB_ID")
    if job and rank == "0":
        why = getattr(exc, "message", str(exc))
        print(f"[shapebench] pre-empted ({why}); requeueing job {job}", file=sys.stderr, flush=True)
        subprocess.run(["scontrol", "requeue", job], check=False, timeout=60)
    raise SystemExit(-1)


class PrepareJob:
    """One array task of ``prepare --launcher slurm``: every ``count``-th object from ``index``."""

    def __init__(self, req: Any, settings: Settings, index: int, count: int, jobs: int) -> None:
        self.req = req
        self.settings = settings
        self.shard = (index, count)
        self.jobs = jobs

    def __call__(self) -> list[str]:
        from shapebench.evaluation.prepare import prepare_request

        reports = prepare_request(self.req, self.settings, self.jobs, True, self.shard)
        lines = []
        for report in reports:
            lines.append(report.summary())
            lines += [f"  failed: {f.ref.id}: {f.reason}" for f in report.failures]
        return lines

    def checkpoint(self) -> Any:
        """Pre-empted: requeued; the objects already cached are read back, not rebuilt."""
        import submitit

        return submitit.helpers.DelayedSubmission(self)
