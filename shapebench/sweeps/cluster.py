"""Running a sweep as cluster jobs through submitit (``--launcher slurm``, ``submitit-local``):
the login side, which submits the jobs and waits for them. What a job runs on its node is in
:mod:`shapebench.sweeps.jobs`, where a submitted sweep stands (``--status``) in
:mod:`shapebench.sweeps.status`.

The sweep is planned first (:mod:`shapebench.sweeps.plan`): only the cells that have no finished
run, and the trainings they need, are submitted, so resubmitting an interrupted sweep submits
exactly what is missing.

- **A training is one job**: ``nodes`` = the trainer's ``--num-nodes`` and ``ntasks_per_node`` =
  its ``--devices``, so ``srun`` starts one process per rank and Lightning's SLURM environment
  sees the right world size. Its checkpoint key (and so the key of every cell evaluating it) is
  the same as on a laptop with those trainer settings.
- **Cells form job arrays** (``cells_per_job`` cells per array task, at most
  ``array_parallelism`` tasks at once); an array whose cells need a training depends on that
  training's job (``afterok``, and SLURM cancels the array if the training fails).
- **Pre-emption**: SLURM sends SIGUSR1 ``signal_delay_s`` before a job's end (submitit's
  ``--signal``). A training stops after its optimiser step, writes ``last.ckpt`` and requeues
  its job (:func:`shapebench.sweeps.jobs.requeue_after`), which resumes from it; a cell job is
  requeued by submitit and recomputes its unfinished cells.
- **Tracking**: jobs on many nodes must not share one SQLite file, so a slurm sweep needs an
  MLflow server (``--tracking-uri http://...``) or ``tracking: per-job``: every job logs to
  ``<workspace>/stores/job-<id>.db``, and ``sweep --status``, ``--wait`` and ``shapebench merge``
  import the finished runs into the main store (idempotent, by cell key).

``submitit-local`` runs the same jobs as processes on this machine (submitit's local executor),
without dependencies (trainings are waited for before their cells are submitted): a way to
check a cluster setup, and how the suite tests this module.

The job classes are imported here from :mod:`~shapebench.sweeps.jobs`: a job pickled when they
lived in this module names them here, and still resolves when it is requeued after an upgrade.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, get_args, get_type_hints

from shapebench.api.errors import ConfigError, ShapebenchError
from shapebench.api.options import check_value, suggest, type_name
from shapebench.config import Settings
from shapebench.sweeps.jobs import PREEMPT_SIGNAL, CellsJob, JobContext, PrepareJob, TrainingJob
from shapebench.sweeps.plan import CellTask, SweepPlan
from shapebench.sweeps.status import job_state, slurm_queue

CLUSTER_LAUNCHERS = ("slurm", "submitit-local")


@dataclass
class LauncherConfig:
    """The ``launcher:`` block of a sweep file (and ``--slurm KEY=VALUE`` on the command line).

    ``methods`` maps a method name to overrides of any other key for that method's jobs, like
    benchopt's ``slurm_params``; ``extra`` holds sbatch options submitit has no name for.
    """

    name: str = "inline"
    partition: str | None = None
    time: int = 60  # minutes per job
    gpus_per_node: int = 0
    cpus_per_task: int = 1
    mem_gb: float | None = None
    account: str | None = None
    qos: str | None = None
    constraint: str | None = None
    array_parallelism: int = 32
    cells_per_job: int = 1
    signal_delay_s: int = 90
    tracking: str = "server"  # or "per-job"
    setup: list[str] = field(default_factory=list)  # shell lines run before the job (module load)
    extra: dict[str, Any] = field(default_factory=dict)
    methods: dict[str, dict[str, Any]] = field(default_factory=dict)

    def for_method(self, name: str) -> LauncherConfig:
        return _apply(self, self.methods.get(name, {}), f"launcher.methods.{name}")


def _apply(cfg: LauncherConfig, values: dict[str, Any], where: str) -> LauncherConfig:
    """``cfg`` with ``values`` (a launcher block, ``--slurm`` values or a method's overrides),
    each checked against its field's type: a list or a bool where a number belongs (``time:
    [1]``, ``gpus_per_node: true``) is refused naming the key, never handed to submitit. Numbers
    given as text (``"30"``) are read as numbers; the other values are kept as given (``mem_gb:
    16`` stays ``16GB``, not ``16.0GB``). A method's overrides under ``methods`` are checked
    here too, before any job is submitted."""
    known = {f.name: f for f in fields(LauncherConfig)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ConfigError(
            f"{where}: unknown launcher keys {unknown}: "
            + ", ".join(suggest(k, known) for k in unknown),
            f"known keys: {', '.join(sorted(known))}",
        )
    hints = get_type_hints(LauncherConfig)
    out = {}
    for key, value in values.items():
        value = _number(value, hints[key], f"{where}: {key}")
        out[key] = check_value(value, hints[key], f"{where}: {key}", convert=False)
    for name, block in out.get("methods", {}).items():
        if "methods" in block:
            raise ConfigError(f"{where}.methods.{name}: a method's overrides hold no 'methods'")
        _apply(cfg, block, f"{where}.methods.{name}")
    return replace(cfg, **out)


def _number(value: Any, annotation: Any, label: str) -> Any:
    """``value`` read as a number when it is text for a number field (``--slurm time=30`` from
    Python, ``time: "30"`` in YAML); anything else unchanged, for :func:`check_value`."""
    accepted = set(get_args(annotation)) or {annotation}
    if not isinstance(value, str) or not accepted & {int, float} or str in accepted:
        return value
    try:
        return int(value)
    except ValueError:
        pass
    if float in accepted:
        try:
            return float(value)
        except ValueError:
            pass
    raise ConfigError(
        f"{label} must be a number ({type_name(annotation)}), got {value!r}"
    ) from None


def launcher_config(
    block: dict[str, Any], overrides: dict[str, Any], name: str | None
) -> LauncherConfig:
    """The sweep file's block, then the command line's ``--slurm`` values and ``--launcher``."""
    cfg = _apply(LauncherConfig(), block, "launcher")
    cfg = _apply(cfg, overrides, "--slurm")
    if name is not None:
        cfg = replace(cfg, name=name)
    if cfg.tracking not in ("server", "per-job"):
        raise ConfigError(f"launcher.tracking must be 'server' or 'per-job', got {cfg.tracking!r}")
    if cfg.cells_per_job < 1 or cfg.array_parallelism < 1:
        raise ConfigError("launcher.cells_per_job and array_parallelism must be at least 1")
    return cfg


def check_tracking(cfg: LauncherConfig, settings: Settings) -> None:
    """Refuse one SQLite store written by jobs on several nodes (it corrupts over NFS)."""
    if cfg.name == "slurm" and not settings.is_remote and cfg.tracking != "per-job":
        raise ShapebenchError(
            "a slurm sweep cannot log every job to one SQLite file "
            f"({settings.tracking_uri}): SQLite over a network filesystem corrupts",
            "start an MLflow server the nodes can reach and pass --tracking-uri http://HOST:PORT, "
            "or add 'tracking: per-job' to the launcher block (each job logs to its own store "
            "under the workspace's stores/, merged by 'sweep --status', '--wait' or "
            "'shapebench merge')",
        )


# --------------------------------------------------------------------------------- submission


@dataclass
class Submitted:
    """One submitted job, as the sweep's manifest records it."""

    job_id: str
    kind: str  # "training" or "cells"
    keys: list[str]  # the cell keys, or the checkpoint key
    names: list[str]
    stdout: str
    stderr: str
    depends_on: str | None = None


