"""The ``shapebench`` command line.

Heavy imports (mlflow, trimesh, torch) happen inside commands, so ``shapebench --help`` and
``shapebench plugins`` stay fast.
"""

from __future__ import annotations

import os
import sys
import warnings
from typing import Any

import click

from shapebench import __version__
from shapebench.api.errors import Interrupted, ShapebenchError
from shapebench.config import DEFAULT_PROFILE
from shapebench.train.lifecycle import note_stop_signal

DEFAULT_CONTEXTS = "50,100,300,1000"


class Group(click.Group):
    """The ``shapebench`` group: global options in either place, and one-line errors.

    ``--debug`` and the :data:`STORE_OPTIONS` mean the same before and after the sub-command
    (``shapebench --workspace X runs`` is ``shapebench runs --workspace X``): every sub-command
    takes ``--debug``, and a store option given before it becomes that command's default (one
    given after it wins). A store option the command does not use is refused in one line.
    """

    def add_command(self, cmd: click.Command, name: str | None = None) -> None:
        cmd.params.append(_debug_option())
        super().add_command(cmd, name)

    def resolve_command(self, ctx: click.Context, args: list[str]) -> Any:
        name, cmd, rest = super().resolve_command(ctx, args)
        ctx.meta[COMMAND_ARGS_KEY] = len(rest)  # where the command starts: _argv_after
        given = {k: v for k, v in (ctx.meta.get(GLOBALS_KEY) or {}).items() if v is not None}
        if cmd is not None and given and name is not None:
            takes = {p.name for p in cmd.params}
            unused = [_flag(k) for k in given if k not in takes]
            if unused and not ctx.resilient_parsing:
                raise click.UsageError(
                    f"'{name}' does not use {', '.join(unused)}; leave "
                    f"{'it' if len(unused) == 1 else 'them'} out",
                    ctx,
                )
            defaults = dict(ctx.default_map or {})
            defaults[name] = {**defaults.get(name, {}), **given}
            ctx.default_map = defaults
        return name, cmd, rest

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
        except Exception as exc:
            # A full disk, where no room said so already (a server gone away is recognised where
            # its URI is known: the runner, Tracker.end_after).
            from shapebench.store.failures import store_failure

            failure = store_failure(exc)
            if failure is None or os.environ.get("SHAPEBENCH_DEBUG"):
                raise
            click.secho(f"Error: {failure.message}", fg="red", err=True)
            click.echo(f"  hint: {failure.hint}", err=True)
            sys.exit(2)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    click.secho(f"Warning: {message}", fg="yellow", err=True)


def _int_list(value: str, flag: str) -> list[int]:
    try:
        return [int(v) for v in str(value).split(",") if v.strip()]
    except ValueError:
        raise click.BadParameter(
            f"expected comma-separated integers, got {value!r}", param_hint=flag
        ) from None


# The options every command that touches the store shares. They are also accepted before the
# sub-command (``shapebench --workspace X runs``): see :class:`Group`.
STORE_OPTIONS: dict[str, dict[str, Any]] = {
    "workspace": dict(
        type=click.Path(file_okay=False),
        help="Folder of the embedded MLflow store and checkpoints "
        "[default: ./shapebench-runs, or $SHAPEBENCH_WORKSPACE].",
    ),
    "cache_dir": dict(
        type=click.Path(file_okay=False),
        help="Where preprocessed data is cached "
        "[default: ~/.cache/shapebench, or $SHAPEBENCH_CACHE_DIR].",
    ),
    "tracking_uri": dict(
        metavar="URI",
        help="MLflow tracking URI, e.g. http://127.0.0.1:5000 "
        "[default: $MLFLOW_TRACKING_URI, else sqlite in the workspace].",
    ),
    "profile": dict(
        help="Config profile (configs/profiles/NAME.yaml): standard (2,200 training shapes, "
        "10 test objects per category; its weights ship), quick (66 training shapes, 2 test "
        "objects per category: minutes on a CPU) or paper (the paper's scale) "
        f"[default: {DEFAULT_PROFILE}, or $SHAPEBENCH_PROFILE].",
    ),
}


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def some_store_options(*names: str):
    """The :data:`STORE_OPTIONS` ``names`` (a command takes only those it uses)."""

    def decorate(f):
        for name in reversed(names):
            f = click.option(_flag(name), name, default=None, **STORE_OPTIONS[name])(f)
        return f

    return decorate


