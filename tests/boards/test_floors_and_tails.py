"""Floors, tails and categories (issue 58): a row not significantly better than the better
floor (given-points, retrieval) is marked, beside each mean stand its median and the share of
samples beyond the card's tail threshold, and each category's mean and median are written out.
The arithmetic is checked on hand-made per-object tables, the board on a tiny MLflow store."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from shapebench.api.metric import MetricCard
from shapebench.boards import stats as board_stats

OBJECTS = 20


def _scored(values: dict[str, np.ndarray], ctx: int = 1000) -> pd.DataFrame:
    """A per-object table under the failure rule: one seed, every object ok."""
    rows = [
        {
            "variant": variant,
            "label": variant,
            "context": ctx,
            "seed": 0,
            "object": f"cat{i % 2}/o{i:02d}",
            "category": f"cat{i % 2}",
            "status": "ok",
            "value": float(v),
        }
        for variant, vs in values.items()
        for i, v in enumerate(vs)
    ]
    return board_stats.with_failure_rule(pd.DataFrame(rows))


def _floor_values() -> np.ndarray:
    return np.linspace(1.0, 3.0, OBJECTS)


def test_a_row_is_marked_unless_it_is_significantly_better_than_the_floor():
    floor = _floor_values()
    # Lower by 0.005 in mean, but up and down by as much from object to object (p about 0.85).
    wiggle = np.array([(-1) ** i * (i + 1) * 0.01 for i in range(OBJECTS)])
    scored = _scored(
        {
            "given-points": floor,
            "good": floor - 0.5,  # lower on every object
            "bad": floor + 0.5,
            "close": floor + wiggle,
        }
    )
    table = board_stats.floor_test(scored, ["given-points"]).set_index("variant")
    assert set(table.index) == {"good", "bad", "close"}  # the floor is not tested against itself
    assert (table["floor"] == "given-points").all()
    assert not table.loc["good", "below_floor"]
    assert table.loc["bad", "below_floor"]
    # a lower mean is not enough: the paired test must say so
    assert scored[scored.variant == "close"]["scored"].mean() < floor.mean()
    assert table.loc["close", "p_floor_holm"] >= board_stats.ALPHA
    assert table.loc["close", "below_floor"]
    # Holm across the three rows at this size
    assert np.allclose(table["p_floor_holm"], board_stats.holm(list(table["p_vs_floor"])))


def test_the_better_floor_is_the_floor_and_missing_floors_are_no_error():
    floor = _floor_values()
    scored = _scored({"given-points": floor, "retrieval": floor - 0.5, "good": floor - 0.2})
    table = board_stats.floor_test(scored, ["given-points", "retrieval"]).set_index("variant")
    assert (table["floor"] == "retrieval").all()
    # better than given-points, but not than retrieval; the floors themselves are not tested
    assert table.loc["good", "below_floor"] and list(table.index) == ["good"]
    # higher-is-better: the floor with the higher mean, and only a higher row beats it
    scored = _scored({"given-points": floor, "retrieval": floor - 0.5, "good": floor + 0.2})
    up = board_stats.floor_test(scored, ["given-points", "retrieval"], higher_is_better=True)
    assert (up["floor"] == "given-points").all()
    up = up.set_index("variant")
    assert not up.loc["good", "below_floor"] and list(up.index) == ["good"]
    # no floor row in the table: nothing tested, nothing marked
    assert board_stats.floor_test(scored, ["nowhere"]).empty
    assert board_stats.floor_test(scored, []).empty


def test_a_floor_named_by_its_method_is_found_in_a_table_of_another_profile_or_protocol():
    """A crop sweep at the quick profile labels every row ``[crop=0.5,profile=quick]``: the
    floors (and the reference) are still its rows of those methods, and not a row whose method
    options differ."""
    from shapebench.boards.board import Row
    from shapebench.boards.leaderboard import _floor_rows

    def row(variant: str, method: str, **overrides) -> Row:
        return Row(variant, f"{method}{sorted(overrides.items())}", method, method, overrides)

    rows = [
        row("r", "retrieval", crop=0.5, profile="quick"),
        row("g", "gauss", crop=0.5, profile="quick"),
        row("g0", "gauss", crop=0.5, profile="quick", sigma=0.0),
        row("m", "msc-noopt", protocol="depth", noise=0.005),
    ]
    rows[2] = Row("g0", "given-points", "gauss", "gauss", rows[2].overrides)
    assert _floor_rows(rows, ("given-points", "retrieval")) == ["g0", "r"]
    assert _floor_rows(rows, ("msc-noopt",)) == ["m"]
    # a method row with an option of its own is not the method's floor row
    assert _floor_rows([row("g1", "gauss", sigma=0.05)], ("gauss",)) == []


def test_median_and_tail_share_equal_hand_computed_ones():
    values = np.array([0.001, 0.002, 0.004, 0.02, 0.05])
    failed = _scored({"m": np.r_[values, 0.5]})
    failed.loc[failed.index[-1], "status"] = "failed"  # scores as the worst success: 0.05
    failed = board_stats.with_failure_rule(failed.drop(columns="scored"))
    raw = board_stats.raw_table(failed, tail=0.01).iloc[0]
    under_rule = np.r_[values, 0.05]
    assert raw["median"] == pytest.approx(np.median(under_rule))
    assert raw["tail_share"] == pytest.approx(3 / 6)  # 0.02, 0.05 and the failure
    up = board_stats.raw_table(failed, tail=0.01, higher_is_better=True).iloc[0]
    assert up["tail_share"] == pytest.approx(3 / 6)  # 0.001, 0.002, 0.004
    assert "tail_share" not in board_stats.raw_table(failed)  # no threshold, no column


def test_category_table_equals_hand_computed_means_and_medians():
    floor = _floor_values()
    cats = board_stats.category_table(_scored({"a": floor})).set_index("category")
    for name, picked in (("cat0", floor[0::2]), ("cat1", floor[1::2])):
        assert cats.loc[name, "mean"] == pytest.approx(picked.mean())
        assert cats.loc[name, "median"] == pytest.approx(np.median(picked))
        assert cats.loc[name, "n"] == OBJECTS // 2


def test_the_tail_threshold_is_no_part_of_the_tag_or_the_cell_key():
    from shapebench.metrics.chamfer import ChamferL1, ChamferL2

    card = ChamferL2().card(30000)
    assert card.tail_threshold == 10.0
    assert "tail" not in card.as_tag()
    assert card.as_tag() == CARD  # the tag (and so the cell key) of every stored cell
    assert MetricCard.from_tag(card.as_tag()) == card  # equality ignores it
    assert ChamferL1().card(30000).tail_threshold is None
    with pytest.raises(ValueError, match="tail_threshold"):
        MetricCard(**{**card.__dict__, "tail_threshold": float("nan")}).validate()


def test_the_card_threshold_follows_the_frame():
    from shapebench.boards.cards import tail_threshold

    card = MetricCard.from_tag(
        "metric=chamfer-l2;power=2;reduction=mean;direction=symmetric;halved=False;scale=1000.0;"
        "frame=unit-radius;eval_points=30000"
    )
    assert tail_threshold("chamfer-l2", card.as_tag()) == 10.0
    # squared distances at half the scale: a quarter
    assert tail_threshold("chamfer-l2", card.in_frame("unit-diameter").as_tag()) == 2.5
    assert tail_threshold("chamfer-l1", card.as_tag().replace("l2", "l1")) is None


# -- a tiny store ------------------------------------------------------------------------------

CARD = (
    "metric=chamfer-l2;power=2;reduction=mean;direction=symmetric;halved=False;scale=1000.0;"
    "frame=unit-radius;eval_points=30000"
)


def _log_cell(
    tracker, root: Path, exp_id: str, label: str, method: str, overrides: dict, values
) -> None:
    """A finished cell with its per-object table, through the store's own record format."""
    from shapebench.store.records import CellRecord

    record = CellRecord(
        cell_key=f"cell-{label}",
        method=method,
        dataset="synthetic",
        split="novel",
        context_size=1000,
        seed=0,
        cards={"chamfer-l2": CARD},
        display_name=method,
        fingerprint="f",
        variant_key=f"key-{label}",
        variant_label=label,
        variant_overrides=overrides,
    )
    run = tracker.client.create_run(exp_id, tags=record.to_tags())
    table = pd.DataFrame(
        {
            "object": [f"cat{i % 2}/o{i:02d}" for i in range(len(values))],
            "category": [f"cat{i % 2}" for i in range(len(values))],
            "status": "ok",
            "chamfer-l2": values,
            "seconds": 0.01,
        }
    )
    folder = root / label
    folder.mkdir()
    table.to_csv(folder / "per_object.csv", index=False)
    tracker.client.log_artifact(run.info.run_id, str(folder / "per_object.csv"))
    tracker.client.set_terminated(run.info.run_id)


