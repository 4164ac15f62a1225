"""The ``shapebench`` command line.

Heavy imports (mlflow, trimesh, torch) happen inside commands, so ``shapebench --help`` and
``shapebench plugins`` stay fast.
"""

from __future__ import annotations

import os
import sys
import warnings
from pathlib import Path
from typing import Any

import click

from shapebench import __version__
from shapebench.api.errors import Interrupted, ShapebenchError

DEFAULT_CONTEXTS = "50,100,300,1000"


class Group(click.Group):
    """Turns :class:`ShapebenchError` into one clear message instead of a traceback."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except Interrupted as exc:
            click.echo(
                f"\nInterrupted: {exc.message}" + (f"; {exc.hint}" if exc.hint else ""), err=True
            )
            sys.exit(130)
        except ShapebenchError as exc:
            if os.environ.get("SHAPEBENCH_DEBUG"):
                raise
            click.secho(f"Error: {exc.message}", fg="red", err=True)
            if exc.hint:
                click.echo(f"  hint: {exc.hint}", err=True)
            sys.exit(2)
        except KeyboardInterrupt:
            click.echo(
                "\nInterrupted: finished cells are kept; rerun the command to resume.", err=True
            )
            sys.exit(130)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    click.secho(f"Warning: {message}", fg="yellow", err=True)


def _int_list(value: str, flag: str) -> list[int]:
    try:
        return [int(v) for v in str(value).split(",") if v.strip()]
    except ValueError:
        raise click.BadParameter(
            f"expected comma-separated integers, got {value!r}", param_hint=flag
        ) from None


def store_options(f):
    """Where runs and data go: shared by every command that touches them."""
    f = click.option(
        "--workspace",
        type=click.Path(file_okay=False),
        default=None,
        help="Folder of the embedded MLflow store and checkpoints "
        "[default: ./shapebench-runs, or $SHAPEBENCH_WORKSPACE].",
    )(f)
    f = click.option(
        "--cache-dir",
        type=click.Path(file_okay=False),
        default=None,
        help="Where preprocessed data is cached "
        "[default: ~/.cache/shapebench, or $SHAPEBENCH_CACHE_DIR].",
    )(f)
    f = click.option(
        "--tracking-uri",
        default=None,
        metavar="URI",
        help="MLflow tracking URI, e.g. http://127.0.0.1:5000 "
        "[default: $MLFLOW_TRACKING_URI, else sqlite in the workspace].",
    )(f)
    f = click.option(
        "--profile",
        default=None,
        help="Config profile: quick (CPU, default) or paper (the paper's scale).",
    )(f)
    return f


def trainer_options(f):
    """Lightning Trainer settings, passed through to trainable methods."""
    for name, kw in reversed(
        [
            ("--accelerator", dict(default=None, help="cpu, gpu, auto... [profile, else auto]")),
            ("--devices", dict(default=None, help="Devices per node, e.g. 2 or auto.")),
            ("--strategy", dict(default=None, help="auto, ddp, ddp_spawn, fsdp...")),
            ("--num-nodes", dict(type=int, default=None, help="Nodes for multi-node training.")),
            ("--precision", dict(default=None, help="32-true, bf16-mixed, 16-mixed...")),
            ("--max-epochs", dict(type=int, default=None, help="Training epochs [profile].")),
            (
                "--checkpoint-every-epochs",
                dict(
                    type=int, default=None, help="Save the resumable checkpoint every N epochs [1]."
                ),
            ),
            (
                "--checkpoint-minutes",
                dict(
                    type=float,
                    default=None,
                    help="Also save it at the first epoch end after M minutes [10].",
                ),
            ),
        ]
    ):
        f = click.option(name, **kw)(f)
    return f


def protocol_options(f):
    """The evaluation protocol: part of every cell key (see shapebench.api.protocol)."""
    f = click.option(
        "--context-normals",
        is_flag=True,
        default=None,
        help="Give methods the normals of the context points (not the paper's protocol; rows are "
        "labelled +normals).",
    )(f)
    f = click.option(
        "--frame",
        type=click.Choice(["unit-radius", "unit-diameter"]),
        default=None,
        help="Frame distances are measured in: unit-radius (default) or unit-diameter (the "
        "paper's scale: squared distances / 4).",
    )(f)
    return f


def plugin_options(f):
    f = click.option(
        "--data-root",
        type=click.Path(),
        default=None,
        help="Local copy of the dataset (for datasets you download yourself).",
    )(f)
    f = click.option(
        "-D",
        "dataset_opts",
        multiple=True,
        metavar="KEY=VALUE",
        help="Dataset option, e.g. -D test_per_category=10 (repeatable).",
    )(f)
    f = click.option(
        "-O",
        "method_opts",
        multiple=True,
        metavar="KEY=VALUE",
        help="Method option, e.g. -O sigma=0.02 (repeatable).",
    )(f)
    return f


def _settings(profile, tracking_uri, cache_dir, workspace):
    from shapebench.config import make_settings

    return make_settings(tracking_uri, cache_dir, profile, workspace)


def _trainer(settings, seed: int, **given) -> Any:
    from shapebench.train.training import trainer_options

    return trainer_options(settings, seed, **given)


def _debug(ctx: click.Context, param: click.Parameter, value: bool) -> None:
    if value:  # read where errors are reported: Group.invoke, the run summaries
        os.environ["SHAPEBENCH_DEBUG"] = "1"


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="shapebench")
@click.option(
    "--debug",
    is_flag=True,
    expose_value=False,
    is_eager=True,
    callback=_debug,
    help="Show full tracebacks: of errors, and of each distinct per-object failure.",
)
def cli() -> None:
    """Benchmark few-shot 3D shape completion.

    Every method completes the same sparse context points (50 to 1000 surface points per
    object), is scored with an explicitly defined Chamfer distance, and logged to MLflow.

    \b
    Start here:
      shapebench run --method gauss --dataset synthetic   # evaluate one method
      shapebench sweep configs/sweeps/default.yaml        # methods x datasets x contexts
      shapebench leaderboard --dataset synthetic          # tables like the paper's
      shapebench ui                                       # compare runs in MLflow
      shapebench plugins                                  # what is installed
    """


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
    help="Metrics to compute [default: every installed metric].",
)
@click.option(
    "--checkpoint",
    type=click.Path(exists=True),
    default=None,
    help="Use this checkpoint instead of training (trainable methods).",
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
    type=click.Choice(["inline", "slurm", "submitit-local"]),
    default="inline",
    show_default=True,
    help="slurm: submit the training and the cells as SLURM jobs (see sweep --help "
    "and docs/cluster.md); submitit-local: the same jobs on this machine.",
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
    slurm_opts,
    wait,
    frame,
    context_normals,
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
      shapebench run -m gauss -d synthetic -D test_per_category=10   # a larger benchmark
      shapebench run -m gauss -d synthetic --frame unit-diameter   # the paper's scale
      shapebench run -m msc -d synthetic --samples 4   # posterior samples, trains first
      shapebench run -m igr -d shapenet --launcher slurm --slurm partition=gpu \\
          --slurm tracking=per-job --devices 1 --accelerator gpu
    """
    from shapebench.cli.printing import print_summary
    from shapebench.evaluate.orchestrate import EvalRequest, evaluate

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
        protocol=_protocol(frame, context_normals),
        label=label,
        retrain=retrain,
    )
    if launcher != "inline":
        from shapebench.sweeps.spec import load_sweep
        from shapebench.sweeps.submit import cluster_sweep, run_as_sweep

        if checkpoint or force or retrain:
            raise ShapebenchError("--checkpoint, --force and --retrain need --launcher inline")
        sweep_file = run_as_sweep(req, settings)
        click.echo(f"as a sweep of one method: {sweep_file}")
        given = {k: v for k, v in trainer.items() if v is not None}
        cluster_sweep(
            load_sweep(sweep_file),
            sweep_file,
            settings,
            given,
            _parse(slurm_opts, "--slurm"),
            launcher,
            1,
            wait,
            None,
            None,
        )
        return
    outcome = evaluate(req, settings, lambda seed: _trainer(settings, seed, **trainer))
    print_summary(outcome, settings)
    _exit_if_all_failed([outcome])


