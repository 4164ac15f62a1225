"""What the CLI prints: run summaries and plugin descriptions."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import click

from shapebench.api.protocol import DEFAULT_FRAME, FRAMES, PAPER_FRAME

if TYPE_CHECKING:
    from shapebench.config import Settings
    from shapebench.evaluation.orchestrate import EvalOutcome


def _pm(mean: float | None, std: float | None, scale: float) -> str:
    if mean is None:
        return "-"
    return f"{mean * scale:.3f} ± {(std or 0.0) * scale:.3f}"


def print_summary(outcome: EvalOutcome, settings: Settings) -> None:
    """The primary metric (mean ± std over objects, shown at its card's scale) per split and
    context size, failures and their most common reasons (``--debug``: with tracebacks)."""
    import os

    from shapebench.evaluation.failures import TOP_REASONS

    debug = bool(os.environ.get("SHAPEBENCH_DEBUG"))
    metric = outcome.primary_metric
    by_split = defaultdict(list)
    for cell in outcome.cells:
        by_split[cell.split].append(cell)
    name = outcome.variant.label if outcome.variant else outcome.method.name
    for split, cells in by_split.items():
        exp_id = cells[0].experiment_id
        click.echo("")
        scale = cells[0].scale(metric)
        click.secho(f"{name} on {outcome.dataset.name}/{split}: {metric} x{scale:g}", bold=True)
        click.echo(
            f"  {'context':>7}  {'seed':>4}  {'objects':>7}  {'failed':>6}  "
            f"{'mean ± std':>18}  {'run':<9}"
        )
        for c in sorted(cells, key=lambda c: (c.seed, c.context_size)):
            m = c.metrics
            value = _pm(m.get(f"{metric}.mean"), m.get(f"{metric}.std"), c.scale(metric))
            if f"{metric}.mean" not in m and m.get(f"{metric}.not_applicable"):
                value = "n/a"
            state = "cached" if c.skipped else "new"
            click.echo(
                f"  {c.context_size:>7}  {c.seed:>4}  {int(m.get('n_objects', 0)):>7}  "
                f"{int(m.get('failures', 0)):>6}  {value:>18}  {state:<9}"
            )
        shown: set[tuple[str, str]] = set()
        for c in cells:  # once per split: the reason is the method's or the dataset's
            for name_, reason, count in c.not_applicable:
                if (name_, reason) not in shown:
                    shown.add((name_, reason))
                    click.echo(f"  {name_}: not applicable to {count} objects: {reason}")
        failed = sum(int(c.metrics.get("failures", 0)) for c in cells)
        if failed:
            click.secho(f"  {failed} object evaluations failed", fg="yellow")
        for c in sorted(cells, key=lambda c: (c.seed, c.context_size)):
            if not c.reasons:
                continue
            everything = c.n_ok == 0
            failed = c.n_objects - c.n_ok
            click.secho(
                f"  k={c.context_size} seed={c.seed}: "
                + (
                    "EVERY object failed"
                    if everything
                    else f"{failed} failed"
                    if failed
                    else "a metric raised"
                )
                + "; most common reasons:",
                fg="red" if everything else "yellow",
            )
            for reason, count in c.reasons:
                click.echo(f"    {count} x {reason}")
                if debug and c.tracebacks.get(reason):
                    click.echo("      " + c.tracebacks[reason].replace("\n", "\n      "))
            if len(c.reasons) >= TOP_REASONS:
                click.echo(f"    (the {TOP_REASONS} most common reasons; all are in the table)")
            click.echo(f"    per-object table: {c.table_uri}")
        click.echo(f"  MLflow experiment {outcome.dataset.name}-{split} (id {exp_id})")
    click.echo("")
    click.echo(f"Runs are in {settings.tracking_uri}")
    if settings.is_remote:
        click.echo(f"  open {settings.tracking_uri}")
    else:
        click.echo("  compare them: shapebench ui   (then open the URL it prints)")
    click.echo(f"  tables:       shapebench leaderboard --dataset {outcome.dataset.name}")


def print_plugins() -> None:
    from shapebench.registry.discovery import KINDS, get_registry

    reg = get_registry()
    if not reg.plugins:
        click.echo("No shapebench plugins are installed.")
        return
    click.echo(f"{'plugin':<16} {'distribution':<22} {'version':<10} module")
    for p in reg.plugins:
        click.echo(f"{p.name:<16} {p.distribution:<22} {p.version:<10} {p.module}")
        for kind in KINDS:
            if p.provides[kind]:
                click.echo(f"{'':<16}   {kind}s: {', '.join(p.provides[kind])}")
        if p.error:
            click.secho(f"{'':<16}   error: {p.error}", fg="red")
    for kind, name, regs in reg.conflicts():
        owners = " and ".join(f"{r.plugin.distribution} ({r.plugin.name})" for r in regs)
        click.secho(f"conflict: {kind} {name!r} is provided by {owners}", fg="red")


def describe_kind(kind: str, profile: str | None = None) -> None:
    """Describe every installed ``kind``; with ``profile``, each option's value in effect (the
    config file and the profile applied) beside its default."""
    from shapebench.api.errors import ShapebenchError
    from shapebench.api.options import describe
    from shapebench.registry.discovery import get_registry

    reg = get_registry()
    profile_data = None
    if profile and kind != "metric":
        from shapebench.config import load_profile

        profile_data = load_profile(profile)  # an unknown profile fails here, naming them all
        click.echo(f"Options in effect with profile {profile!r} (override with -O/-D):\n")
    names = reg.names(kind)
    if not names:
        click.echo(f"No {kind}s are installed.")
    for name in names:
        try:
            entry = reg.get(kind, name)
            cls = entry.load()
        except ShapebenchError as exc:
            click.secho(f"{name}: {exc.message}", fg="red")
            continue
        origin = f"{entry.plugin.distribution} {entry.plugin.version}"
        click.secho(f"{name}", bold=True, nl=False)
        click.echo(f"  ({origin}): {getattr(cls, 'description', '')}")
        if kind == "method":
            sup = ", ".join(sorted(str(s) for s in cls.supervision)) or "context only"
            click.echo(f"    trains: {'yes' if cls.trains else 'no'}; needs: {sup}")
        elif kind == "dataset":
            _echo_categories(cls)
            click.echo(
                f"    splits: {', '.join(cls.eval_splits)}"
                + (
                    f" (for choosing options: {', '.join(cls.validation_splits)})"
                    if cls.validation_splits
                    else ""
                )
                + f"; default metric: "
                f"{cls.default_metric}; needs --data-root: "
                f"{'yes' if cls.needs_data_root else 'no'}"
            )
        elif kind == "metric":
            card = cls().card(30000)
            click.echo(
                f"    {'higher' if cls.higher_is_better else 'lower'} is better; card: "
                f"{card.describe()}"
            )
            click.echo(f"    in other frames: {frame_factor(card)}")
        if kind != "metric":
            effect = _in_effect(kind, name, cls, profile_data)
            for opt in describe(cls.Options):
                value = effect.get(opt.name, opt.default)
                shown = (
                    f"{value!r}, default {opt.default!r}"
                    if value != opt.default
                    else f"default {opt.default!r}"
                )
                if profile_data is not None and value == opt.default:
                    shown = f"{value!r}"
                click.echo(f"    {opt.name} ({opt.type}, {shown}): {opt.help}")
        click.echo("")
    if kind == "metric":
        echo_presets(click.echo)
        echo_frames(click.echo)


def frame_factor(card: Any) -> str:
    """How a value of ``card`` converts between the evaluation frames (--frame)."""
    ratio = FRAMES[PAPER_FRAME][0] / FRAMES[DEFAULT_FRAME][0]
    if card.power in (1, 2) and card.reduction != "fraction":
        factor = ratio**card.power
        return (
            f"a value in {PAPER_FRAME} is the {DEFAULT_FRAME} value x {factor:g} "
            f"(distances{' squared' if card.power == 2 else ''}: 1/{1 / factor:g})"
        )
    if card.reduction == "fraction":
        return (
            "not a fixed factor: the threshold is a distance in the frame of the run, so the "
            "same completion counts other points; compare values of one frame only"
        )
    # Not a distance, but it may still depend on the scale (DCD's exp(-alpha d^2)): no factor
    # can be promised from the card.
    return "no fixed factor (not a distance; it may still depend on scale): compare one frame"


def echo_presets(echo: Callable[[str], None]) -> None:
    """The named sets of metrics ``--metric`` takes (shapebench.api.metric.PRESETS)."""
    from shapebench.api.metric import PRESETS

    echo("Presets (--metric NAME computes the set):")
    for name, metrics in PRESETS.items():
        echo(f"  {name}: {', '.join(metrics)}")
    echo("")


def echo_frames(echo: Callable[[str], None]) -> None:
    """The evaluation frames, what each means, and which one the paper's tables use."""
    echo("Frames (--frame on run, sweep, leaderboard and report; part of every card and cell key):")
    for name, (scale, text) in FRAMES.items():
        marks = [
            m
            for m, on in (
                ("default", name == DEFAULT_FRAME),
                ("the paper's tables", name == PAPER_FRAME),
            )
            if on
        ]
        shown = f" [{', '.join(marks)}]" if marks else ""
        echo(f"  {name}{shown}: coordinates x {scale:g} before scoring; {text}")
    echo(f"  Compare with the paper's figures only in {PAPER_FRAME} (docs/metrics.md).")


def _in_effect(kind: str, name: str, cls: type, profile: dict | None) -> dict:
    """The option values a run gets from the config file and ``profile`` ({} without one)."""
    if profile is None:
        return {}
    from dataclasses import asdict

    from shapebench.api.options import build
    from shapebench.config import plugin_overrides

    return asdict(build(cls.Options, plugin_overrides(kind, name, profile), f"{kind} {name!r}"))


def _echo_categories(cls: type) -> None:
    """Categories by split, for datasets that know them without a local copy."""
    if cls.needs_data_root:
        return
    from shapebench.config import default_cache_dir

    try:
        cats = cls(cls.Options(), default_cache_dir()).categories()
    except Exception:  # describing must never fail because of one dataset
        return
    for split in ("trained", "novel"):
        names = [c.name for c in cats if c.split == split]
        if names:
            click.echo(f"    {split} categories ({len(names)}): {', '.join(names)}")