def manifest_path(settings: Settings, sweep_name: str) -> Path:
    return settings.artifact_root.parent / "sweeps" / f"{sweep_name}.jsonl"


def _submitit() -> Any:
    """The submitit module, or one clear line saying how to install it (an optional extra)."""
    try:
        import submitit
    except ImportError as exc:
        raise ShapebenchError(
            "the slurm and submitit-local launchers need submitit, which is not installed",
            hint="pip install 'shapebench[cluster]'",
        ) from exc
    return submitit


def _executor(cfg: LauncherConfig, folder: Path, ranks: int = 1, nodes: int = 1) -> Any:
    os.environ.setdefault("SUBMITIT_PREEMPT_SIGNAL", PREEMPT_SIGNAL)
    submitit = _submitit()

    if cfg.name == "submitit-local":
        executor = submitit.LocalExecutor(folder=str(folder))
        # Lightning launches the ranks of a local training itself, as inline.
        executor.update_parameters(timeout_min=cfg.time, tasks_per_node=1)
        return executor
    executor = submitit.SlurmExecutor(folder=str(folder))
    params: dict[str, Any] = dict(
        time=cfg.time,
        nodes=nodes,
        ntasks_per_node=ranks,
        cpus_per_task=cfg.cpus_per_task,
        array_parallelism=cfg.array_parallelism,
        signal_delay_s=cfg.signal_delay_s,
        job_name="shapebench",
        setup=list(cfg.setup),
        additional_parameters=dict(cfg.extra),
    )
    for key in ("partition", "account", "qos", "constraint"):
        if getattr(cfg, key):
            params[key] = getattr(cfg, key)
    if cfg.gpus_per_node:
        params["gpus_per_node"] = cfg.gpus_per_node
    if cfg.mem_gb:
        params["mem"] = f"{cfg.mem_gb}GB"
    executor.update_parameters(**params)
    return executor