def _protocol(frame: str | None, context_normals: bool | None):
    from shapebench.api.protocol import DEFAULT_FRAME, Protocol

    return Protocol(context_normals=bool(context_normals), frame=frame or DEFAULT_FRAME)


def _exit_if_all_failed(outcomes) -> None:
    bad = [(o, c) for o in outcomes for c in o.all_failed_cells]
    if bad:
        cells = ", ".join(
            f"{o.variant.label if o.variant else o.method.name} {c.split} k={c.context_size}"
            for o, c in bad
        )
        click.secho(
            f"Error: every object failed in {len(bad)} cell(s): {cells}", fg="red", err=True
        )
        click.echo(
            "  the reasons are listed above; the runs are kept in MLflow as evidence", err=True
        )
        sys.exit(1)


def _argv_after(command: str) -> list[str]:
    """This process's arguments after the sub-command ``command`` (global options before it are
    not passed on)."""
    args = sys.argv[1:]
    return args[args.index(command) + 1 :] if command in args else args


def _parse(pairs, flag) -> dict:
    from shapebench.api.options import parse_assignments

    return parse_assignments(pairs, flag)


@cli.command()
@click.argument("sweep_file", type=click.Path(dir_okay=False))
@click.option("--force", is_flag=True, help="Recompute cells that already have a finished run.")
@click.option(
    "--retrain",
    is_flag=True,
    help="Train locally even where shapebench ships a reference checkpoint of the "
    "same key (the rows are then labelled weights=local).",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress bars; only summaries.")
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
    launcher,
    jobs,
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
    """Run every method x dataset x split x context size x seed of SWEEP_FILE.

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
    label: gauss-wide}. Exits with status 1 when every object of some cell failed.

    --launcher local -j N runs the cells in N worker processes (logs under the workspace's
    logs/), each cell once and each training once, then prints the summaries.

    --launcher slurm submits the missing trainings (one job each, one task per device) and
    the missing cells (job arrays that start after their training), then returns; follow with
    --status, and rerun the same command to resubmit what failed. See docs/cluster.md.

    \b
    Examples:
      shapebench sweep configs/sweeps/default.yaml
      shapebench sweep configs/sweeps/default.yaml --launcher local -j 2
      shapebench sweep configs/sweeps/default.yaml --launcher slurm --slurm partition=gpu
      shapebench sweep configs/sweeps/default.yaml --status
    """
    from shapebench.cli.printing import print_summary
    from shapebench.sweeps.spec import load_sweep, run_sweep

    spec = load_sweep(Path(sweep_file))
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
    launcher = launcher or spec.launcher.get("name") or "inline"
    given = {k: v for k, v in trainer.items() if v is not None}
    if status or launcher in ("slurm", "submitit-local"):
        from shapebench.sweeps.submit import cluster_sweep, show_status

        if status:
            show_status(spec, settings, given, _parse(slurm_opts, "--slurm"), launcher)
            return
        if force or retrain:
            raise ShapebenchError(
                "--force and --retrain cannot be split between jobs",
                "run such a sweep with --launcher inline",
            )
        cluster_sweep(
            spec,
            Path(sweep_file),
            settings,
            given,
            _parse(slurm_opts, "--slurm"),
            launcher,
            jobs,
            wait,
            frame,
            context_normals,
        )
        return
    if launcher == "local":
        from shapebench.sweeps.launchers import run_local

        if force or retrain:
            raise ShapebenchError(
                "--force and --retrain cannot be split between workers",
                "run such a sweep with --launcher inline",
            )
        if jobs < 1:
            raise ShapebenchError(f"--jobs must be at least 1, got {jobs}")
        log_dir = settings.artifact_root.parent / "logs"
        if run_local(_argv_after("sweep"), jobs, log_dir, click.echo):
            click.secho("some workers failed; computing what they left here", fg="yellow")

    def report(method: str, dataset: str, exc: ShapebenchError) -> None:
        click.secho(f"Error: {method} on {dataset}: {exc.message}", fg="red", err=True)
        if exc.hint:
            click.echo(f"  hint: {exc.hint}", err=True)
        click.echo("  continuing with the rest of the sweep", err=True)

    from shapebench.sweeps.spec import SweepProgress, sweep_size

    progress = SweepProgress(sweep_size(spec, settings))
    outcomes = []
    for outcome in run_sweep(
        spec,
        settings,
        force,
        quiet,
        lambda seed: _trainer(settings, seed, **trainer),
        report,
        offset=worker,
        retrain=retrain,
    ):
        print_summary(outcome, settings)
        click.secho(progress.update(outcome), dim=True)
        outcomes.append(outcome)
    _exit_if_all_failed(outcomes)


@cli.command()
@click.option("--method", "-m", required=True, help="Method name.")
@click.option("--dataset", "-d", required=True, help="Dataset to train on (its train split).")
@click.option("--seed", default=0, show_default=True, help="Training seed.")
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
    seed,
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
      shapebench train -m pcn -d synthetic --max-epochs 5 --quiet
      shapebench train -m msc -d shapenet --data-root ~/data/ShapeNetCore.v2 \\
          --accelerator gpu --devices 2 --strategy ddp --profile paper
    """
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method
    from shapebench.train.training import train_here

    settings = _settings(profile, tracking_uri, cache_dir, workspace)
    reg = get_registry()
    resolved = resolve_method(reg, method, settings, _parse(method_opts, "-O"))
    if not resolved.cls.trains:
        raise ShapebenchError(f"method {method!r} does not train", "use 'shapebench run' directly")
    ds = resolve_dataset(reg, dataset, settings, data_root, _parse(dataset_opts, "-D"))
    record = train_here(resolved, ds, _trainer(settings, seed, **trainer), settings, quiet, retrain)
    click.echo(f"checkpoint: {record['path']}")


@cli.command()
@click.option("--dataset", "-d", required=True, help="Dataset whose runs to tabulate.")
@click.option(
    "--split",
    "splits",
    default=None,
    help="Comma-separated splits [default: every split with runs].",
)
@click.option(
    "--reference",
    default="msc-noopt",
    show_default=True,
    help="Method the normalised table divides by (paper's eq. 8).",
)
@click.option("--metric", default=None, help="Metric to rank by [default: the dataset's].")
@click.option(
    "--frame",
    type=click.Choice(["unit-radius", "unit-diameter"]),
    default="unit-radius",
    show_default=True,
    help="Evaluation frame of the runs to tabulate; unit-diameter tables show the paper's "
    "figures beside ours and are written as <dataset>-<split>-unit-diameter.md.",
)
@click.option(
    "--data-version",
    default=None,
    metavar="FINGERPRINT",
    help="Tabulate this data version (a fingerprint prefix) [default: the newest with runs].",
)
@click.option(
    "--all-variants",
    is_flag=True,
    help="Also show older variants that share a label with a newer one (suffixed #key).",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default="leaderboards",
    show_default=True,
    help="Where the .md and .csv files are written.",
)
@store_options
def leaderboard(
    dataset,
    splits,
    reference,
    metric,
    frame,
    data_version,
    all_variants,
    out_dir,
    profile,
    tracking_uri,
    cache_dir,
    workspace,
) -> None:
    """Build raw and normalised Chamfer tables for DATASET from the runs in MLflow.

    Writes leaderboards/<dataset>-<split>.md and .csv, laid out like the paper's Tables 1-3.
    A row is one method variant (options, code, checkpoint, protocol), labelled like
    gauss[sigma=0.05]; per context size the best row is bold and rows statistically tied with
    it (paired Wilcoxon over the same objects, Holm-corrected) are marked. The paper's own
    figures (ShapeNet, ICL-NUIM) appear only beside a --frame unit-diameter table.

    \b
    Examples:
      shapebench leaderboard -d synthetic
      shapebench leaderboard -d synthetic --split trained --reference gauss
      shapebench leaderboard -d shapenet --frame unit-diameter   # beside the paper's figures
      shapebench leaderboard -d meshes --data-version 3f2a       # an older data version
    """
    from shapebench.boards.leaderboard import build_leaderboards

    settings = _settings(profile, tracking_uri, cache_dir, workspace)
    for path in build_leaderboards(
        settings,
        dataset,
        splits.split(",") if splits else None,
        reference,
        metric,
        Path(out_dir),
        frame,
        data_version,
        all_variants,
    ):
        click.echo(f"wrote {path}")


@cli.command()
@click.option("--dataset", "-d", required=True, help="Dataset whose runs to report.")
@click.option(
    "--split",
    "splits",
    default=None,
    help="Comma-separated splits [default: every split with runs].",
)
@click.option(
    "--reference",
    default="msc-noopt",
    show_default=True,
    help="Method the normalised table divides by (paper's eq. 8).",
)
@click.option("--metric", default=None, help="Metric to rank by [default: the dataset's].")
@click.option(
    "--frame",
    type=click.Choice(["unit-radius", "unit-diameter"]),
    default="unit-radius",
    show_default=True,
    help="Evaluation frame of the runs to report.",
)
@click.option(
    "--data-version",
    default=None,
    metavar="FINGERPRINT",
    help="Report this data version (fingerprint prefix) [default: newest].",
)
@click.option(
    "--all-variants",
    is_flag=True,
    help="Also show older variants that share a label with a newer one.",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default="leaderboards",
    show_default=True,
    help="Where the page and its figures are written.",
)
@store_options
def report(
    dataset,
    splits,
    reference,
    metric,
    frame,
    data_version,
    all_variants,
    out_dir,
    profile,
    tracking_uri,
    cache_dir,
    workspace,
) -> None:
    """Write one self-contained HTML page for DATASET from the runs in MLflow.

    Per split: the winner at each context size and the rows tied with it, the raw and
    normalised tables (sortable), cost (test time per object, training device-hours), the
    metric card, Chamfer against context size and accuracy against cost, the qualitative grids
    (rows = methods, columns = context sizes), posterior-spread pictures, and provenance.
    Written as leaderboards/<dataset>-report.html (open it in any browser; it fetches
    nothing) and logged to MLflow beside the leaderboard.

    \b
    Examples:
      shapebench report -d synthetic
      shapebench report -d synthetic --split novel --reference gauss
      shapebench report -d shapenet --frame unit-diameter
    """
    from shapebench.boards.html_report import build_report

    # Reading back dozens of small artifacts would print one progress bar each.
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    settings = _settings(profile, tracking_uri, cache_dir, workspace)
    page, seconds = build_report(
        settings,
        dataset,
        splits.split(",") if splits else None,
        reference,
        metric,
        Path(out_dir),
        frame,
        data_version,
        all_variants,
    )
    click.echo(f"wrote {page} in {seconds:.1f} s (open it in a browser)")


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
    from shapebench.evaluate.prepare import PrepareRequest, prepare_request

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


@cli.command()
def plugins() -> None:
    """List installed plugins: distribution, version, module, what each provides.

    A plugin that failed to load is listed with its error; two plugins registering one name
    are listed as a conflict.

    \b
    Examples:
      shapebench plugins
      shapebench check shapebench-foo              # then check what one provides
    """
    from shapebench.cli.printing import print_plugins

    print_plugins()


_PROFILE_OPTION = click.option(
    "--profile",
    default=None,
    help="Also show the values in effect with this profile (configs/<kind>s/<name>.yaml and "
    "configs/profiles/<profile>.yaml applied) [default: quick, or $SHAPEBENCH_PROFILE].",
)


@cli.command()
@_PROFILE_OPTION
def methods(profile) -> None:
    """Describe every installed method: options (with the values a run uses), supervision
    needed, whether it trains.

    \b
    Examples:
      shapebench methods
      shapebench methods --profile paper           # the values at the paper's scale
      shapebench run -m gauss -d synthetic -O sigma=0.02   # override one
    """
    from shapebench.cli.printing import describe_kind

    describe_kind("method", _profile_name(profile))


@cli.command()
@_PROFILE_OPTION
def datasets(profile) -> None:
    """Describe every installed dataset: categories, splits and options (with the values a run
    uses).

    \b
    Examples:
      shapebench datasets
      shapebench datasets --profile paper
      shapebench run -m gauss -d synthetic -D test_per_category=10   # override one
    """
    from shapebench.cli.printing import describe_kind

    describe_kind("dataset", _profile_name(profile))


def _profile_name(profile: str | None) -> str:
    from shapebench.config import DEFAULT_PROFILE

    return profile or os.environ.get("SHAPEBENCH_PROFILE") or DEFAULT_PROFILE


@cli.command()
def metrics() -> None:
    """Describe every installed metric and its card (the exact convention).

    \b
    Examples:
      shapebench metrics
      shapebench run -m gauss -d synthetic --metric chamfer-l2   # compute only this one
    """
    from shapebench.cli.printing import describe_kind

    describe_kind("metric")


@cli.command()
@click.option(
    "--kind",
    type=click.Choice(["cell", "parent", "training", "all"]),
    default="cell",
    show_default=True,
    help="cell: one per context size and seed; parent: one per method variant and split; "
    "training: trainings.",
)
@click.option("--method", "-m", default=None, help="Only runs of this method.")
@click.option("--dataset", "-d", default=None, help="Only runs on this dataset.")
@click.option("--split", default=None, help="Only runs on this split.")
@click.option("--context", "-k", type=int, default=None, help="Only cells of this context size.")
@click.option(
    "--status",
    type=click.Choice(["finished", "running", "failed", "killed"], case_sensitive=False),
    default=None,
    help="Only runs in this state.",
)
@click.option("--limit", default=1000, show_default=True, help="At most this many (newest).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON (one object per run).")
@store_options
def runs(
    kind,
    method,
    dataset,
    split,
    context,
    status,
    limit,
    as_json,
    profile,
    tracking_uri,
    cache_dir,
    workspace,
) -> None:
    """List the runs in the store: variant, dataset/split, context size, seed, status, the
    primary metric (mean over objects, at its card's scale), failures, duration and run id.

    \b
    Examples:
      shapebench runs                              # every cell
      shapebench runs -d synthetic --split novel -k 100
      shapebench runs --status failed              # what to look at
      shapebench runs --kind training              # trainings and how long they took
      shapebench runs -m gauss --json | jq '.[].value'
    """
    from shapebench.store.listing import format_rows, list_runs, rows_json

    settings = _settings(profile, tracking_uri, cache_dir, workspace)
    rows = list_runs(settings, kind, method, dataset, split, status, context, limit)
    if as_json:
        click.echo(rows_json(rows))
        return
    if not rows:
        click.echo(f"No {kind if kind != 'all' else ''} runs match in {settings.tracking_uri}.")
        return
    for line in format_rows(rows):
        click.echo(line)
    click.echo(f"{len(rows)} runs; details: shapebench show RUN_ID")


@cli.command()
@click.argument("run_id", metavar="RUN")
@click.option("--all", "all_tags", is_flag=True, help="Also every tag and param.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@store_options
def show(run_id, all_tags, as_json, profile, tracking_uri, cache_dir, workspace) -> None:
    """Show one run: what it evaluated, its metrics, artifacts and links to it (and to its
    training) in the MLflow UI. RUN is a run id or a unique prefix of one.

    \b
    Examples:
      shapebench show 3f2a9c                       # a prefix from 'shapebench runs'
      shapebench show 3f2a9c --all                 # with every tag and param
      shapebench show 3f2a9c --json
    """
    from shapebench.store.listing import details_json, format_details, show_run

    settings = _settings(profile, tracking_uri, cache_dir, workspace)
    details = show_run(settings, run_id)
    if as_json:
        click.echo(details_json(details))
        return
    for line in format_details(details, all_tags):
        click.echo(line)


@cli.command()
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="Address to bind; 0.0.0.0 exposes the UI to your network.",
)
@click.option("--port", default=5000, show_default=True, help="Port to listen on.")
@click.option("--workers", default=1, show_default=True, help="Server worker processes.")
@store_options
def ui(host, port, workers, profile, tracking_uri, cache_dir, workspace) -> None:
    """Start the MLflow UI on the configured store; print links to each experiment.

    The links open an experiment's runs table with the primary metric as a column, and its
    chart view, where each method variant is one line of the metric against context size.
    Exits with status 2, before starting anything, when the port is taken.

    \b
    Examples:
      shapebench ui                                # http://127.0.0.1:5000
      shapebench ui --port 5001                    # when 5000 is taken
      shapebench ui --workspace jobs/ws-0          # another workspace's store
    """
    from shapebench.store.ui import experiment_links, print_links, serve

    settings = _settings(profile, tracking_uri, cache_dir, workspace)
    if settings.is_remote:
        from shapebench.store.tracking import check_reachable, open_client

        check_reachable(settings.tracking_uri)
        click.echo(
            f"Runs are on the tracking server {settings.tracking_uri}: open it in a browser."
        )
        print_links(
            experiment_links(open_client(settings.tracking_uri), settings.tracking_uri), click.echo
        )
        return
    serve(settings, host, port, workers, click.echo)


@cli.command()
@click.argument("distribution", required=False)
@click.option("--method", "-m", "method_names", multiple=True, help="A method (repeatable).")
@click.option("--dataset", "-d", "dataset_names", multiple=True, help="A dataset (repeatable).")
@click.option("--metric", "metric_names", multiple=True, help="A metric (repeatable).")
@click.option(
    "-O",
    "method_opts",
    multiple=True,
    metavar="KEY=VALUE",
    help="Option of every method checked, e.g. -O epochs=2 (repeatable).",
)
@click.option(
    "-D",
    "dataset_opts",
    multiple=True,
    metavar="KEY=VALUE",
    help="Option of every dataset checked (repeatable).",
)
@click.option(
    "--data-root",
    type=click.Path(exists=True, file_okay=False),
    default=None,
    help="Local copy for a dataset that reads one (otherwise its data checks skip).",
)
def check(
    distribution, method_names, dataset_names, metric_names, method_opts, dataset_opts, data_root
) -> None:
    """Check that a plugin's components follow the rules, on a tiny built-in dataset.

    Checks every method, dataset and metric of DISTRIBUTION (e.g. shapebench, or
    shapebench-foo), or those named with -m/-d/--metric; with neither, every installed
    plugin. Prints PASS, FAIL or SKIP per check with the reason, and exits with status 1 when a
    check failed ('shapebench --debug check ...' also shows tracebacks and what the plugin
    printed). Data is built in a temporary folder, never in your cache.

    \b
    Examples:
      shapebench check shapebench-foo        # everything a distribution registers
      shapebench check -m gauss              # one method (seconds; trainable ones train)
      shapebench check -d synthetic --metric chamfer-l2
    """
    import time

    from shapebench.registry import check as checks
    from shapebench.registry.discovery import get_registry

    start = time.perf_counter()
    registry = get_registry()
    comps = checks.select_components(
        registry, distribution, method_names, dataset_names, metric_names
    )
    overrides = {"method": _parse(method_opts, "-O"), "dataset": _parse(dataset_opts, "-D")}
    debug = bool(os.environ.get("SHAPEBENCH_DEBUG"))
    colors = {checks.PASS: "green", checks.FAIL: "red", checks.SKIP: "yellow"}
    reports = []
    with checks.CheckEnv(registry) as env:
        for comp in comps:
            click.secho(comp.title, bold=True)
            report = checks.ComponentReport(comp)
            for res in checks.run_checks(comp, env, overrides.get(comp.kind), data_root):
                report.results.append(res)
                took = f" ({res.seconds:.1f}s)" if res.seconds >= 1 else ""
                click.echo(
                    "  "
                    + click.style(f"{res.status.upper():<4}", fg=colors[res.status])
                    + f"  {res.check:<13} {res.reason}{took}"
                )
                if debug and res.failed:
                    for text in (res.traceback, res.output):
                        if text.strip():
                            click.echo("      " + text.strip().replace("\n", "\n      "))
            reports.append(report)
    failures = checks.failure_lines(reports)
    results = [r for rep in reports for r in rep.results]
    click.echo("")
    for line in failures:
        click.secho(f"FAILED {line}", fg="red")
    click.secho(
        checks.summary(results, time.perf_counter() - start),
        bold=True,
        fg="red" if failures else "green",
    )
    if failures:
        sys.exit(1)


@cli.command()
@click.argument("stores", nargs=-1, required=True, metavar="STORE...")
@click.option(
    "--into",
    "into",
    default=None,
    metavar="URI",
    help="Store to merge into [default: this workspace's store, or --tracking-uri].",
)
@store_options
def merge(stores, into, profile, tracking_uri, cache_dir, workspace) -> None:
    """Import the finished cells and trainings of other MLflow stores into one.

    For jobs on nodes without a tracking server: each job logs to a workspace of its own, then
    this brings their runs together. A STORE is a workspace folder, its mlflow.db, or a tracking
    URI. Runs are matched by cell key (trainings by checkpoint key), so merging a store twice
    adds nothing.

    \b
    Examples:
      shapebench merge jobs/ws-0 jobs/ws-1 jobs/ws-2
      shapebench merge jobs/ws-* --into http://127.0.0.1:5000
    """
    from shapebench.store.merge import merge_stores

    settings = _settings(profile, tracking_uri, cache_dir, workspace)
    target = into or settings.tracking_uri
    from shapebench.store.tracking import check_reachable

    check_reachable(target)
    report = merge_stores(list(stores), target, echo=click.echo)
    click.echo(f"into {target}: {report.line()}")


def _sigterm_as_interrupt(signum: int, frame: Any) -> None:
    # A scheduler's or a parent's SIGTERM stops shapebench like Ctrl-C does: runs in progress are
    # marked KILLED, child trainings are stopped, finished cells and checkpoints are kept.
    raise KeyboardInterrupt


def main() -> None:
    import logging
    import signal

    signal.signal(signal.SIGTERM, _sigterm_as_interrupt)

    warnings.showwarning = _show_warning
    # MLflow's own progress bars and INFO lines would interleave with ours.
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    os.environ.setdefault("MLFLOW_LOGGING_LEVEL", "WARNING")
    logging.getLogger("alembic").setLevel(logging.WARNING)
    cli(prog_name="shapebench")
