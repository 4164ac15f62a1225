"""Leaderboards are computed from the runs in MLflow, per object, like the paper's tables."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import TINY, TINY_CONTEXTS

from shapebench.api.errors import ShapebenchError
from shapebench.boards.leaderboard import BoardQuery, build_board
from shapebench.config import make_settings
from shapebench.store.records import CellRecord
from shapebench.store.tracking import Tracker


def _per_object(sb, method: str, k: int) -> pd.DataFrame:
    tags = {"method": method, "context_size": str(k)}
    run = next(r for r in sb.cell_runs("synthetic-novel") if tags.items() <= r.data.tags.items())
    dst = sb.workspace / f"dl-{method}-{k}"
    dst.mkdir(exist_ok=True)
    return pd.read_csv(sb.client().download_artifacts(run.info.run_id, "per_object.csv", str(dst)))


@pytest.mark.slow  # runs the CLI in subprocesses
def test_leaderboard_raw_and_normalised_from_mlflow(with_example):
    sb = with_example
    for method in ("gauss", "example-sphere"):
        assert (
            sb(
                "run",
                "-m",
                method,
                "-d",
                "synthetic",
                *TINY,
                *TINY_CONTEXTS,
                "-q",
                "--split",
                "novel",
            ).returncode
            == 0
        )
    res = sb("leaderboard", "--dataset", "synthetic", "--split", "novel", "--reference", "gauss")
    assert res.returncode == 0, res.stderr
    md = (sb.workspace / "leaderboards" / "synthetic-novel.md").read_text()
    csv = pd.read_csv(sb.workspace / "leaderboards" / "synthetic-novel.csv")
    assert "squared Euclidean NN distances" in md and "2000 eval points" in md
    assert "| Gauss densification (`gauss`) |" in md
    assert "| Sphere fit (example) (`example-sphere`) |" in md
    # one seed: samples are objects, and the row list says which seed
    assert "Raw: mean ± std over objects" in md and "* `gauss`: gauss, " in md
    assert next(line for line in md.splitlines() if line.startswith("* `gauss`")).endswith(
        "; seed 0"
    )

    # Recompute equation 8 by hand from the per-object artifacts.
    for k in (50, 100):
        g = _per_object(sb, "gauss", k).set_index("object")["chamfer-l2"]
        s = _per_object(sb, "example-sphere", k).set_index("object")["chamfer-l2"]
        raw = csv[(csv.kind == "raw") & (csv.method == "example-sphere") & (csv.context == k)]
        assert np.isclose(raw["mean"].item(), 1000 * s.mean())
        assert np.isclose(raw["std"].item(), 1000 * s.std(ddof=1))
        assert raw["n"].item() == 4 and raw["failures"].item() == 0
        ratio = (s / g.loc[s.index]).to_numpy()
        norm = csv[
            (csv.kind == "normalized") & (csv.method == "example-sphere") & (csv.context == k)
        ]
        assert np.isclose(norm["mean"].item(), ratio.mean())
        ref = csv[(csv.kind == "normalized") & (csv.method == "gauss") & (csv.context == k)]
        assert np.isclose(ref["mean"].item(), 1.0) and np.isclose(ref["std"].item(), 0.0)


@pytest.mark.slow  # runs the CLI in subprocesses
def test_leaderboard_without_reference_runs_says_so(shapebench):
    assert (
        shapebench(
            "run",
            "-m",
            "gauss",
            "-d",
            "synthetic",
            *TINY,
            "--contexts",
            "50",
            "-q",
            "--split",
            "novel",
        ).returncode
        == 0
    )
    res = shapebench("leaderboard", "--dataset", "synthetic")  # default reference: msc-noopt
    assert res.returncode == 0, res.stderr
    md = (shapebench.workspace / "leaderboards" / "synthetic-novel.md").read_text()
    assert "No runs of the reference 'msc-noopt'" in md
    assert "raw 50" in md


@pytest.mark.slow  # runs the CLI in subprocesses
def test_leaderboard_without_runs_is_a_clear_error(shapebench):
    res = shapebench("leaderboard", "--dataset", "synthetic")
    assert res.returncode == 2 and "no finished runs of dataset 'synthetic'" in res.stderr


def _log_cell(client, exp_id: str, method: str, card: str) -> None:
    """A finished cell run whose tags are the store's own record format (never hand-written
    tag strings: those drift from what the store reads)."""
    record = CellRecord(
        cell_key=f"cell-{method}",
        method=method,
        dataset="synthetic",
        split="novel",
        context_size=50,
        seed=0,
        cards={"chamfer-l2": card},
        display_name=method,
        fingerprint="f",
        variant_key=method,
        variant_label=method,
    )
    run = client.create_run(exp_id, tags=record.to_tags())
    client.set_terminated(run.info.run_id)


@pytest.mark.slow  # builds an MLflow store: about 6 s
def test_leaderboard_refuses_to_mix_metric_cards(tmp_path):
    settings = make_settings(f"sqlite:///{tmp_path / 'mlflow.db'}", tmp_path, "quick", tmp_path)
    tracker = Tracker(settings)
    exp = tracker.experiment_id("synthetic-novel")
    card = "metric=chamfer-l2;power=2;reduction=mean;direction=symmetric;halved=False;scale=1000.0"
    _log_cell(tracker.client, exp, "a", card + ";frame=unit-radius;eval_points=30000")
    _log_cell(tracker.client, exp, "b", card + ";frame=unit-radius;eval_points=16384")
    with pytest.raises(
        ShapebenchError,
        match="different cards.*used by a.*used by b|different cards.*used by b.*used by a",
    ):
        build_board(tracker, BoardQuery("synthetic", "a", "chamfer-l2"), "novel")


def test_a_row_lists_its_seeds_and_each_seeds_checkpoint():
    from shapebench.boards.leaderboard import _rows

    def run(key: str, seed: int, start: int, ckpt: str) -> dict:
        return {
            "variant_key": key,
            "_label": key,
            "method": key,
            "display_name": key,
            "variant_overrides": "{}",
            "method_code": "c0de",
            "checkpoint_key": ckpt,
            "seed": str(seed),
            "start": start,
        }

    runs = pd.DataFrame(
        [
            run("igr", 1, 1, "k1-old"),
            run("igr", 0, 2, "k0"),
            run("igr", 1, 3, "k1"),
            run("igr", 2, 4, "k2"),
            run("gauss", 0, 5, ""),
        ]
    )
    rows = {r.label: r for r in _rows(runs)}
    # seed order, and the newest run of a seed (a --force rerun) names its checkpoint
    assert rows["igr"].seeds == (0, 1, 2)
    assert rows["igr"].checkpoints == ((0, "k0"), (1, "k1"), (2, "k2"))
    assert rows["gauss"].seeds == (0,) and rows["gauss"].checkpoints == ()


@pytest.mark.slow  # builds an MLflow store: about 6 s
def test_splits_come_in_the_order_the_dataset_declares(tmp_path):
    """Trained before novel (the paper's Table 1, then Table 2), not alphabetically; a split no
    dataset declares comes last; a dataset not installed here falls back to the built-in order."""
    from shapebench.boards.splits import splits_with_runs

    settings = make_settings(f"sqlite:///{tmp_path / 'mlflow.db'}", tmp_path, "quick", tmp_path)
    tracker = Tracker(settings)
    for name in (
        "synthetic-novel",
        "synthetic-extra",
        "synthetic-trained",
        "synthetic-train",
        "gone-novel",
        "gone-trained",
    ):
        tracker.experiment_id(name)
    assert splits_with_runs(tracker, "synthetic") == ["trained", "novel", "extra"]
    assert splits_with_runs(tracker, "gone") == ["trained", "novel"]
