"""``shapebench sweep --launcher slurm|submitit-local`` and ``sweep --status``: plan, submit,
wait, report (the jobs themselves are in :mod:`shapebench.sweeps.cluster`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from shapebench.api.errors import ShapebenchError
from shapebench.config import Settings
from shapebench.sweeps.cluster import (
    JobContext,
    check_tracking,
    launcher_config,
    manifest_path,
    merge_job_stores,
    print_status,
    read_manifest,
    submit_plan,
    sweep_status,
    wait_for,
    write_manifest,
)
from shapebench.sweeps.plan import plan_sweep
from shapebench.sweeps.spec import SweepSpec, sweep_methods
from shapebench.train.training import trainer_options


def _trainer_for_seed(settings: Settings, given: dict[str, Any]):
    return lambda seed: trainer_options(settings, seed, **given)


def show_status(
    spec: SweepSpec,
    settings: Settings,
    given: dict[str, Any],
    overrides: dict[str, Any],
    launcher: str,
) -> None:
    """Print each cell's state; per-job stores are merged first, so finished means merged."""
    cfg = launcher_config(spec.launcher, overrides, launcher)
    if cfg.tracking == "per-job":
        merge_job_stores(settings, click.echo)
    plan = plan_sweep(spec, settings, _trainer_for_seed(settings, given))
    manifest = read_manifest(manifest_path(settings, spec.name))
    print_status(sweep_status(plan, settings, manifest), plan, click.echo)


def cluster_sweep(
    spec: SweepSpec,
    sweep_file: Path,
    settings: Settings,
    given: dict[str, Any],
    overrides: dict[str, Any],
    launcher: str,
    jobs: int,
    wait: bool,
    frame: str | None,
    context_normals: bool | None,
) -> None:
    """Submit the sweep's missing trainings and cells; submitit-local (or ``--wait``) waits for
    them, merges per-job stores and prints the status."""
    import os

    cfg = launcher_config(spec.launcher, overrides, launcher)
    check_tracking(cfg, settings)
    per_job = cfg.tracking == "per-job"
    if per_job:
        merge_job_stores(settings, click.echo)
    plan = plan_sweep(spec, settings, _trainer_for_seed(settings, given))
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
    threads = max(1, (os.cpu_count() or 1) // jobs) if local else cfg.cpus_per_task
    ctx = JobContext(
        sweep_file=str(sweep_file.absolute()),
        profile=settings.profile_name,
        tracking_uri=settings.tracking_uri,
        cache_dir=str(settings.cache_dir),
        workspace=str(settings.artifact_root.parent),
        trainer=given,
        frame=frame,
        context_normals=context_normals,
        per_job_store=per_job,
        threads=threads,
    )
    folder = settings.artifact_root.parent / "logs" / "submitit" / spec.name
    names = [m.name for m in sweep_methods(spec)]
    submitted = submit_plan(plan, ctx, cfg, names, folder, click.echo, jobs if local else 0)
    write_manifest(manifest_path(settings, spec.name), launcher, [s for s, _ in submitted])
    if not (local or wait):
        click.echo(f"submitted {len(submitted)} jobs; logs under {folder}")
        click.echo(f"follow with: shapebench sweep {sweep_file} --status")
        return
    click.echo(f"waiting for {len(submitted)} jobs (Ctrl-C stops waiting, not the jobs)")
    failed = wait_for([job for _, job in submitted], click.echo)
    if per_job:
        merge_job_stores(settings, click.echo)
    plan = plan_sweep(spec, settings, _trainer_for_seed(settings, given))
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
    if req.splits:
        data["splits"] = list(req.splits)
    if req.metrics:
        data["metrics"] = list(req.metrics)
    name = f"run-{req.method}-{req.dataset}-{stable_hash(data)[:8]}"
    path = settings.artifact_root.parent / "sweeps" / f"{name}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump({"name": name, **data}, sort_keys=False))
    return path
