"""``shapebench leaderboard``, ``report``, ``runs``, ``show``, ``ui`` and ``merge``: what the store
holds, as tables, pages and the MLflow UI."""

from __future__ import annotations

import os
from pathlib import Path

import click

from shapebench.api.errors import ShapebenchError
from shapebench.cli.app import (
    _protocol,
    _settings,
    cli,
    context_options,
    some_store_options,
)

# The store's place is all a command that only reads it uses.
store_location = some_store_options("tracking_uri", "workspace")


def _floor_and_tail_options(command):
    """``--floor`` and ``--tail-threshold``, shared by ``leaderboard`` and ``report``."""
    command = click.option(
        "--tail-threshold",
        "tail",
        type=float,
        default=None,
        metavar="VALUE",
        help="Beside each mean the table shows the median and the share of (object, seed) "
        "pairs worse than this value (above it; below it for higher-is-better metrics), in "
        "the table's displayed units and frame (chamfer-l2: x1000) [default: the metric "
        "card's tail threshold, chamfer-l2 10 in the unit-radius frame; none for metrics "
        "whose card states none].",
    )(command)
    return click.option(
        "--floor",
        "floors",
        multiple=True,
        metavar="LABEL",
        help="A floor row (repeatable): a row label, or a method run with its defaults. Per "
        "context size the better floor present is the floor, and each other row not "
        "significantly better than it (paired Wilcoxon, Holm-corrected, alpha 0.05) is "
        "marked with a dagger. [default: given-points and retrieval, those with rows; "
        "--floor none: no floor marks]",
    )(command)


def _floors(given: tuple[str, ...]) -> tuple[str, ...] | None:
    """The floors asked for: None for the defaults, () for ``--floor none``."""
    if not given:
        return None
    return () if list(given) == ["none"] else tuple(given)


