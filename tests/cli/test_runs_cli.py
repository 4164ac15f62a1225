"""``shapebench runs`` and ``shapebench show`` as a person uses them, the examples in every
command's ``--help``, ``shapebench methods --profile``, progress output in a non-terminal, and
the line a training announces itself with."""

from __future__ import annotations

import json
import re

import pytest
from click.testing import CliRunner
from conftest import TINY, Shapebench

from shapebench.cli import cli

RUN = ["-d", "synthetic", *TINY, "--split", "novel", "--contexts", "50,100"]


@pytest.fixture(scope="module")
def store(tmp_path_factory, data_cache) -> tuple[Shapebench, str]:
    """gauss and gauss[sigma=0.05] on the tiny novel split; the first run's stderr (a pipe)."""
    sb = Shapebench(tmp_path_factory.mktemp("runs-ws"), data_cache)
    first = sb("run", "-m", "gauss", *RUN)  # not --quiet: progress bars would be drawn
    assert first.returncode == 0, first.stderr
    res = sb("run", "-m", "gauss", *RUN, "-O", "sigma=0.05", "-q")
    assert res.returncode == 0, res.stderr
    return sb, first.stderr


@pytest.mark.slow
def test_progress_bars_do_not_flood_a_pipe_with_carriage_returns(store):
    _, stderr = store
    assert "\r" not in stderr


@pytest.mark.slow
def test_runs_lists_cells_with_variant_metric_duration_and_id(store):
    sb, _ = store
    cells = {r.info.run_id: r for r in sb.cell_runs("synthetic-novel")}
    res = sb("runs")
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert lines[0].split() == [
        "variant",
        "dataset/split",
        "k",
        "seed",
        "status",
        "metric",
        "mean",
        "failed",
        "time",
        "run",
        "id",
    ]
    assert lines[-1] == "4 runs; details: shapebench show RUN_ID"
    rows = [line.split() for line in lines[1:-1]]
    assert {row[-1] for row in rows} == set(cells)
    for row in rows:
        run = cells[row[-1]]
        tags = run.data.tags
        assert row[0] == tags["variant.label"] and row[1] == "synthetic/novel"
        assert row[2] == tags["context_size"] and row[4] == "FINISHED"
        assert row[5:7] == ["chamfer-l2", "x1000"]  # the card's scale, as the leaderboards
        assert float(row[7]) == pytest.approx(run.data.metrics["chamfer-l2.mean"] * 1000, abs=1e-3)
        assert row[8] == "0/4" and re.fullmatch(r"\d+\.\ds", row[9])
    assert {row[0] for row in rows} == {"gauss", "gauss[sigma=0.05]"}


@pytest.mark.slow
def test_runs_filters_and_json(store):
    sb, _ = store
    res = sb("runs", "-k", "100", "--json")
    assert res.returncode == 0, res.stderr
    rows = json.loads(res.stdout)
    assert sorted(r["variant"] for r in rows) == ["gauss", "gauss[sigma=0.05]"]
    assert {r["context_size"] for r in rows} == {100}
    assert all(r["metric"] == "chamfer-l2" and r["scale"] == 1000 for r in rows)
    res = sb("runs", "-m", "gauss", "--split", "trained")
    assert res.returncode == 0 and res.stdout.startswith("No cell runs match"), res.stdout
    parents = sb("runs", "--kind", "parent").stdout.splitlines()
    assert sorted(line.split("  ")[0] for line in parents[1:-1]) == [
        "gauss (parent)",
        "gauss[sigma=0.05] (parent)",
    ]
    assert parents[-1].startswith("2 runs")
    bad = sb("runs", "--state", "lost")
    assert bad.returncode == 2 and "'lost' is not one of" in bad.stderr
    # The filter's old name still filters, and says its new one.
    old = sb("runs", "--status", "finished", "--kind", "parent")
    assert old.returncode == 0 and old.stdout.splitlines()[-1].startswith("2 runs"), old.stdout
    assert "runs --status is now --state" in old.stderr


