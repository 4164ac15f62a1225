"""Launching a sweep: :class:`SweepLaunch` is one ``shapebench sweep`` (or ``run --launcher``)
as plain data; :func:`start_sweep` submits it as cluster jobs or runs its local worker
processes, :func:`run_inline` computes what is left in this process, :func:`show_status` reports
(submitting the jobs is :mod:`shapebench.sweeps.cluster`, the jobs themselves
:mod:`shapebench.sweeps.jobs`, their status :mod:`shapebench.sweeps.status`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import click

from shapebench.api.errors import ShapebenchError
from shapebench.config import Settings
from shapebench.sweeps.cluster import (
    check_tracking,
    launcher_config,
    manifest_path,
    merge_job_stores,
    read_manifest,
    submit_plan,
    wait_for,
    write_manifest,
)
from shapebench.sweeps.jobs import JobContext
from shapebench.sweeps.launchers import run_local, threads_per_worker, use_threads
from shapebench.sweeps.plan import plan_sweep
from shapebench.sweeps.spec import SweepSpec, sweep_methods
from shapebench.sweeps.status import print_status, sweep_status
from shapebench.train.training import trainer_options

#: Launchers that submit jobs through submitit.
CLUSTER_LAUNCHERS = ("slurm", "submitit-local")


@dataclass(frozen=True)
class SweepLaunch:
    """One sweep to launch, as the command line (or a Python caller) gives it."""

    spec: SweepSpec
    sweep_file: Path
    settings: Settings
    #: inline, local, slurm or submitit-local.
    launcher: str = "inline"
    #: Worker processes (local), jobs at once (submitit-local).
    jobs: int = 1
    #: Torch threads of each worker, job or (inline) this process; None: the cores shared
    #: between the workers (local, submitit-local), ``cpus_per_task`` (slurm), torch's default
    #: (inline).
    threads: int | None = None
    #: Trainer options given explicitly (``--devices 1``...), the rest from the profile.
    trainer: dict[str, Any] = field(default_factory=dict)
    #: Keys of the sweep file's launcher block overridden (``--slurm KEY=VALUE``).
    overrides: dict[str, Any] = field(default_factory=dict)
    force: bool = False
    retrain: bool = False
    quiet: bool = False
    #: With slurm: wait for the jobs to end.
    wait: bool = False
    #: Cells to skip before this worker's first (local workers start at different cells).
    worker: int = 0
    #: Protocol given on the command line (jobs pass it on); None: the sweep file's.
    frame: str | None = None
    context_normals: bool | None = None
    #: ``-m``: the method entries kept (``spec`` is already narrowed; jobs narrow it again).
    methods: tuple[str, ...] = ()
    #: ``--seeds``: the run seeds kept (``spec`` is already narrowed; jobs narrow it again).
    seeds: tuple[int, ...] = ()
    #: ``-D``: dataset options over every dataset entry's (``spec`` has them; jobs add them again).
    dataset_options: dict[str, Any] = field(default_factory=dict)

    def trainer_for_seed(self) -> Callable[[int], Any]:
        return lambda seed: trainer_options(self.settings, seed, **self.trainer)


def start_sweep(launch: SweepLaunch, worker_argv: list[str]) -> bool:
    """Hand ``launch`` to its launcher: submit it as cluster jobs (False: nothing is left to do
    here), or run the local worker processes to the end (``worker_argv``: the ``sweep``
    arguments they are started with). True when the caller computes the remaining cells inline,
    with :func:`run_inline` (for the inline launcher: every cell)."""
    if launch.threads is not None and launch.threads < 1:
        raise ShapebenchError(
            f"--threads must be at least 1, got {launch.threads}",
            "leave it out to share the cores between the workers",
        )
    if launch.launcher in CLUSTER_LAUNCHERS:
        if launch.force or launch.retrain:
            raise ShapebenchError(
                "--force and --retrain cannot be split between jobs",
                "run such a sweep with --launcher inline",
            )
        cluster_sweep(launch)
        return False
    if launch.launcher == "local":
        if launch.force or launch.retrain:
            raise ShapebenchError(
                "--force and --retrain cannot be split between workers",
                "run such a sweep with --launcher inline",
            )
        if launch.jobs < 1:
            raise ShapebenchError(f"--jobs must be at least 1, got {launch.jobs}")
        log_dir = launch.settings.artifact_root.parent / "logs"
        if run_local(worker_argv, launch.jobs, log_dir, click.echo, launch.threads):
            click.secho("some workers failed; computing what they left here", fg="yellow")
    return True


def run_inline(
    launch: SweepLaunch, on_error: Callable[[str, str, ShapebenchError], None]
) -> Iterator[Any]:
    """Compute the sweep's cells in this process, yielding each method x dataset outcome
    (:class:`shapebench.evaluation.orchestrate.EvalOutcome`) as it finishes; ``on_error`` hears of
    a method or dataset that cannot run (the rest of the sweep goes on)."""
    from shapebench.sweeps.spec import run_sweep

    if launch.threads is not None:
        use_threads(launch.threads)
    yield from run_sweep(
        launch.spec,
        launch.settings,
        launch.force,
        launch.quiet,
        launch.trainer_for_seed(),
        on_error,
        offset=launch.worker,
        retrain=launch.retrain,
    )


def show_status(launch: SweepLaunch) -> None:
    """Print each cell's state; per-job stores are merged first, so finished means merged."""
    spec, settings = launch.spec, launch.settings
    cfg = launcher_config(spec.launcher, launch.overrides, launch.launcher)
    if cfg.tracking == "per-job":
        merge_job_stores(settings, click.echo)
    plan = plan_sweep(spec, settings, launch.trainer_for_seed())
    manifest = read_manifest(manifest_path(settings, spec.name))
    print_status(sweep_status(plan, settings, manifest), plan, click.echo)