def _out(out_dir: str | None, settings) -> Path:
    """Where tables and reports go: ``--out``, else the workspace's ``leaderboards/`` (so that
    a checkout's committed tables change only when asked: ``--out leaderboards``)."""
    return Path(out_dir) if out_dir else settings.workspace / "leaderboards"


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
    default=None,
    help="Where the .md and .csv files are written [default: the workspace's leaderboards/].",
)
@_floor_and_tail_options
@context_options
@store_location
def leaderboard(
    dataset,
    splits,
    reference,
    metric,
    frame,
    data_version,
    all_variants,
    out_dir,
    floors,
    tail,
    context_protocol,
    crop_fraction,
    context_noise,
    tracking_uri,
    workspace,
) -> None:
    """Build raw and normalised Chamfer tables for DATASET from the runs in MLflow.

    Writes <dataset>-<split>.md and .csv, laid out like the paper's Tables 1-3, and
    <dataset>-<split>-categories.csv (each category's mean and median) into the workspace's
    leaderboards/ folder, or --out DIR (a checkout's committed tables: --out leaderboards).
    A row is one method variant (options, code, checkpoint, protocol), labelled like
    gauss[sigma=0.05]; per context size the best row is bold and rows statistically tied with
    it (paired Wilcoxon over the same objects, Holm-corrected) are marked, and rows not
    significantly better than the floor (returning the context unchanged, given-points, or
    retrieving the nearest training shape, retrieval) carry a dagger. Beside each mean: the
    median and the share of pairs worse than the card's tail threshold. The paper's own
    figures (ShapeNet, ICL-NUIM) appear only beside a --frame unit-diameter table.

    \b
    Examples:
      shapebench leaderboard -d synthetic
      shapebench leaderboard -d synthetic --split trained --reference gauss
      shapebench leaderboard -d shapenet --frame unit-diameter   # beside the paper's figures
      shapebench leaderboard -d meshes --data-version 3f2a       # an older data version
      shapebench leaderboard -d synthetic --protocol crop --crop-fraction 0.5   # its own table

    Runs with another context protocol (--protocol crop, --context-noise) are tables of their
    own, written as <dataset>-<split>-crop-0_5.md; the header names the protocol. Without
    --protocol, every protocol with runs gets its table.
    """
    from shapebench.boards.leaderboard import BoardQuery, build_leaderboards

    settings = _settings(None, tracking_uri, None, workspace)
    given = context_protocol is not None or crop_fraction or context_noise
    protocol = (
        _protocol(None, None, context_protocol, crop_fraction, context_noise).name
        if given
        else None
    )
    query = BoardQuery(
        dataset, reference, metric, frame, data_version, all_variants, _floors(floors), tail
    )
    for path in build_leaderboards(
        settings, query, splits.split(",") if splits else None, _out(out_dir, settings), protocol
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
    default=None,
    help="Where the page and its figures are written [default: the workspace's leaderboards/].",
)
@_floor_and_tail_options
@store_location
def report(
    dataset,
    splits,
    reference,
    metric,
    frame,
    data_version,
    all_variants,
    out_dir,
    floors,
    tail,
    tracking_uri,
    workspace,
) -> None:
    """Write one self-contained HTML page for DATASET from the runs in MLflow.

    Per split: the winner at each context size and the rows tied with it, the rows not better
    than the floor (given-points, retrieval; --floor), the raw and normalised tables
    (sortable; median and tail share beside each mean), per-category means, cost (test time
    per object, training device-hours), the metric card, Chamfer against context size and
    accuracy against cost, the qualitative grids (rows = methods, columns = context sizes),
    each row's worst object at the largest context size, posterior-spread pictures, and
    provenance.
    Written as <dataset>-report.html in the workspace's leaderboards/ folder, or --out DIR
    (open it in any browser; it fetches nothing), and logged to MLflow beside the leaderboard.

    \b
    Examples:
      shapebench report -d synthetic
      shapebench report -d synthetic --split novel --reference gauss
      shapebench report -d shapenet --frame unit-diameter
    """
    from shapebench.boards.html_report import build_report
    from shapebench.boards.leaderboard import BoardQuery

    # Reading back dozens of small artifacts would print one progress bar each.
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    settings = _settings(None, tracking_uri, None, workspace)
    query = BoardQuery(
        dataset, reference, metric, frame, data_version, all_variants, _floors(floors), tail
    )
    page, seconds = build_report(
        settings, query, splits.split(",") if splits else None, _out(out_dir, settings)
    )
    click.echo(f"wrote {page} in {seconds:.1f} s (open it in a browser)")


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
    "--state",
    "status",
    type=click.Choice(["finished", "running", "failed", "killed"], case_sensitive=False),
    default=None,
    help="Only runs in this state.",
)
@click.option(
    "--status",
    "old_status",
    type=click.Choice(["finished", "running", "failed", "killed"], case_sensitive=False),
    default=None,
    hidden=True,  # the old name; `sweep --status` shows cells, so the filter is --state
)
@click.option(
    "--limit",
    default=1000,
    show_default=True,
    help="At most this many (the newest); 0: every run. Says so when it leaves runs out.",
)
@click.option("--json", "as_json", is_flag=True, help="Print JSON (one object per run).")
@store_location
def runs(
    kind,
    method,
    dataset,
    split,
    context,
    status,
    old_status,
    limit,
    as_json,
    tracking_uri,
    workspace,
) -> None:
    """List the runs in the store: variant, dataset/split, context size, seed, status, the
    primary metric (mean over objects, at its card's scale), failures, duration and run id.

    \b
    Examples:
      shapebench runs                              # every cell
      shapebench runs -d synthetic --split novel -k 100
      shapebench runs --state failed               # what to look at
      shapebench runs --kind training              # trainings and how long they took
      shapebench runs -m gauss --json | jq '.[].value'
    """
    from shapebench.store.listing import format_rows, list_runs_counted, rows_json

    if old_status:
        click.secho("Warning: runs --status is now --state", fg="yellow", err=True)
        status = status or old_status
    if limit < 0:
        raise ShapebenchError(f"--limit must be 0 (every run) or more, got {limit}")
    settings = _settings(None, tracking_uri, None, workspace)
    rows, more = list_runs_counted(
        settings, kind, method, dataset, split, status, context, limit or None
    )
    cut = f"the newest {limit}; older ones match too (--limit 0 lists every one)"
    if as_json:
        click.echo(rows_json(rows))
        if more:
            click.echo(f"note: {cut}", err=True)
        return
    if not rows:
        click.echo(f"No {kind if kind != 'all' else ''} runs match in {settings.tracking_uri}.")
        return
    for line in format_rows(rows):
        click.echo(line)
    click.echo(f"{len(rows)} runs{f' ({cut})' if more else ''}; details: shapebench show RUN_ID")


@cli.command()
@click.argument("run_id", metavar="RUN")
@click.option("--all", "all_tags", is_flag=True, help="Also every tag and param.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@store_location
def show(run_id, all_tags, as_json, tracking_uri, workspace) -> None:
    """Show one run: what it evaluated, its metrics, artifacts and links to it (and to its
    training) in the MLflow UI. RUN is a run id or a unique prefix of one.

    \b
    Examples:
      shapebench show 3f2a9c                       # a prefix from 'shapebench runs'
      shapebench show 3f2a9c --all                 # with every tag and param
      shapebench show 3f2a9c --json
    """
    from shapebench.store.listing import details_json, format_details, show_run

    settings = _settings(None, tracking_uri, None, workspace)
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
@store_location
def ui(host, port, workers, tracking_uri, workspace) -> None:
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

    settings = _settings(None, tracking_uri, None, workspace)
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
@click.argument("stores", nargs=-1, required=True, metavar="STORE...")
@click.option(
    "--into",
    "into",
    default=None,
    metavar="URI",
    help="Store to merge into [default: this workspace's store, or --tracking-uri].",
)
@store_location
def merge(stores, into, tracking_uri, workspace) -> None:
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

    settings = _settings(None, tracking_uri, None, workspace)
    target = into or settings.tracking_uri
    from shapebench.store.tracking import check_reachable

    check_reachable(target)
    report = merge_stores(list(stores), target, echo=click.echo)
    click.echo(f"into {target}: {report.line()}")