@pytest.mark.slow
def test_show_by_prefix_gives_metrics_artifacts_and_a_link(store):
    sb, _ = store
    run = next(
        r
        for r in sb.cell_runs("synthetic-novel")
        if r.data.tags["variant.label"] == "gauss[sigma=0.05]"
    )
    run_id, exp_id = run.info.run_id, run.info.experiment_id
    res = sb("show", run_id[:8])
    assert res.returncode == 0, res.stderr
    out = res.stdout
    assert out.startswith(f"{run.info.run_name}  (cell, FINISHED)")
    assert f"http://127.0.0.1:5000/#/experiments/{exp_id}/runs/{run_id}" in out
    mean = run.data.metrics["chamfer-l2.mean"]
    assert f"(x1000: {mean * 1000:.3f})" in out
    assert "per_object.csv" in out and "contexts.npz" in out
    details = json.loads(sb("show", run_id, "--json").stdout)
    assert details["run_id"] == run_id and details["parent_id"]
    assert details["metrics"]["chamfer-l2.mean"] == mean
    missing = sb("show", "nonexistent")
    assert missing.returncode == 2
    assert "no run 'nonexistent'" in missing.stderr and "shapebench runs" in missing.stderr


def test_runs_on_a_workspace_without_a_store_says_how_to_make_one(shapebench):
    res = shapebench("runs")
    assert res.returncode == 2
    assert "no MLflow store at" in res.stderr and "shapebench run --method" in res.stderr
    assert not (shapebench.workspace / "mlflow.db").exists()  # listing created nothing


def test_every_command_help_has_examples():
    runner = CliRunner()
    lacking = []
    for name, command in cli.commands.items():
        if command.hidden:
            continue
        res = runner.invoke(cli, [name, "--help"])
        assert res.exit_code == 0, res.output
        if "Examples:" not in res.output or f"shapebench {name}" not in res.output:
            lacking.append(name)
    assert not lacking, f"--help without examples: {lacking}"


def test_methods_profile_shows_the_values_in_effect():
    from dataclasses import fields

    from shapebench.config import load_profile, plugin_overrides
    from shapebench.registry.discovery import get_registry

    cls = get_registry().get("method", "deepsdf").load()
    defaults = {f.name: f.default for f in fields(cls.Options)}
    for profile in ("quick", "paper"):
        res = CliRunner().invoke(cli, ["methods", "--profile", profile])
        assert res.exit_code == 0, res.output
        assert f"Options in effect with profile '{profile}'" in res.output
        section = res.output.split("\ndeepsdf ")[1].split("\n\n")[0]
        given = plugin_overrides("method", "deepsdf", load_profile(profile))
        if profile == "quick":  # quick shrinks deepsdf; paper keeps the paper's defaults
            assert given, "profile quick sets no deepsdf option: nothing to show"
        if not given:
            assert ", default " not in section, section
        for name, value in given.items():
            line = next(ln for ln in section.splitlines() if ln.strip().startswith(f"{name} ("))
            expected = (
                f"{value!r}"
                if value == defaults[name]
                else (f"{value!r}, default {defaults[name]!r}")
            )
            assert f", {expected})" in line, line
    res = CliRunner().invoke(cli, ["methods", "--profile", "nope"])
    assert res.exit_code == 2 and "unknown profile 'nope'" in res.output


@pytest.mark.slow
def test_training_says_why_it_starts_and_lists_with_its_link(with_example):
    sb = with_example
    args = (
        "run",
        "-m",
        "example-template",
        "-d",
        "synthetic",
        *TINY,
        "--contexts",
        "50",
        "--split",
        "novel",
        "-q",
    )
    res = sb(*args)
    assert res.returncode == 0, res.stderr
    (line,) = [ln for ln in res.stderr.splitlines() if "no checkpoint for key" in ln]
    assert line.startswith("training example-template on synthetic: no checkpoint for key ")
    again = sb(*args, "--contexts", "100")
    assert again.returncode == 0 and "no checkpoint for key" not in again.stderr
    trainings = json.loads(sb("runs", "--kind", "training", "--json").stdout)
    assert len(trainings) == 1 and trainings[0]["experiment"] == "training/synthetic"
    assert trainings[0]["name"].startswith("train example-template")
    cell = sb.cell_runs("synthetic-novel")[0]
    shown = sb("show", cell.info.run_id).stdout
    training = trainings[0]
    assert (
        f"training:    http://127.0.0.1:5000/#/experiments/{training['experiment_id']}"
        f"/runs/{training['run_id']}"
    ) in shown
    assert f"runs/{training['run_id']})" in cell.data.tags["mlflow.note.content"]
