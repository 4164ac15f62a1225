"""``shapebench run``, ``sweep`` and ``train``: evaluate methods and train them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from shapebench.api.errors import ShapebenchError
from shapebench.cli.app import (
    DEFAULT_CONTEXTS,
    _argv_after,
    _exit_if_all_failed,
    _int_list,
    _parse,
    _protocol,
    _settings,
    _trainer,
    cli,
    context_options,
    plugin_options,
    protocol_options,
    store_options,
    trainer_options,
)


@cli.command()
@click.option("--method", "-m", required=True, help="Method name (see 'shapebench methods').")
@click.option("--dataset", "-d", required=True, help="Dataset name (see 'shapebench datasets').")
@click.option(
    "--split",
    "splits",
    default=None,
    help="Comma-separated evaluation splits [default: trained,novel].",
)
@click.option(
    "--contexts", default=DEFAULT_CONTEXTS, show_default=True, help="Comma-separated context sizes."
)
@click.option("--seeds", default="0", show_default=True, help="Comma-separated run seeds.")
@click.option(
    "--metric",
    "metrics",
    multiple=True,
    help="Metric to compute, or a preset of the field's conventions (pcn, convonet, mvp, "
    "paper); repeatable [default: every metric computed by default].",
)
@click.option(
    "--checkpoint",
    type=click.Path(exists=True),
    default=None,
    help="Use this checkpoint instead of training (trainable methods). Its rows are keyed by "
    "the file's sha256, so a copy of it anywhere reuses them; a shipped reference is named "
    "by its family and key.",
)
@click.option(
    "--samples",
    type=int,
    default=None,
    metavar="K",
    help="Also draw K shapes from the posterior (methods with one, e.g. msc); they are logged "
    "with a per-point spread.",
)
@click.option("--force", is_flag=True, help="Recompute cells that already have a finished run.")
@click.option(
    "--retrain",
    is_flag=True,
    help="Train locally even where shapebench ships a reference checkpoint of the "
    "same key (the rows are then labelled weights=local).",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress bars; only the summary.")
@click.option(
    "--label",
    default=None,
    help="Leaderboard row name for this variant [default: the method name with the options "
    "that differ from the profile, e.g. gauss[sigma=0.05]].",
)
@click.option(
    "--launcher",
    type=click.Choice(["inline", "local", "slurm", "submitit-local"]),
    default="inline",
    show_default=True,
    help="inline: every cell in this process; local: in -j worker processes; slurm: submit "
    "the training and the cells as SLURM jobs (see sweep --help and docs/cluster.md); "
    "submitit-local: the same jobs on this machine.",
)
@click.option(
    "--jobs",
    "-j",
    type=int,
    default=None,
    help="Worker processes of --launcher local [2]; jobs at once for submitit-local [1].",
)
@click.option(
    "--slurm",
    "slurm_opts",
    multiple=True,
    metavar="KEY=VALUE",
    help="SLURM settings, as in a sweep file's launcher block (repeatable).",
)
@click.option("--wait", is_flag=True, help="With --launcher slurm: wait for the jobs to end.")
@protocol_options
@context_options
@plugin_options
@trainer_options
@store_options
def run(
    method,
    dataset,
    splits,
    contexts,
    seeds,
    metrics,
    checkpoint,
    samples,
    force,
    retrain,
    quiet,
    label,
    launcher,
    jobs,
    slurm_opts,
    wait,
    frame,
    context_normals,
    context_protocol,
    crop_fraction,
    context_noise,
    method_opts,
    dataset_opts,
    data_root,
    profile,
    tracking_uri,
    cache_dir,
    workspace,
    **trainer,
) -> None:
    """Evaluate METHOD on DATASET at every context size; log to MLflow; print a summary.

    Cells (split x context size x seed) that already have a finished run with the same
    resolved configuration (options, code, checkpoint, protocol) are skipped, so an
    interrupted run resumes where it stopped. Exits with status 1 when every object of some
    cell failed, after printing the most common reasons.

    \b
    Examples:
      shapebench run --method gauss --dataset synthetic
      shapebench run -m gauss -d synthetic --contexts 50,100 -O sigma=0.02 --quiet
      shapebench run -m gauss -d synthetic -D test_per_category=20   # a larger benchmark
      shapebench run -m gauss -d synthetic --frame unit-diameter   # the paper's scale
      shapebench run -m gauss -d synthetic --protocol crop --crop-fraction 0.5 --contexts 2048
      shapebench run -m gauss -d synthetic --context-noise 0.005   # noisy sparse contexts
      shapebench run -m msc -d synthetic --samples 4   # posterior samples, trains first
      shapebench run -m igr -d shapenet --launcher slurm --slurm partition=gpu \\
          --slurm tracking=per-job --devices 1 --accelerator gpu
    """
    from shapebench.cli.printing import print_summary
    from shapebench.evaluation.orchestrate import EvalRequest, evaluate

    settings = _settings(profile, tracking_uri, cache_dir, workspace)
    req = EvalRequest(
        method=method,
        dataset=dataset,
        splits=splits.split(",") if splits else None,
        contexts=_int_list(contexts, "--contexts"),
        seeds=_int_list(seeds, "--seeds"),
        method_opts=_parse(method_opts, "-O") | ({"posterior_samples": samples} if samples else {}),
        dataset_opts=_parse(dataset_opts, "-D"),
        data_root=data_root,
        metrics=list(metrics) or None,
        checkpoint=checkpoint,
        force=force,
        quiet=quiet,
        protocol=_protocol(frame, context_normals, context_protocol, crop_fraction, context_noise),
        label=label,
        retrain=retrain,
    )
    if launcher != "inline":
        from shapebench.sweeps.spec import load_sweep
        from shapebench.sweeps.submit import SweepLaunch, cluster_sweep, run_as_sweep

        if checkpoint or force or retrain:
            raise ShapebenchError("--checkpoint, --force and --retrain need --launcher inline")
        sweep_file = run_as_sweep(req, settings)
        click.echo(f"as a sweep of one method: {sweep_file}")
        given = {k: v for k, v in trainer.items() if v is not None}
        launch = SweepLaunch(
            spec=load_sweep(sweep_file),
            sweep_file=sweep_file,
            settings=settings,
            launcher=launcher,
            jobs=jobs if jobs is not None else 2 if launcher == "local" else 1,
            trainer=given,
            overrides=_parse(slurm_opts, "--slurm"),
            quiet=quiet,
            wait=wait,
        )
        if launcher == "local":
            _sweep_here(launch, _worker_argv(sweep_file, settings, given, quiet))
        else:
            cluster_sweep(launch)
        return
    outcome = evaluate(req, settings, lambda seed: _trainer(settings, seed, **trainer))
    print_summary(outcome, settings)
    _exit_if_all_failed([outcome])


@cli.command()
@click.argument("sweep_file", metavar="SWEEP")
@click.option("--force", is_flag=True, help="Recompute cells that already have a finished run.")
@click.option(
    "--retrain",
    is_flag=True,
    help="Train locally even where shapebench ships a reference checkpoint of the "
    "same key (the rows are then labelled weights=local).",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress bars; only summaries.")
@click.option(
    "--method",
    "-m",
    "methods",
    multiple=True,
    help="Run only the sweep file's entries of this method (repeatable or comma-separated), "
    "with the same cells and keys as the whole sweep: e.g. -m msc,msc-noopt.",
)
@click.option(
    "--seeds",
    "seed_list",
    default="",
    metavar="LIST",
    help="Run only these of the sweep file's seeds (comma-separated), with the same cells "
    "and keys as the whole sweep: e.g. --seeds 0 for a first look at a three-seed sweep.",
)
@click.option(
    "-D",
    "dataset_opts",
    multiple=True,
    metavar="KEY=VALUE",
    help="Dataset option for every dataset entry, over the sweep file's, e.g. -D "
    "test_per_category=4 (fewer test objects, the same trained weights; repeatable).",
)
@click.option(
    "--launcher",
    type=click.Choice(["inline", "local", "slurm", "submitit-local"]),
    default=None,
    help="inline: every cell in this process [default, or the sweep file's launcher.name]; "
    "local: in -j worker processes; slurm: as SLURM jobs through submitit; submitit-local: "
    "the slurm launcher's jobs as processes on this machine.",
)
@click.option(
    "--jobs",
    "-j",
    type=int,
    default=2,
    show_default=True,
    help="Worker processes of --launcher local (jobs at once for submitit-local).",
)
@click.option(
    "--threads",
    type=int,
    default=None,
    metavar="N",
    help="Torch threads of each worker (local), job (submitit-local, slurm) or of this process "
    "(inline) [default: the cores shared between -j workers; slurm: cpus_per_task]. Lower it to "
    "evaluate beside a training without oversubscribing the cores; scores agree across thread "
    "counts to the cell key's tolerance.",
)
@click.option(
    "--slurm",
    "slurm_opts",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override a key of the sweep file's launcher block, e.g. --slurm "
    "partition=gpu --slurm time=120 (repeatable).",
)
@click.option(
    "--status", is_flag=True, help="Show finished, running, queued and failed cells with job logs."
)
@click.option("--wait", is_flag=True, help="With --launcher slurm: wait for the jobs to end.")
@click.option("--worker", type=int, default=0, hidden=True)
@protocol_options
@trainer_options
@store_options
def sweep(
    sweep_file,
    force,
    retrain,
    quiet,
    methods,
    seed_list,
    dataset_opts,
    launcher,
    jobs,
    threads,
    slurm_opts,
    status,
    wait,
    worker,
    frame,
    context_normals,
    profile,
    tracking_uri,
    cache_dir,
    workspace,
    **trainer,
) -> None:
    """Run every method x dataset x split x context size x seed of SWEEP.

    SWEEP is a sweep file, or the name of a built-in one (default, standard, paper-methods,
    crop-25, ...: the files of configs/sweeps/; a ./configs/sweeps/NAME.yaml of your own comes
    first), so that `shapebench sweep default` runs from any folder.

    Finished cells (same resolved config hash) are skipped: rerun the same command after
    Ctrl-C or a crash and only the missing cells run. --force recomputes everything.

    \b
    A sweep file (YAML):
      name: default
      profile: quick                 # optional
      methods: all                   # or a list: [gauss, {name: gauss, options: {sigma: 0.02}}]
      datasets: [synthetic]          # or [{name: synthetic, options: {...}, data_root: ...}]
      splits: [trained, novel]
      contexts: [50, 100, 300, 1000]
      seeds: [0]
      frame: unit-radius             # or unit-diameter (the paper's scale)
      context_normals: false         # the paper's protocol: points only
      launcher: {name: slurm, partition: gpu, time: 240, gpus_per_node: 1,
                 tracking: per-job, methods: {gauss: {gpus_per_node: 0}}}

    A method entry may carry a leaderboard label: {name: gauss, options: {sigma: 0.05},
    label: gauss-wide}, and run on some datasets only: {name: msc, options: {steps: 10800},
    datasets: [big]} pairs it with the dataset entries labelled big ({name: synthetic, label:
    big, options: {train_per_category: 200}}), so that a sweep can be a cross rather than a full
    grid (configs/sweeps/data-scaling.yaml). Exits with status 1 when every object of some cell
    failed.

    --launcher local -j N runs the cells in N worker processes (logs under the workspace's
    logs/), each cell once and each training once, then prints the summaries.

    --launcher slurm submits the missing trainings (one job each, one task per device) and
    the missing cells (job arrays that start after their training), then returns; follow with
    --status, and rerun the same command to resubmit what failed. See docs/cluster.md.

    \b
    Examples:
      shapebench sweep default
      shapebench sweep default --launcher local -j 2
      shapebench sweep default --threads 1                      # beside a training
      shapebench sweep default -D test_per_category=4           # fewer objects
      shapebench sweep default --seeds 0                        # one seed of three
      shapebench sweep default --launcher slurm --slurm partition=gpu
      shapebench sweep default --status
      shapebench sweep data-scaling -m msc,msc-noopt            # MSC's part
      shapebench sweep my-sweep.yaml                            # a file of your own
    """
    from shapebench.config import find_sweep
    from shapebench.sweeps.spec import load_sweep, narrow_sweep

    dataset_options = _parse(dataset_opts, "-D")
    seeds = tuple(_int_list(seed_list, "--seeds"))
    sweep_file = find_sweep(sweep_file)
    spec = narrow_sweep(load_sweep(sweep_file), methods, seeds, dataset_options)
    settings = _settings(profile or spec.profile, tracking_uri, cache_dir, workspace)
    if frame is not None or context_normals is not None:
        from dataclasses import replace

        spec = replace(
            spec,
            protocol=_protocol(
                frame or spec.protocol.frame,
                spec.protocol.context_normals if context_normals is None else context_normals,
            ),
        )
    from shapebench.sweeps.submit import SweepLaunch, show_status

    launch = SweepLaunch(
        spec=spec,
        sweep_file=sweep_file,
        settings=settings,
        launcher=launcher or spec.launcher.get("name") or "inline",
        jobs=jobs,
        threads=threads,
        trainer={k: v for k, v in trainer.items() if v is not None},
        overrides=_parse(slurm_opts, "--slurm"),
        force=force,
        retrain=retrain,
        quiet=quiet,
        wait=wait,
        worker=worker,
        frame=frame,
        context_normals=context_normals,
        methods=tuple(methods),
        seeds=seeds,
        dataset_options=dataset_options,
    )
    if status:
        show_status(launch)
        return
    _sweep_here(launch, _argv_after("sweep"))


def _sweep_here(launch: Any, worker_argv: list[str]) -> None:
    """Start ``launch`` (local workers run ``sweep`` with ``worker_argv``; cluster jobs are
    submitted), then compute what is left in this process and print each summary."""
    from shapebench.cli.printing import print_summary
    from shapebench.sweeps.spec import SweepProgress, sweep_size
    from shapebench.sweeps.submit import run_inline, start_sweep

    if not start_sweep(launch, worker_argv):
        return  # submitted as jobs

    def report(method: str, dataset: str, exc: ShapebenchError) -> None:
        click.secho(f"Error: {method} on {dataset}: {exc.message}", fg="red", err=True)
        if exc.hint:
            click.echo(f"  hint: {exc.hint}", err=True)
        click.echo("  continuing with the rest of the sweep", err=True)

    progress = SweepProgress(sweep_size(launch.spec, launch.settings))
    outcomes = []
    for outcome in run_inline(launch, report):
        print_summary(outcome, launch.settings)
        click.secho(progress.update(outcome), dim=True)
        outcomes.append(outcome)
    _exit_if_all_failed(outcomes)


def _worker_argv(
    sweep_file: Path, settings: Any, trainer: dict[str, Any], quiet: bool
) -> list[str]:
    """``run --launcher local``'s workers: ``sweep`` of the one-method sweep file, with this
    command's store, profile and trainer settings."""
    argv = [
        str(sweep_file),
        "--workspace",
        str(settings.workspace),
        "--tracking-uri",
        settings.tracking_uri,
        "--cache-dir",
        str(settings.cache_dir),
        "--profile",
        settings.profile_name,
    ]
    for name, value in trainer.items():
        argv += [f"--{name.replace('_', '-')}", str(value)]
    return argv + (["--quiet"] if quiet else [])