@pytest.fixture(scope="module")
def tiny_store(tmp_path_factory):
    from shapebench.config import make_settings
    from shapebench.store.tracking import Tracker

    root = tmp_path_factory.mktemp("floors")
    settings = make_settings(f"sqlite:///{root / 'mlflow.db'}", root, "quick", root)
    tracker = Tracker(settings)
    exp = tracker.experiment_id("synthetic-novel")
    floor = _floor_values() / 200  # 5 to 15 x1000: half of the objects above 10
    _log_cell(tracker, root, exp, "given-points", "gauss", {"sigma": 0.0}, floor)
    _log_cell(tracker, root, exp, "good", "good", {}, floor - 0.002)
    _log_cell(tracker, root, exp, "bad", "bad", {}, floor * 3)
    return tracker, floor


@pytest.mark.slow  # builds an MLflow store: about 6 s
def test_a_board_marks_rows_below_the_floor_and_writes_tails_and_categories(tiny_store):
    from shapebench.boards.leaderboard import BoardQuery, build_board
    from shapebench.boards.markdown import render_markdown
    from shapebench.boards.tidy import category_csv, tidy_csv

    tracker, floor = tiny_store
    board = build_board(tracker, BoardQuery("synthetic", "given-points"), "novel")
    md = render_markdown(board, "shapebench leaderboard", "uri")
    lines = {
        label: next(line for line in md.splitlines() if f"(`{label}`)" in line)
        for label in ("given-points", "good", "bad")
    }
    assert "†" in lines["bad"] and "†" not in lines["good"] + lines["given-points"]
    assert "†: not significantly better than the floor row `given-points`" in md
    assert "tail threshold 10 (x1000)" in md

    csv = tidy_csv(board)
    raw = csv[csv.kind == "raw"].set_index("label")
    assert raw.loc["bad", "below_floor"] and not raw.loc["good", "below_floor"]
    assert (raw["floor"] == "given-points").all()
    bad = floor * 3 * 1000
    assert raw.loc["bad", "median"] == pytest.approx(np.median(bad))
    assert raw.loc["bad", "tail_share"] == pytest.approx(np.mean(bad > 10))
    assert raw.loc["given-points", "tail_share"] == pytest.approx(np.mean(floor * 1000 > 10))
    assert (raw["tail_threshold"] == 10).all()
    assert f"med. {np.median(bad):.2f}; {100 * np.mean(bad > 10):.0f}% > 10" in lines["bad"]

    cats = category_csv(board).set_index(["label", "category"])
    assert list(cats.index.get_level_values(0).unique()) == [r.label for r in board.rows]
    for name, picked in (("cat0", bad[0::2]), ("cat1", bad[1::2])):
        assert cats.loc[("bad", name), "mean"] == pytest.approx(picked.mean())
        assert cats.loc[("bad", name), "median"] == pytest.approx(np.median(picked))
        assert cats.loc[("bad", name), "n"] == len(picked)
    # the CSV's category_mean is the mean of these means
    assert raw.loc["bad", "category_mean"] == pytest.approx(cats.loc["bad", "mean"].mean())

    # --floor none, and floors without rows: no marks, no error
    for floors in ((), ("retrieval",)):
        none = build_board(tracker, BoardQuery("synthetic", "given-points", floors=floors), "novel")
        assert none.floors is None and "†" not in render_markdown(none, "c", "u")
        assert tidy_csv(none)["below_floor"].isna().all()
    # --tail-threshold overrides the card's
    other = build_board(tracker, BoardQuery("synthetic", "given-points", tail=20.0), "novel")
    share = tidy_csv(other).set_index(["kind", "label"]).loc[("raw", "bad"), "tail_share"]
    assert share == pytest.approx(np.mean(bad > 20))


