"""``shapebench prepare``: preprocess a dataset ahead of a run, in parallel."""

from __future__ import annotations

import click

from shapebench.api.errors import ShapebenchError
from shapebench.cli.app import (
    _parse,
    _settings,
    cli,
    plugin_options,
    store_options,
)


@cli.command()
@click.option("--dataset", "-d", required=True, help="Dataset to preprocess.")
@click.option(
    "--split",
    "splits",
    default=None,
    help="Comma-separated splits [default: the dataset's evaluation splits].",
)
@click.option("--categories", default=None, help="Comma-separated categories to prepare only.")
@click.option(
    "--method",
    "-m",
    "methods",
    multiple=True,
    help="Also prepare the train split with what METHOD needs (repeatable).",
)
@click.option(
    "--jobs",
    "-j",
    default=1,
    show_default=True,
    help="Parallel worker processes (per array task on a cluster).",
)
@click.option(
    "--launcher",
    type=click.Choice(["inline", "slurm", "submitit-local"]),
    default="inline",
    show_default=True,
    help="slurm: an array of --shards jobs through submitit, each preparing every "
    "n-th object; submitit-local: the same jobs on this machine.",
)
@click.option(
    "--shards", type=int, default=8, show_default=True, help="Array tasks of a cluster launcher."
)
@click.option(
    "--slurm",
    "slurm_opts",
    multiple=True,
    metavar="KEY=VALUE",
    help="SLURM settings (partition=..., time=..., cpus_per_task=...), as in a sweep "
    "file's launcher block.",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress bar.")
@plugin_options
@store_options
def prepare(
    dataset,
    splits,
    categories,
    methods,
    jobs,
    launcher,
    shards,
    slurm_opts,
    quiet,
    method_opts,
    dataset_opts,
    data_root,
    profile,
    tracking_uri,
    cache_dir,
    workspace,
) -> None:
    """Preprocess DATASET ahead of time (the paper's §4.1), with parallel workers.

    Results are cached per object, so an interrupted prepare resumes; 'run' prepares whatever
    is missing by itself. Objects that cannot be processed are listed with the reason and
    skipped. On a cluster, --launcher slurm shards the objects over an array of jobs (the
    cache folder must be on a filesystem the nodes share); the command waits for them.

    \b
    Examples:
      shapebench prepare -d shapenet --data-root ~/data/ShapeNetCore.v2 --jobs 2
      shapebench prepare -d shapenet --categories chair,table -m deepsdf
      shapebench prepare -d shapenet --data-root /shared/ShapeNetCore.v2 --launcher slurm \\
          --shards 64 --slurm partition=cpu --slurm time=60
    """
    from shapebench.evaluation.prepare import PrepareRequest, prepare_request

    settings = _settings(profile, tracking_uri, cache_dir, workspace)
    req = PrepareRequest(
        dataset,
        splits.split(",") if splits else None,
        categories.split(",") if categories else None,
        list(methods),
        _parse(method_opts, "-O"),
        _parse(dataset_opts, "-D"),
        data_root,
    )
    if launcher != "inline":
        from shapebench.sweeps.cluster import prepare_on_cluster

        failed = prepare_on_cluster(
            req, settings, launcher, shards, jobs, _parse(slurm_opts, "--slurm"), click.echo
        )
        if failed:
            raise ShapebenchError(
                f"{failed} of {shards} prepare jobs failed",
                "see the logs above; rerun to finish the rest",
            )
        return
    for report in prepare_request(req, settings, jobs, quiet):
        click.echo(report.summary())
        for failure in report.failures:
            click.secho(f"  failed: {failure.ref.id}: {failure.reason}", fg="yellow")