def _ranks(trainer: dict[str, Any]) -> tuple[int, int]:
    """(tasks per node, nodes) of a training job: one SLURM task per Lightning rank."""
    devices = str(trainer.get("devices") or "1")
    per_node = int(devices) if devices.isdigit() else len([d for d in devices.split(",") if d])
    return max(per_node, 1), max(int(trainer.get("num_nodes") or 1), 1)


def submit_plan(
    plan: SweepPlan,
    ctx: JobContext,
    cfg: LauncherConfig,
    method_names: list[str],
    folder: Path,
    echo: Callable[[str], None],
    jobs: int = 0,
) -> list[tuple[Submitted, Any]]:
    """Submit the plan's missing trainings, then its missing cells in arrays that depend on
    them; ``jobs`` (submitit-local) caps the number of cell jobs at once. Returns each job's
    record and its submitit job."""
    folder.mkdir(parents=True, exist_ok=True)
    out: list[tuple[Submitted, Any]] = []
    training_jobs: dict[str, Any] = {}
    ranks, nodes = _ranks(ctx.trainer) if cfg.name == "slurm" else (1, 1)
    for task in plan.trainings:
        mcfg = cfg.for_method(method_names[task.method_index])
        executor = _executor(mcfg, folder, ranks, nodes)
        job = executor.submit(TrainingJob(ctx, task))
        training_jobs[task.key] = job
        out.append((_record(job, "training", [task.key], [task.name]), job))
        echo(f"  job {job.job_id}: {task.name} ({ranks * nodes} ranks)")
    if cfg.name == "submitit-local" and training_jobs:
        # No dependencies between local jobs: train first, then submit the cells.
        echo(f"  waiting for {len(training_jobs)} training job(s)")
        for key, job in training_jobs.items():
            try:
                job.result()
            except Exception as exc:  # its cells fail below, naming the training
                echo(f"  training {key} failed: {str(exc).strip().splitlines()[-1]}")
        training_jobs = {}
    groups: dict[tuple[str | None, int], list[CellTask]] = {}
    for cell in plan.missing:
        groups.setdefault((cell.training, cell.method_index), []).append(cell)
    for (training, mi), cells in groups.items():
        mcfg = cfg.for_method(method_names[mi])
        per_job = mcfg.cells_per_job
        if jobs:
            per_job = max(per_job, math.ceil(len(plan.missing) / jobs))
        chunks = [cells[i : i + per_job] for i in range(0, len(cells), per_job)]
        executor = _executor(mcfg, folder)
        depends = training_jobs.get(training) if training else None
        if depends is not None:
            # afterok, and a failed training cancels its cells instead of leaving them queued.
            extra = {**mcfg.extra, "kill_on_invalid_dep": "yes"}
            executor.update_parameters(
                dependency=f"afterok:{depends.job_id}", additional_parameters=extra
            )
        with executor.batch():
            submitted = [executor.submit(CellsJob(ctx, chunk)) for chunk in chunks]
        for job, chunk in zip(submitted, chunks, strict=True):
            record = _record(
                job,
                "cells",
                [c.key for c in chunk],
                [c.name for c in chunk],
                depends.job_id if depends is not None else None,
            )
            out.append((record, job))
        first = submitted[0].job_id if submitted else "-"
        after = f", after job {depends.job_id}" if depends is not None else ""
        echo(
            f"  {len(submitted)} job(s) from {first}: {len(cells)} cells of "
            f"{cells[0].label} on {cells[0].dataset}{after}"
        )
    return out