@pytest.mark.slow  # builds an MLflow store and the page
def test_the_report_says_which_rows_are_not_better_than_the_floor(tiny_store):
    from shapebench.boards.html_report import Section, render_html
    from shapebench.boards.html_tables import floor_sentences
    from shapebench.boards.leaderboard import BoardQuery, build_board

    tracker, _ = tiny_store
    board = build_board(tracker, BoardQuery("synthetic", "given-points"), "novel")
    assert floor_sentences(board) == [
        "At 1000 points 1 of 2 rows are not better than the floor (given-points): bad."
    ]
    page = render_html([Section(board, {})], "synthetic", "shapebench report", "uri")
    assert "not better than the floor (given-points): bad." in page
    assert "Per category" in page and ">cat0</th>" in page
    assert page.count(" †") == 1


def test_the_worst_sample_is_the_highest_or_the_lowest_when_higher_is_better():
    floor = _floor_values()
    scored = _scored({"a": floor, "b": floor[::-1]})
    worst = board_stats.worst_samples(scored).set_index("variant")
    assert worst.loc["a", "object"] == f"cat1/o{OBJECTS - 1:02d}" and worst.loc["a", "scored"] == 3
    assert worst.loc["b", "object"] == "cat0/o00"
    best = board_stats.worst_samples(scored, higher_is_better=True).set_index("variant")
    assert best.loc["a", "object"] == "cat0/o00" and best.loc["a", "scored"] == 1
