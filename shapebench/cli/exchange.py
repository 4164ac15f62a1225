"""``shapebench export`` and ``shapebench import``: contexts out, completions made anywhere back in.

``export`` writes the contexts of a set of cells and their manifest
(:mod:`shapebench.exchange.export`); ``import`` scores the completions written beside them with
the built-in ``files`` method, with the dataset, protocol, sizes and seeds the manifest names
(``run -m files -O root=DIR`` does the same with them given by hand). The guide is
docs/byo-completions.md.
"""

from __future__ import annotations

from pathlib import Path

import click

from shapebench.cli.app import (
    DEFAULT_CONTEXTS,
    _exit_if_all_failed,
    _int_list,
    _parse,
    _protocol,
    _settings,
    _trainer,
    cli,
    context_options,
    dataset_options,
    store_options,
)


@cli.command()
@click.option("--dataset", "-d", required=True, help="Dataset name (see 'shapebench datasets').")
@click.option(
    "--split",
    "splits",
    default=None,
    help="Comma-separated splits [default: the dataset's evaluation splits].",
)
@click.option("--contexts", default=DEFAULT_CONTEXTS, show_default=True, help="Context sizes.")
@click.option("--seeds", default="0", show_default=True, help="Comma-separated run seeds.")
@click.option(
    "--context-normals",
    is_flag=True,
    default=False,
    help="Also export the normals of the context points (-normals.npy, and in the .ply).",
)
@click.option(
    "--out",
    required=True,
    type=click.Path(file_okay=False),
    help="Folder to write contexts/, completions/ (empty) and manifest.json to.",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress bars; only the summary.")
@context_options
@dataset_options
@store_options
def export(
    dataset,
    splits,
    contexts,
    seeds,
    context_normals,
    out,
    quiet,
    context_protocol,
    crop_fraction,
    context_noise,
    dataset_opts,
    data_root,
    profile,
    tracking_uri,
    cache_dir,
    workspace,
) -> None:
    """Write the exact contexts of DATASET's cells for a model that runs elsewhere.

    One file per object, context size and seed, in the dataset's frame: OUT/contexts/<split>/
    <category>/<object>/n<size>-s<seed>.npy and .ply; OUT/manifest.json names the dataset
    (fingerprints), the protocol, the cells and where each completion is expected (below
    OUT/completions/). The contexts are those every method of a run completes; exporting twice
    gives identical files. Score the completions with 'shapebench import OUT'.

    \b
    Examples:
      shapebench export -d synthetic --contexts 50,100 --out exported
      shapebench export -d shapenet55 --data-root ~/data/ShapeNet55 --protocol crop \\
          --crop-fraction 0.5 --contexts 2048 --out sn55-median
    """
    from shapebench.exchange.export import export_contexts
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset

    settings = _settings(profile, tracking_uri, cache_dir, workspace)
    ds = resolve_dataset(get_registry(), dataset, settings, data_root, _parse(dataset_opts, "-D"))
    protocol = _protocol(None, context_normals, context_protocol, crop_fraction, context_noise)
    report = export_contexts(
        ds,
        protocol,
        splits.split(",") if splits else None,
        _int_list(contexts, "--contexts"),
        _int_list(seeds, "--seeds"),
        Path(out),
        quiet,
        click.echo,
    )
    click.echo(report.summary())


@cli.command(name="import")
@click.argument("folder", type=click.Path(file_okay=False, exists=True))
@click.option("--label", default=None, help="The row's name in tables and reports.")
@click.option(
    "--metric",
    "metrics",
    multiple=True,
    help="Metric to compute (repeatable) [default: every metric computed by default].",
)
@click.option(
    "--frame",
    type=click.Choice(["unit-radius", "unit-diameter"]),
    default=None,
    help="Frame distances are measured in [default: unit-radius].",
)
@click.option("--force", is_flag=True, help="Recompute cells that already have a finished run.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bars; only the summary.")
@dataset_options
@store_options
def import_(
    folder,
    label,
    metrics,
    frame,
    force,
    quiet,
    dataset_opts,
    data_root,
    profile,
    tracking_uri,
    cache_dir,
    workspace,
) -> None:
    """Score the completions in FOLDER (an export folder) like any method's, as row LABEL.

    The dataset, its options, the protocol, splits, context sizes and seeds are the manifest's;
    -D changes a dataset option and is refused when the contexts would differ. This runs
    'shapebench run -m files -O root=FOLDER' with them: the rows go to the same store, tables,
    paired tests and report as every other method's. A missing or unreadable completion fails
    its object alone, naming the file.

    \b
    Examples:
      shapebench import exported --label my-model
      shapebench leaderboard -d synthetic
    """
    from shapebench.cli.printing import print_summary
    from shapebench.evaluation.orchestrate import EvalRequest, evaluate
    from shapebench.exchange.manifest import read_manifest
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset

    settings = _settings(profile, tracking_uri, cache_dir, workspace)
    root = Path(folder).resolve()
    manifest = read_manifest(root)
    options = {**manifest.dataset_options, **_parse(dataset_opts, "-D")}
    ds = resolve_dataset(get_registry(), manifest.dataset, settings, data_root, options)
    p = manifest.protocol
    protocol = _protocol(frame, p.context_normals, p.context, p.crop_fraction, p.context_noise)
    manifest.check_matches(ds, protocol, root)
    req = EvalRequest(
        method="files",
        dataset=manifest.dataset,
        splits=manifest.splits,
        contexts=manifest.contexts,
        seeds=manifest.seeds,
        method_opts={"root": str(root)},
        dataset_opts=options,
        data_root=data_root,
        metrics=list(metrics) or None,
        force=force,
        quiet=quiet,
        protocol=protocol,
        label=label,
    )
    outcome = evaluate(req, settings, lambda seed: _trainer(settings, seed))
    print_summary(outcome, settings)
    _exit_if_all_failed([outcome])