def _record(
    job: Any, kind: str, keys: list[str], names: list[str], depends: str | None = None
) -> Submitted:
    return Submitted(
        str(job.job_id), kind, keys, names, str(job.paths.stdout), str(job.paths.stderr), depends
    )


def write_manifest(path: Path, launcher: str, jobs: list[Submitted]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as f:
        stamp = time.strftime("%Y-%m-%dT%H:%M:%S")
        for job in jobs:
            f.write(json.dumps({"submitted": stamp, "launcher": launcher, **asdict(job)}) + "\n")


def read_manifest(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:  # a line cut by a kill: the jobs before it still count
            continue
    return out


def wait_for(jobs: list[Any], echo: Callable[[str], None], poll: float = 2.0) -> int:
    """Wait for submitit jobs; the number that failed (each printed with its log).

    A SLURM job has ended when it left the queue (``squeue``): this needs no accounting database
    (``sacct``, which submitit's own watcher asks, is missing on many small clusters)."""
    failed = 0
    pending = list(jobs)
    while pending:
        # Local jobs answer done() themselves: ask SLURM only when some job is SLURM's.
        local = all(type(job).__name__ == "LocalJob" for job in pending)
        queue = {} if local else slurm_queue()
        still = []
        for job in pending:
            if type(job).__name__ == "LocalJob":
                running = not job.done()
            else:
                running = _in_queue(str(job.job_id), queue) and not job.paths.result_pickle.exists()
            if running:
                still.append(job)
                continue
            error = _job_error(job)
            if error:
                failed += 1
                echo(f"  job {job.job_id} failed: {error}; log: {job.paths.stderr}")
        pending = still
        if pending:
            time.sleep(poll)
    return failed


def _in_queue(jid: str, queue: dict[str, str]) -> bool:
    return job_state({"job_id": jid, "launcher": "slurm"}, queue) != "ended"


def _job_error(job: Any) -> str | None:
    """Why an ended job failed, or None if it succeeded."""
    if not job.paths.result_pickle.exists():
        return "ended without a result (cancelled, killed, out of memory or out of time)"
    try:
        job.results()  # every task's result (a training job has one task per rank)
    except Exception as exc:
        lines = [ln for ln in str(exc).strip().splitlines() if ln.strip()]
        return lines[-1] if lines else repr(exc)
    return None


def per_job_stores(settings: Settings) -> list[Path]:
    return sorted((settings.artifact_root.parent / "stores").glob("job-*.db"))


def merge_job_stores(settings: Settings, echo: Callable[[str], None]) -> None:
    """Import the finished runs of the per-job stores into the main store (idempotent)."""
    from shapebench.store.merge import merge_stores

    stores = per_job_stores(settings)
    if stores:
        report = merge_stores([str(s) for s in stores], settings.tracking_uri, lambda _: None)
        echo(f"merged {len(stores)} per-job stores: {report.line()}")


# ------------------------------------------------------------------------------------- prepare


def prepare_on_cluster(
    req: Any,
    settings: Settings,
    launcher: str,
    shards: int,
    jobs: int,
    overrides: dict[str, Any],
    echo: Callable[[str], None],
) -> int:
    """Prepare ``req`` as an array of ``shards`` jobs and wait for them; the number that failed."""
    if shards < 1:
        raise ShapebenchError(f"--shards must be at least 1, got {shards}")
    cfg = launcher_config({}, overrides, launcher)
    folder = settings.artifact_root.parent / "logs" / "submitit" / f"prepare-{req.dataset}"
    folder.mkdir(parents=True, exist_ok=True)
    executor = _executor(cfg, folder)
    with executor.batch():
        submitted = [
            executor.submit(PrepareJob(req, settings, i, shards, jobs)) for i in range(shards)
        ]
    echo(f"{shards} prepare jobs from {submitted[0].job_id}; logs under {folder}")
    failed = wait_for(submitted, echo)
    for job in submitted:
        if job.paths.result_pickle.exists() and not _job_error(job):
            for line in job.results()[0]:
                echo(f"[{job.job_id}] {line}")
    return failed
