"""Leaderboard figures and cost accounting: checked for content (lines, bands, marker sizes,
non-blank pixels), and the leaderboard command writes them beside the tables and to MLflow."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from conftest import TINY
from matplotlib.collections import PathCollection, PolyCollection

from shapebench.boards import figures
from shapebench.boards.cost import describe_training, device_count, row_costs
from shapebench.evaluation.pictures import is_blank


def _scored(labels: dict[str, tuple[float, float]], contexts=(50, 100, 300, 1000), n=12):
    """Per-object values: label -> (mean at 50 points, spread); halving per context step."""
    rng = np.random.default_rng(1)
    rows = []
    for label, (mean, spread) in labels.items():
        for i, k in enumerate(contexts):
            for obj in range(n):
                value = mean / 2**i + spread * rng.standard_normal()
                rows.append(
                    {
                        "variant": label,
                        "label": label,
                        "context": k,
                        "seed": 0,
                        "object": str(obj),
                        "scored": value,
                    }
                )
    return pd.DataFrame(rows)


def test_bootstrap_band_contains_the_mean_and_narrows_with_less_spread():
    rng = np.random.default_rng(0)
    wide = rng.normal(10, 3, 40)
    narrow = rng.normal(10, 0.3, 40)
    lo, hi = figures.bootstrap_band(wide)
    assert lo < wide.mean() < hi
    # Near the normal-theory interval: mean ± 1.96 s / sqrt(n).
    half = 1.96 * wide.std(ddof=1) / np.sqrt(len(wide))
    assert (hi - lo) / 2 == pytest.approx(half, rel=0.2)
    nlo, nhi = figures.bootstrap_band(narrow)
    assert nhi - nlo < (hi - lo) / 5
    assert figures.bootstrap_band(wide) == (lo, hi)  # seeded: a rebuilt table draws the same
    assert figures.bootstrap_band(np.array([3.0])) == (3.0, 3.0)


def test_context_curve_has_one_line_and_one_band_per_row_on_a_log_axis():
    scored = _scored({"gauss": (20, 2), "msc": (40, 8), "pcn": (30, 1)})
    fig = figures.context_curve(scored, ["gauss", "msc", "pcn"], "chamfer-l2 x1000", "t")
    ax = fig.axes[0]
    assert figures.line_count(fig) == 3
    assert [line.get_label() for line in ax.get_lines()] == ["gauss", "msc", "pcn"]
    assert ax.get_xscale() == "log"
    assert [int(t) for t in ax.get_xticks()] == [50, 100, 300, 1000]
    bands = [c for c in ax.collections if isinstance(c, PolyCollection)]
    assert len(bands) == 3
    # Each line is the mean over objects, inside its band.
    table = figures.curve_table(scored)
    for line in ax.get_lines():
        t = table[table.label == line.get_label()].sort_values("context")
        assert np.allclose(line.get_ydata(), t["mean"])
        assert (t["low"] < t["mean"]).all() and (t["mean"] < t["high"]).all()
    # The noisier row has the wider band.
    width = (table["high"] - table["low"]).groupby(table["label"]).mean()
    assert width["msc"] > width["gauss"] > width["pcn"]
    png = figures.io.BytesIO()
    fig.savefig(png, format="png")
    assert not is_blank(png.getvalue())


def test_context_curve_scales_to_the_cards_unit():
    scored = _scored({"gauss": (0.02, 0.001)})
    fig = figures.context_curve(scored, ["gauss"], "x1000", "t", scale=1000)
    assert fig.axes[0].get_lines()[0].get_ydata()[0] == pytest.approx(20, rel=0.05)


def test_pareto_sizes_markers_by_training_device_hours():
    points = pd.DataFrame(
        {
            "label": ["gauss", "pcn", "msc"],
            "value": [15.0, 24.0, 55.0],
            "seconds_per_object": [0.004, 0.01, 1.0],
            "train_device_hours": [np.nan, 0.3, 0.03],
        }
    )
    fig = figures.pareto(points, "s/object", "chamfer", "t")
    ax = fig.axes[0]
    marks = {c.get_label(): c for c in ax.collections if isinstance(c, PathCollection)}
    assert set(marks) == {"gauss", "pcn", "msc"}
    size = {k: c.get_sizes()[0] for k, c in marks.items()}
    assert size["pcn"] > size["msc"] > size["gauss"]
    assert marks["gauss"].get_facecolors().size == 0  # hollow: trains nothing
    assert marks["pcn"].get_facecolors()[0][3] > 0
    assert np.allclose(marks["pcn"].get_offsets()[0], [0.01, 24.0])
    assert ax.get_xscale() == "log"
    assert any("no training" in t.get_text() for t in ax.texts)


def _scaling_board(sizes: dict[str, tuple[int, int]], display: dict[str, str]):
    """A board whose rows were trained at (shapes, steps); the more shapes, the lower."""
    scored = _scored({v: (400 / shapes**0.5, 0.5) for v, (shapes, _) in sizes.items()})
    rows = [SimpleNamespace(variant=v, label=v, display=display[v]) for v in sizes]
    costs = pd.DataFrame(
        [
            {"variant": v, "train_shapes": float(a), "train_steps": float(b)}
            for v, (a, b) in sizes.items()
        ]
        + [{"variant": "gauss", "train_shapes": math.nan, "train_steps": math.nan}]
    )
    rows.append(SimpleNamespace(variant="gauss", label="gauss", display="Gauss"))
    scored = pd.concat([scored, _scored({"gauss": (20, 1)})])
    return SimpleNamespace(rows=rows, costs=costs, scored=scored, contexts=[50, 100, 300, 1000])


def test_scaling_curve_draws_each_method_against_its_training_shapes():
    sizes = {
        "msc": (66, 2700),
        "msc[tpc=20]": (220, 2700),
        "msc[tpc=200]": (2200, 2700),
        "msc[steps=10800,tpc=200]": (2200, 10800),
        "pcn": (66, 900),
        "pcn[tpc=200]": (2200, 900),
    }
    display = {v: "MSC" if v.startswith("msc") else "PCN" for v in sizes}
    fig = figures.scaling_curve(_scaling_board(sizes, display), "chamfer", "t")
    assert [ax.get_title() for ax in fig.axes] == ["50 context points", "1000 context points"]
    ax = fig.axes[0]
    assert ax.get_xscale() == "log"
    assert [int(t) for t in ax.get_xticks()] == [66, 220, 2200]
    lines = {line.get_label(): line for line in ax.get_lines() if len(line.get_xdata()) > 1}
    assert set(lines) == {"MSC", "PCN"}  # gauss trains nothing: no line
    assert list(lines["MSC"].get_xdata()) == [66, 220, 2200]
    ys = lines["MSC"].get_ydata()
    assert ys[0] > ys[1] > ys[2]  # the data's trend, drawn in order of size
    bands = [c for c in ax.collections if isinstance(c, PolyCollection)]
    assert len(bands) == 2
    # The longer budget at one size is a point with an error bar, named by its steps.
    labels = ax.get_legend_handles_labels()[1]
    assert "MSC, 10800 steps" in labels
    png = figures.io.BytesIO()
    fig.savefig(png, format="png")
    assert not is_blank(png.getvalue())


def test_no_scaling_curve_without_two_training_sizes():
    board = _scaling_board(
        {"msc": (66, 2700), "msc[steps=10800]": (66, 10800)},
        {"msc": "MSC", "msc[steps=10800]": "MSC"},
    )
    assert figures.scaling_curve(board, "chamfer", "t") is None


def test_save_writes_png_and_svg_and_refuses_a_blank_figure(tmp_path):
    scored = _scored({"a": (10, 1), "b": (12, 1)})
    fig = figures.context_curve(scored, ["a", "b"], "y", "t")
    png, svg = figures.save(fig, tmp_path / "board-chamfer")
    assert png.read_bytes().startswith(b"\x89PNG") and not is_blank(png.read_bytes())
    assert "<svg" in svg.read_text() and svg.read_text().count(">a<") + 1  # legend text present
    empty = figures._new_figure(3, 3)
    empty.patch.set_facecolor("white")
    with pytest.raises(RuntimeError, match="blank"):
        figures.save(empty, tmp_path / "blank")


def test_training_summary_counts_device_hours_and_prints_them(capsys):
    from shapebench.train.summary import report_summary, training_summary

    device = SimpleNamespace(type="cpu")
    trainer = SimpleNamespace(
        strategy=SimpleNamespace(root_device=device),
        num_devices=2,
        num_nodes=3,
        callback_metrics={"train/loss": 0.5, "val/x": 1.0},
        current_epoch=4,
        global_step=40,
        datamodule=None,  # a Trainer always has one (None when fit was given no data module)
    )
    summary = training_summary(trainer, 1800.0)
    assert summary["devices"] == 6 and summary["device_hours"] == pytest.approx(3.0)
    assert summary["device"] == "cpu x6" and summary["final"] == {"train/loss": 0.5}
    report_summary(summary, None)
    err = capsys.readouterr().err
    assert "training done in 1800.0 s on cpu x6 (3 device-hours): 4 epochs, 40 optimiser" in err


def test_device_count_reads_the_training_device_tag():
    assert device_count("cpu x1") == 1
    assert device_count("cuda x4 (NVIDIA H100 80GB HBM3)") == 4
    assert device_count("") == 1


@pytest.mark.slow  # builds an MLflow store: a few seconds
def test_row_costs_from_real_training_runs_and_per_object_seconds(tmp_path):
    from shapebench.config import make_settings
    from shapebench.store.tracking import Tracker

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    tracker = Tracker(make_settings(uri, tmp_path / "cache", "quick", tmp_path))
    client = tracker.client  # the test writes training runs as MLflow holds them
    exp = client.create_experiment("synthetic-train")
    new = client.create_run(exp, tags={"training_device": "cuda x4 (NVIDIA H100)"}).info.run_id
    for key, value in {
        "summary/wall_seconds": 900.0,
        "summary/device_hours": 1.0,
        "summary/epochs": 10.0,
        "summary/optimizer_steps": 90.0,
        "summary/training_shapes": 66.0,
        "summary/final_loss": 0.25,
    }.items():
        client.log_metric(new, key, value)
    # A training logged before device-hours were recorded: derived from wall time x devices.
    old = client.create_run(exp, tags={"training_device": "cuda x2"}).info.run_id
    client.log_metric(old, "summary/wall_seconds", 3600.0)
    runs = pd.DataFrame(
        {"variant_key": ["msc", "msc", "old", "gauss"], "training_run_id": [new, new, old, ""]}
    )
    per_object = pd.DataFrame(
        {
            "variant": ["msc", "msc", "msc", "old", "gauss", "gauss"],
            "status": ["ok", "ok", "failed", "ok", "ok", "ok"],
            "seconds": [1.0, 3.0, 50.0, 2.0, 0.01, 0.03],
        }
    )
    costs = row_costs(tracker, runs, per_object).set_index("variant")
    assert costs.loc["msc", "seconds_per_object"] == pytest.approx(2.0)  # successes only
    assert costs.loc["msc", "train_device_hours"] == pytest.approx(1.0)
    assert costs.loc["msc", "train_device"] == "cuda x4 (NVIDIA H100)"
    assert costs.loc["old", "train_device_hours"] == pytest.approx(2.0)
    assert costs.loc["msc", "train_steps"] == 90 and costs.loc["msc", "train_shapes"] == 66
    assert math.isnan(costs.loc["old", "train_shapes"])  # logged before it was recorded
    assert math.isnan(costs.loc["gauss", "train_device_hours"])
    assert costs.loc["gauss", "seconds_per_object"] == pytest.approx(0.02)
    assert describe_training(costs.loc["msc"]) == (
        "1 device-h (900 s on cuda x4 (NVIDIA H100)), 90 steps (10 epochs), loss 0.25"
    )
    assert describe_training(costs.loc["gauss"]) == "–"


@pytest.mark.slow  # runs the CLI in subprocesses
def test_leaderboard_writes_figures_and_cost_columns_and_logs_them(with_example):
    from shapebench.boards.leaderboard import BoardQuery, build_board
    from shapebench.config import make_settings
    from shapebench.store.tracking import Tracker

    sb = with_example
    for method in ("gauss", "example-sphere"):
        res = sb(
            "run",
            "-m",
            method,
            "-d",
            "synthetic",
            *TINY,
            "--contexts",
            "50,100,300",
            "-q",
            "--split",
            "novel",
        )
        assert res.returncode == 0, res.stderr
    res = sb("leaderboard", "-d", "synthetic", "--reference", "gauss")
    assert res.returncode == 0, res.stderr
    out = sb.workspace / "leaderboards"
    md = (out / "synthetic-novel.md").read_text()
    assert "| test time / object | training |" in md
    assert "![chamfer](synthetic-novel-chamfer.svg)" in md
    assert "![pareto](synthetic-novel-pareto.svg)" in md
    gauss_line = next(line for line in md.splitlines() if "(`gauss`)" in line)
    assert gauss_line.rstrip(" |").endswith("| –") and " ms |" in gauss_line
    for name in ("chamfer", "pareto"):
        png = out / f"synthetic-novel-{name}.png"
        assert not is_blank(png.read_bytes())
        assert "<svg" in (out / f"synthetic-novel-{name}.svg").read_text()
    csv = pd.read_csv(out / "synthetic-novel.csv")
    assert (csv.loc[csv.kind == "raw", "seconds_per_object"] > 0).all()

    # The figures of this store, counted: one line per row, three context sizes each.
    settings = make_settings(sb.tracking_uri, sb.cache, "quick", sb.workspace)
    tracker = Tracker(settings)
    board = build_board(tracker, BoardQuery("synthetic", "gauss"), "novel")
    drawn = figures.board_figures(board)
    assert figures.line_count(drawn["chamfer"]) == 2
    assert all(len(line.get_xdata()) == 3 for line in drawn["chamfer"].axes[0].get_lines())
    # Test time per object, as the per-object tables recorded it.
    per_obj = board.scored[board.scored.status == "ok"].groupby("variant")["seconds"].mean()
    costs = board.costs.set_index("variant")["seconds_per_object"]
    assert np.allclose(costs.loc[per_obj.index], per_obj)

    # Everything is in MLflow too, in the table's leaderboard run.
    run = tracker.client.search_runs(
        [board.experiment_id], filter_string="tags.`shapebench.kind` = 'leaderboard'"
    )
    assert len(run) == 1
    names = {a.path for a in tracker.client.list_artifacts(run[0].info.run_id)}
    assert {
        "synthetic-novel.md",
        "synthetic-novel-chamfer.png",
        "synthetic-novel-pareto.svg",
        "synthetic-novel.csv",
    } <= names
    # Rebuilding reuses that run.
    assert sb("leaderboard", "-d", "synthetic", "--reference", "gauss").returncode == 0
    again = tracker.client.search_runs(
        [board.experiment_id], filter_string="tags.`shapebench.kind` = 'leaderboard'"
    )
    assert [r.info.run_id for r in again] == [run[0].info.run_id]
