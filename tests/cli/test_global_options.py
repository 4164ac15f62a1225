"""One behaviour per option: the global options before or after the sub-command, options a
command does not use refused, built-in sweeps by name, tables written to the workspace."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from click.testing import CliRunner

from shapebench.cli import cli
from shapebench.config import find_sweep, sweep_names


@pytest.fixture
def runner(monkeypatch, tmp_path) -> CliRunner:
    for name in ("SHAPEBENCH_WORKSPACE", "MLFLOW_TRACKING_URI", "SHAPEBENCH_DEBUG"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)
    return CliRunner()


def _store_of(output: str) -> str:
    # `runs` on a workspace without a store names the store it looked for.
    assert "no MLflow store at " in output, output
    return output.split("no MLflow store at ")[1].split()[0]


def test_the_workspace_means_the_same_before_and_after_the_command(runner, tmp_path) -> None:
    ws = tmp_path / "elsewhere"
    before = runner.invoke(cli, ["--workspace", str(ws), "runs"])
    after = runner.invoke(cli, ["runs", "--workspace", str(ws)])
    assert before.exit_code == after.exit_code == 2, before.output + after.output
    assert _store_of(before.output) == _store_of(after.output) == str(ws / "mlflow.db")
    # Given in both places, the one after the command wins (it is the command's own).
    both = runner.invoke(cli, ["--workspace", str(ws), "runs", "--workspace", str(tmp_path / "b")])
    assert _store_of(both.output) == str(tmp_path / "b" / "mlflow.db")


def test_debug_is_accepted_after_the_command_too(runner) -> None:
    from shapebench.api.errors import ShapebenchError

    quiet = runner.invoke(cli, ["runs"])
    assert quiet.exit_code == 2 and quiet.exception is not None  # SystemExit: one line
    assert not isinstance(quiet.exception, ShapebenchError)
    # --debug shows the error itself (its traceback), after the command as before it.
    for args in (["runs", "--debug"], ["--debug", "runs"]):
        res = runner.invoke(cli, args)
        assert isinstance(res.exception, ShapebenchError), (args, res.output)
        os.environ.pop("SHAPEBENCH_DEBUG", None)


@pytest.mark.parametrize(
    "args, flag",
    [
        (["--profile", "quick", "runs"], "--profile"),
        (["--cache-dir", "c", "leaderboard", "-d", "synthetic"], "--cache-dir"),
        (["--workspace", "w", "plugins"], "--workspace"),
    ],
)
def test_a_global_option_the_command_does_not_use_is_refused(runner, args, flag) -> None:
    res = runner.invoke(cli, args)
    assert res.exit_code == 2
    assert f"does not use {flag}" in res.output, res.output


@pytest.mark.parametrize("command", ["runs", "show", "ui", "merge", "leaderboard", "report"])
def test_commands_that_only_read_the_store_take_only_its_place(runner, command) -> None:
    help_text = runner.invoke(cli, [command, "--help"]).output
    assert "--workspace" in help_text and "--tracking-uri" in help_text
    assert "--profile" not in help_text and "--cache-dir" not in help_text


def test_a_builtin_sweep_runs_by_name_from_any_folder(runner, tmp_path) -> None:
    assert {"default", "standard", "crop-50", "data-scaling"} <= set(sweep_names())
    path = find_sweep("default")
    assert path.name == "default.yaml" and path.parent.name == "sweeps"
    # The user's own configs/sweeps/NAME.yaml comes first; a path is a path.
    own = tmp_path / "configs" / "sweeps" / "default.yaml"
    own.parent.mkdir(parents=True)
    own.write_text("name: mine\nmethods: [gauss]\ndatasets: [synthetic]\n")
    assert find_sweep("default").resolve() == own.resolve()
    assert find_sweep(str(own)) == own


def test_an_unknown_sweep_name_lists_the_builtin_ones(runner) -> None:
    res = runner.invoke(cli, ["sweep", "defualt", "--status"])
    assert res.exit_code == 2
    assert "did you mean 'default'?" in res.output
    assert "crop-50" in res.output and "shapebench init" in res.output
    assert "Traceback" not in res.output


def test_tables_go_to_the_workspace_unless_told_otherwise(runner, tmp_path) -> None:
    import click

    leaderboard = cli.commands["leaderboard"]
    report = cli.commands["report"]
    for command in (leaderboard, report):
        out = next(p for p in command.params if p.name == "out_dir")
        assert isinstance(out, click.Option) and out.default is None
    from shapebench.cli.results import _out
    from shapebench.config import make_settings

    settings = make_settings(workspace=tmp_path / "ws")
    assert _out(None, settings) == tmp_path / "ws" / "leaderboards"
    assert _out("leaderboards", settings) == Path("leaderboards")


def test_local_workers_get_the_global_options_even_one_named_like_the_command(
    runner, monkeypatch, tmp_path
) -> None:
    """The workers' command line is this one's, the sub-command's name taken out where click
    found it: not at an earlier option value spelled the same (``--workspace sweep``)."""
    import sys

    from shapebench.cli import evaluate

    got = []
    monkeypatch.setattr(evaluate, "_sweep_here", lambda launch, argv: got.append(argv))
    args = ["--workspace", "sweep", "--profile", "quick", "sweep", "default", "-m", "gauss"]
    args += ["--launcher", "local"]
    monkeypatch.setattr(sys, "argv", ["shapebench", *args])
    res = runner.invoke(cli, args)
    assert res.exit_code == 0, res.output
    assert got == [["--workspace", "sweep", "--profile", "quick", "default", "-m", "gauss",
                    "--launcher", "local"]]  # fmt: skip
