"""The cell record: what the runner writes as tags is what resume and leaderboards read back."""

from __future__ import annotations

from shapebench.api.metric import MetricCard
from shapebench.store.records import CellRecord

CARD = MetricCard("chamfer-l2", 2, "mean", "symmetric", False, 1000.0, "unit-radius", 2000)


def _record(**kw) -> CellRecord:
    values = dict(
        cell_key="k1",
        method="igr",
        dataset="synthetic",
        split="novel",
        context_size=50,
        seed=3,
        cards={"chamfer-l2": CARD.as_tag()},
        trains=True,
        frame="unit-diameter",
        context_normals=True,
        variant_key="v1",
        variant_label="igr[epochs=3]",
        variant_overrides={"epochs": 3},
        metric_errors=("crashy",),
        eval_points_actual=1500,
        checkpoint_key="c1",
    )
    values.update(kw)
    return CellRecord(**values)


def test_tags_round_trip_to_the_same_typed_record():
    record = _record()
    tags = record.to_tags()
    assert all(isinstance(v, str) for v in tags.values())
    assert tags["shapebench.kind"] == "cell" and tags["context_size"] == "50"
    back = CellRecord.from_tags(tags)
    assert back == record
    assert back.card("chamfer-l2") == CARD and back.card("fscore") is None


def test_tags_of_an_older_store_read_with_defaults():
    old = {
        "shapebench.kind": "cell",
        "shapebench.cell_key": "k0",
        "method": "gauss",
        "dataset": "synthetic",
        "split": "novel",
        "context_size": "100",
        "seed": "0",
        "card.chamfer-l2": CARD.as_tag(),
    }
    record = CellRecord.from_tags(old)
    assert (record.context_size, record.seed, record.variant_key) == (100, 0, "")
    assert record.metric_errors == () and record.cards == {"chamfer-l2": CARD.as_tag()}


def test_a_row_is_keyed_by_field_name_with_typed_values():
    row = _record().row()
    assert row["context_size"] == 50 and row["variant_key"] == "v1"
    assert row["card.chamfer-l2"] == CARD.as_tag() and row["metric_errors"] == "crashy"
