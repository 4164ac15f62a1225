"""Results as DataFrames (shapebench.load_results, load_leaderboard) agree with the store and the
leaderboard, and the notebook example in docs/ runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import TINY, TINY_CONTEXTS

import shapebench
import shapebench as shapebench_api
from shapebench.api.errors import ShapebenchError
from shapebench.boards.frames import RESULT_COLUMNS

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def two_rows(shapebench):
    for extra in ([], ["-O", "sigma=0.05"]):
        res = shapebench(
            "run",
            "-m",
            "gauss",
            "-d",
            "synthetic",
            "--split",
            "trained",
            *TINY,
            *TINY_CONTEXTS,
            "-q",
            *extra,
        )
        assert res.returncode == 0, res.stderr
    return shapebench


@pytest.mark.slow  # runs the CLI
def test_results_and_leaderboard_frames_match_the_store(two_rows):
    ws = two_rows.workspace
    scores = shapebench.load_results("synthetic", workspace=ws)
    assert list(scores.columns[: len(RESULT_COLUMNS)]) == list(RESULT_COLUMNS)
    assert {"chamfer-l2", "chamfer-l1", "fscore"} <= set(scores.columns)
    assert set(scores.label) == {"gauss", "gauss[sigma=0.05]"}
    assert set(scores.split) == {"trained"} and set(scores.context) == {50, 100}
    # 11 trained categories, one object each, per (label, context)
    assert len(scores) == 2 * 2 * 11 and not scores.failed.any()
    assert scores.groupby(["label", "context"]).object.nunique().eq(11).all()
    assert (scores.category == scores.object.str.split("/").str[0]).all()
    assert set(scores.protocol) == {"points"} and set(scores.frame) == {"unit-radius"}

    # The same numbers as the cell's per-object artifact...
    run = scores[(scores.label == "gauss") & (scores.context == 50)]
    dst = ws / "dl"
    dst.mkdir()
    path = two_rows.client().download_artifacts(run.run_id.iloc[0], "per_object.csv", str(dst))
    stored = pd.read_csv(path).set_index("object")["chamfer-l2"]
    got = run.set_index("object")["chamfer-l2"]
    assert np.array_equal(got.sort_index().to_numpy(), stored.sort_index().to_numpy())

    # ... and as the leaderboard's table (x1000, the card's display scale).
    table = shapebench.load_leaderboard("synthetic", "trained", reference="gauss", workspace=ws)
    raw = table[table.kind == "raw"].set_index(["label", "context"])["mean"]
    means = scores.groupby(["label", "context"])["chamfer-l2"].mean() * 1000
    assert np.allclose(raw.sort_index().to_numpy(), means.sort_index().to_numpy())
    assert {"p_vs_best", "p_holm", "best", "tied"} <= set(table.columns)

    only = shapebench.load_results("synthetic", "trained", metric="fscore", workspace=ws)
    assert list(only.columns) == list(RESULT_COLUMNS) + ["fscore"]
    with pytest.raises(ShapebenchError, match="no run of synthetic recorded metric 'nope'"):
        shapebench.load_results("synthetic", metric="nope", workspace=ws)

    # The notebook example of docs/python.md, as a user would run it.
    out = subprocess.run(
        [sys.executable, str(ROOT / "docs" / "examples" / "notebook.py"), str(ws)],
        cwd=ws,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    assert "gauss vs gauss[sigma=0.05] at 50 points: 11 pairs" in out.stdout
    assert (ws / "notebook-example.png").stat().st_size > 0


def test_an_empty_store_says_what_to_run(tmp_path):
    with pytest.raises(ShapebenchError, match="no finished runs of synthetic") as err:
        shapebench.load_results("synthetic", workspace=tmp_path)
    assert "shapebench run -m gauss -d synthetic" in err.value.hint
    with pytest.raises(ShapebenchError, match="no finished runs of synthetic/trained"):
        shapebench.load_leaderboard("synthetic", "trained", workspace=tmp_path)


#: conftest.TINY as Python values, the way a notebook passes them.
TINY_OPTIONS = {
    "test_per_category": 1,
    "train_per_category": 1,
    "surface_candidates": 3000,
    "gt_points": 2000,
}


@pytest.mark.slow  # runs cells, then the CLI
def test_evaluate_runs_the_cells_the_cli_then_finds_cached(shapebench):
    ws = shapebench.workspace
    where = {"workspace": ws, "cache_dir": shapebench.cache}
    scores = shapebench_api.evaluate(
        "gauss",
        "synthetic",
        contexts=(50, 100),
        split="trained",
        options={"sigma": 0.05},
        dataset_options=TINY_OPTIONS,
        progress=False,
        **where,
    )
    assert list(scores.columns[: len(RESULT_COLUMNS)]) == list(RESULT_COLUMNS)
    assert set(scores.label) == {"gauss[sigma=0.05]"} and set(scores.context) == {50, 100}
    assert len(scores) == 2 * 11 and not scores.failed.any()
    assert scores["chamfer-l2"].notna().all()

    # The command with the same options, given as text, finds every cell: the same keys.
    res = shapebench(
        "run",
        "-m",
        "gauss",
        "-d",
        "synthetic",
        "--split",
        "trained",
        *TINY,
        *TINY_CONTEXTS,
        "-O",
        "sigma=0.05",
        "-q",
    )
    assert res.returncode == 0, res.stderr
    states = [line.split()[-1] for line in res.stdout.splitlines() if line.strip()[:1].isdigit()]
    assert states == ["cached", "cached"], res.stdout

    # Called again, it recomputes nothing and returns the same rows.
    again = shapebench_api.evaluate(
        "gauss",
        "synthetic",
        contexts=[50, 100],
        split=["trained"],
        options={"sigma": 0.05},
        dataset_options=TINY_OPTIONS,
        progress=False,
        **where,
    )
    pd.testing.assert_frame_equal(again, scores)
    # What it returns is what load_results reads from the store.
    stored = shapebench_api.load_results("synthetic", "trained", workspace=ws)
    pd.testing.assert_frame_equal(stored, scores)


def test_evaluate_names_a_bad_argument(tmp_path):
    with pytest.raises(ShapebenchError, match="trainer= has no option 'max_step'") as err:
        shapebench_api.evaluate("gauss", "synthetic", trainer={"max_step": 5}, workspace=tmp_path)
    assert "max_steps" in err.value.hint
    with pytest.raises(ShapebenchError, match="contexts= must be an int or a sequence of ints"):
        shapebench_api.evaluate("gauss", "synthetic", contexts="50,100", workspace=tmp_path)
    with pytest.raises(ShapebenchError, match="unknown method 'nope'"):
        shapebench_api.evaluate("nope", "synthetic", workspace=tmp_path)