def cluster_sweep(launch: SweepLaunch) -> None:
    """Submit the sweep's missing trainings and cells; submitit-local (or ``--wait``) waits for
    them, merges per-job stores and prints the status."""
    spec, settings, launcher, jobs = launch.spec, launch.settings, launch.launcher, launch.jobs
    sweep_file, given = launch.sweep_file, launch.trainer

    cfg = launcher_config(spec.launcher, launch.overrides, launcher)
    check_tracking(cfg, settings)
    per_job = cfg.tracking == "per-job"
    if per_job:
        merge_job_stores(settings, click.echo)
    plan = plan_sweep(spec, settings, launch.trainer_for_seed())
    missing = plan.missing
    click.echo(
        f"sweep {spec.name}: {len(plan.cells)} cells, {len(plan.finished)} finished, "
        f"{len(missing)} to submit, {len(plan.trainings)} trainings to submit"
    )
    for error in plan.errors:
        click.secho(f"  cannot run: {error}", fg="red", err=True)
    if not missing:
        click.echo("nothing to submit")
        return
    local = launcher == "submitit-local"
    if local and jobs < 1:
        raise ShapebenchError(f"--jobs must be at least 1, got {jobs}")
    threads = (
        threads_per_worker(jobs, launch.threads) if local else (launch.threads or cfg.cpus_per_task)
    )
    ctx = JobContext(
        sweep_file=str(sweep_file.absolute()),
        profile=settings.profile_name,
        tracking_uri=settings.tracking_uri,
        cache_dir=str(settings.cache_dir),
        workspace=str(settings.artifact_root.parent),
        trainer=given,
        frame=launch.frame,
        context_normals=launch.context_normals,
        per_job_store=per_job,
        threads=threads,
        methods=launch.methods,
        seeds=launch.seeds,
        dataset_options=launch.dataset_options,
    )
    folder = settings.artifact_root.parent / "logs" / "submitit" / spec.name
    names = [m.name for m in sweep_methods(spec)]
    submitted = submit_plan(plan, ctx, cfg, names, folder, click.echo, jobs if local else 0)
    write_manifest(manifest_path(settings, spec.name), launcher, [s for s, _ in submitted])
    if not (local or launch.wait):
        click.echo(f"submitted {len(submitted)} jobs; logs under {folder}")
        click.echo(f"follow with: shapebench sweep {sweep_file} --status")
        return
    click.echo(f"waiting for {len(submitted)} jobs (Ctrl-C stops waiting, not the jobs)")
    failed = wait_for([job for _, job in submitted], click.echo)
    if per_job:
        merge_job_stores(settings, click.echo)
    plan = plan_sweep(spec, settings, launch.trainer_for_seed())
    print_status(
        sweep_status(plan, settings, read_manifest(manifest_path(settings, spec.name))),
        plan,
        click.echo,
    )
    if failed or plan.missing:
        raise ShapebenchError(
            f"{failed} jobs failed, {len(plan.missing)} cells are missing",
            "see the logs above; rerun the same command to resubmit only what is missing",
        )


def run_as_sweep(req: Any, settings: Settings) -> Path:
    """``shapebench run`` on a cluster: the same request written as a sweep file of one method
    (under the workspace's sweeps/, named by its content), so that jobs rebuild it exactly."""
    import yaml

    from shapebench.hashing import stable_hash

    method: dict[str, Any] = {"name": req.method, "options": dict(req.method_opts)}
    if req.label:
        method["label"] = req.label
    dataset: dict[str, Any] = {"name": req.dataset, "options": dict(req.dataset_opts)}
    if req.data_root:
        dataset["data_root"] = str(Path(req.data_root).absolute())
    data: dict[str, Any] = {
        "profile": settings.profile_name,
        "methods": [method],
        "datasets": [dataset],
        "contexts": list(req.contexts),
        "seeds": list(req.seeds),
        "frame": req.protocol.frame,
        "context_normals": req.protocol.context_normals,
    }
    if not req.protocol.is_default_context:
        data["protocol"] = req.protocol.context
        if req.protocol.context == "crop":
            data["crop_fraction"] = req.protocol.crop_fraction
        if req.protocol.context_noise:
            data["context_noise"] = req.protocol.context_noise
    if req.splits:
        data["splits"] = list(req.splits)
    if req.metrics:
        data["metrics"] = list(req.metrics)
    name = f"run-{req.method}-{req.dataset}-{stable_hash(data)[:8]}"
    path = settings.artifact_root.parent / "sweeps" / f"{name}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump({"name": name, **data}, sort_keys=False))
    return path