@cli.command()
@click.option("--method", "-m", required=True, help="Method name.")
@click.option("--dataset", "-d", required=True, help="Dataset to train on (its train split).")
@click.option(
    "--seeds",
    "--seed",
    "seeds",
    default="0",
    show_default=True,
    help="Comma-separated training seeds, trained one after another (as run's and sweep's "
    "--seeds; --seed is the same option).",
)
@click.option(
    "--retrain",
    is_flag=True,
    help="Train even where shapebench ships a reference checkpoint of the same key "
    "(by default it is installed instead).",
)
@click.option("--quiet", "-q", is_flag=True, help="Less output.")
@plugin_options
@trainer_options
@store_options
def train(
    method,
    dataset,
    seeds,
    retrain,
    quiet,
    method_opts,
    dataset_opts,
    data_root,
    profile,
    tracking_uri,
    cache_dir,
    workspace,
    **trainer,
) -> None:
    """Train METHOD on DATASET's train split (one Lightning Trainer.fit in this process).

    The checkpoint is keyed by (method config, dataset, seed) and reused by 'run' and 'sweep';
    an interrupted training resumes from its last checkpoint. 'run' trains by itself when no
    checkpoint exists: train ahead to do it on another machine or with other devices. Where
    shapebench ships a reference checkpoint of the key (the synthetic benchmark at the default
    profile), it is installed instead of training, unless --retrain.

    \b
    Examples:
      shapebench train -m msc -d synthetic
      shapebench train -m msc -d synthetic --seeds 1,2     # two more seeds, in turn
      shapebench train -m pcn -d synthetic --max-epochs 5 --quiet
      shapebench train -m msc -d shapenet --data-root ~/data/ShapeNetCore.v2 \\
          --accelerator gpu --devices 2 --strategy ddp --profile paper
    """
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method
    from shapebench.train.ticket import training_ticket
    from shapebench.train.training import ensure_checkpoint, train_here

    settings = _settings(profile, tracking_uri, cache_dir, workspace)
    reg = get_registry()
    resolved = resolve_method(reg, method, settings, _parse(method_opts, "-O"))
    if not resolved.cls.trains:
        raise ShapebenchError(f"method {method!r} does not train", "use 'shapebench run' directly")
    ds = resolve_dataset(reg, dataset, settings, data_root, _parse(dataset_opts, "-D"))
    seed_list = _int_list(seeds, "--seeds")
    if not seed_list:
        raise ShapebenchError("--seeds names no seed", "give e.g. --seeds 0 or --seeds 0,1,2")
    for seed in seed_list:
        options = _trainer(settings, seed, **trainer)
        ticket = training_ticket(resolved, ds, options, settings, retrain)
        if len(seed_list) == 1:
            record = train_here(ticket, settings, quiet)
        else:
            # Several seeds: each trains in a child process of its own, as `run` trains them, so
            # that the ranks a multi-device training launches re-run one seed, not the list.
            record = ensure_checkpoint(ticket, settings, data_root, quiet)
        click.echo(f"checkpoint: {record['path']}")
