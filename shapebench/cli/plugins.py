"""``shapebench plugins``, ``methods``, ``datasets``, ``metrics`` and ``check``: what is installed,
what its options are, and whether it follows the rules."""

from __future__ import annotations

import os
import sys

import click

from shapebench.cli.app import (
    _parse,
    cli,
)
from shapebench.config import DEFAULT_PROFILE


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
    f"configs/profiles/<profile>.yaml applied) [default: {DEFAULT_PROFILE}, or "
    "$SHAPEBENCH_PROFILE].",
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
      shapebench run -m gauss -d synthetic -D test_per_category=20   # override one
    """
    from shapebench.cli.printing import describe_kind

    describe_kind("dataset", _profile_name(profile))


def _profile_name(profile: str | None) -> str:
    from shapebench.config import default_profile

    return profile or default_profile()


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

    from shapebench.conformance.framework import (
        FAIL,
        PASS,
        SKIP,
        CheckEnv,
        ComponentReport,
        failure_lines,
        summary,
    )
    from shapebench.conformance.runner import run_checks, select_components
    from shapebench.registry.discovery import get_registry

    start = time.perf_counter()
    registry = get_registry()
    comps = select_components(registry, distribution, method_names, dataset_names, metric_names)
    overrides = {"method": _parse(method_opts, "-O"), "dataset": _parse(dataset_opts, "-D")}
    debug = bool(os.environ.get("SHAPEBENCH_DEBUG"))
    colors = {PASS: "green", FAIL: "red", SKIP: "yellow"}
    reports = []
    with CheckEnv(registry) as env:
        for comp in comps:
            click.secho(comp.title, bold=True)
            report = ComponentReport(comp)
            for res in run_checks(comp, env, overrides.get(comp.kind), data_root):
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
    failures = failure_lines(reports)
    results = [r for rep in reports for r in rep.results]
    click.echo("")
    for line in failures:
        click.secho(f"FAILED {line}", fg="red")
    click.secho(
        summary(results, time.perf_counter() - start),
        bold=True,
        fg="red" if failures else "green",
    )
    if failures:
        sys.exit(1)