def store_options(f):
    """Where runs and data go, and the profile: shared by every command that touches them."""
    return some_store_options("profile", "tracking_uri", "cache_dir", "workspace")(f)


def trainer_options(f):
    """Lightning Trainer settings, passed through to trainable methods."""
    for name, kw in reversed(
        [
            ("--accelerator", dict(default=None, help="cpu, gpu, auto... [profile, else auto]")),
            ("--devices", dict(default=None, help="Devices per node, e.g. 2 or auto.")),
            ("--strategy", dict(default=None, help="auto, ddp, ddp_spawn, fsdp...")),
            ("--num-nodes", dict(type=int, default=None, help="Nodes for multi-node training.")),
            ("--precision", dict(default=None, help="32-true, bf16-mixed, 16-mixed...")),
            (
                "--max-epochs",
                dict(
                    type=int,
                    default=None,
                    help="Train this many epochs (replaces the profile's step budget).",
                ),
            ),
            (
                "--max-steps",
                dict(
                    type=int,
                    default=None,
                    help="Train this many optimiser steps, whatever the training-set size "
                    "[profile].",
                ),
            ),
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


def context_options(f):
    """Where context points come from (see shapebench.api.protocol): run and leaderboard."""
    f = click.option(
        "--context-noise",
        type=float,
        default=0.0,
        metavar="SD",
        help="Gaussian noise of this standard deviation on the context points, seeded, the "
        "same for every method (the field's levels: 0.005, 0.025).",
    )(f)
    f = click.option(
        "--crop-fraction",
        type=float,
        default=0.0,
        metavar="F",
        help="With --protocol crop: the share of the complete cloud removed (ShapeNet-55: "
        "0.25, 0.5, 0.75).",
    )(f)
    f = click.option(
        "--protocol",
        "context_protocol",
        type=click.Choice(["sparse", "crop", "depth"]),
        default=None,
        help="sparse: the paper's points on the visible surface [default]; crop: ShapeNet-55's "
        "partial shapes (the complete cloud less the part nearest a viewpoint, farthest-point "
        "sampled; the field uses --contexts 2048); depth: a simulated single-view scan (the "
        "complete cloud's points one camera sees, farthest-point sampled). leaderboard: the "
        "tables of this protocol only [default: a table per protocol with runs].",
    )(f)
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


def dataset_options(f):
    """``--data-root`` and ``-D KEY=VALUE``: which copy of the dataset, with which options."""
    f = click.option(
        "--data-root",
        type=click.Path(),
        default=None,
        help="Local copy of the dataset (for datasets you download yourself).",
    )(f)
    return click.option(
        "-D",
        "dataset_opts",
        multiple=True,
        metavar="KEY=VALUE",
        help="Dataset option, e.g. -D test_per_category=4 (repeatable).",
    )(f)


def plugin_options(f):
    """:func:`dataset_options` and ``-O KEY=VALUE`` (method options)."""
    f = dataset_options(f)
    return click.option(
        "-O",
        "method_opts",
        multiple=True,
        metavar="KEY=VALUE",
        help="Method option, e.g. -O sigma=0.02 (repeatable).",
    )(f)


def _settings(profile, tracking_uri, cache_dir, workspace):
    from shapebench.config import make_settings

    return make_settings(tracking_uri, cache_dir, profile, workspace)


def _trainer(settings, seed: int, **given) -> Any:
    from shapebench.train.training import trainer_options

    return trainer_options(settings, seed, **given)


def _debug(ctx: click.Context, param: click.Parameter, value: bool) -> None:
    if value:  # read where errors are reported: Group.invoke, the run summaries
        os.environ["SHAPEBENCH_DEBUG"] = "1"


def _debug_option() -> click.Option:
    return click.Option(
        ["--debug"],
        is_flag=True,
        expose_value=False,
        is_eager=True,
        callback=_debug,
        help="Show full tracebacks: of errors, and of each distinct per-object failure.",
    )


# Where the group keeps the store options given before the sub-command (Group.resolve_command),
# and how many arguments follow the sub-command's name.
GLOBALS_KEY = "shapebench.globals"
COMMAND_ARGS_KEY = "shapebench.command_args"


def _remember_global(ctx: click.Context, param: click.Parameter, value: Any) -> None:
    ctx.meta.setdefault(GLOBALS_KEY, {})[param.name] = value


def _global_store_options(f):
    for name in reversed(list(STORE_OPTIONS)):
        f = click.option(
            _flag(name),
            name,
            default=None,
            expose_value=False,
            callback=_remember_global,
            **STORE_OPTIONS[name],
        )(f)
    return f


@click.group(
    cls=Group,
    context_settings={"help_option_names": ["-h", "--help"]},
    params=[_debug_option()],
)
@click.version_option(__version__, prog_name="shapebench")
@_global_store_options
def cli() -> None:
    """Benchmark few-shot 3D shape completion.

    Every method completes the same sparse context points (50 to 1000 surface points per
    object), is scored with an explicitly defined Chamfer distance, and logged to MLflow.

    \b
    Start here:
      shapebench run --method gauss --dataset synthetic   # evaluate one method
      shapebench sweep default                            # methods x datasets x contexts
      shapebench leaderboard --dataset synthetic          # tables like the paper's
      shapebench ui                                       # compare runs in MLflow
      shapebench plugins                                  # what is installed

    --workspace, --profile, --tracking-uri, --cache-dir and --debug may come before or
    after the command.
    """


def _protocol(
    frame: str | None,
    context_normals: bool | None,
    context: str | None = None,
    crop_fraction: float = 0.0,
    context_noise: float = 0.0,
):
    from shapebench.api.protocol import DEFAULT_CONTEXT, DEFAULT_FRAME, Protocol

    return Protocol(
        context_normals=bool(context_normals),
        frame=frame or DEFAULT_FRAME,
        context=context or DEFAULT_CONTEXT,
        crop_fraction=crop_fraction,
        context_noise=context_noise,
    )


def _exit_if_all_failed(outcomes) -> None:
    """Exit 1 when every object of some cell failed (a local sweep's worker: its own status,
    :data:`shapebench.sweeps.launchers.ALL_FAILED_STATUS`, which the launcher tells from a
    crash)."""
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
        from shapebench.sweeps.launchers import ALL_FAILED_STATUS, WORKER_ENV

        sys.exit(ALL_FAILED_STATUS if os.environ.get(WORKER_ENV) else 1)


def _argv_after(command: str) -> list[str]:
    """This process's arguments for the sub-command ``command``, with the global options given
    before it (every one of them is also an option of the sub-command: :class:`Group`)."""
    args = sys.argv[1:]
    ctx = click.get_current_context(silent=True)
    after = ctx.find_root().meta.get(COMMAND_ARGS_KEY) if ctx is not None else None
    at = len(args) - after - 1 if after is not None else -1
    if not (0 <= at < len(args) and args[at] == command):  # argv is not what click parsed
        if command not in args:
            return args
        at = args.index(command)
    return args[:at] + args[at + 1 :]


def _parse(pairs, flag) -> dict:
    from shapebench.api.options import parse_assignments

    return parse_assignments(pairs, flag)


def _sigterm_as_interrupt(signum: int, frame: Any) -> None:
    # A scheduler's or a parent's SIGTERM stops shapebench like Ctrl-C does: runs in progress are
    # marked KILLED, child trainings are stopped, finished cells and checkpoints are kept. It is
    # also remembered, for a training that starts after the interrupt was lost in an import.
    note_stop_signal(signum)
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
    # MLflow logs a database error (several lines) before raising it; the error itself is
    # reported once, in one line, by Group.invoke (--debug shows its traceback).
    logging.getLogger("mlflow.store.db.utils").setLevel(logging.CRITICAL)
    cli(prog_name="shapebench")
