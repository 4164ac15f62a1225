"""benchmarks/bench_scale.py at toy size: every timed command sees all N cells of a store whose
searches take several pages (MLflow's page size lowered below N, as tests/store/test_paging.py
does), and the script fails when a command reads one page only."""

from __future__ import annotations

import pytest
from conftest import load_benchmark

from shapebench.store import paging

pytestmark = pytest.mark.slow  # computes a sweep's seed 0, then runs four commands on the store

CELLS = 16  # four seeds x two splits x two context sizes
PAGE = 5  # fewer than the cells of one experiment (8) and of the store (16)


def test_every_command_sees_every_cell_across_pages(data_cache, tmp_path):
    bench = load_benchmark("bench_scale")
    lines = bench.run([CELLS], PAGE, data_cache, tmp_path / "stores")
    counted = lines[-1]
    assert f"{CELLS} cells, {CELLS} finished" in counted
    assert f"= {CELLS} cells" in counted  # the leaderboard's (object, seed) rows
    assert f"runs --json: {CELLS} runs" in counted
    assert f"merge: {CELLS} cell runs added" in counted
    assert paging.PAGE == 10_000  # restored for the tests that follow


def one_page(client, experiment_ids, filter_string="", order_by=None, limit=None, page_size=None):
    """A search that reads MLflow's first page only: what a command did before paging."""
    want = paging.PAGE if limit is None else min(paging.PAGE, limit)
    return list(
        client.search_runs(
            list(experiment_ids),
            filter_string=filter_string,
            max_results=want,
            order_by=list(order_by) if order_by else None,
        )
    )


@pytest.mark.parametrize(
    ("module", "command"),
    [
        # The tracker's searches serve the sweep's plan first (then the leaderboard).
        ("shapebench.store.tracking", "sweep --status"),
        ("shapebench.store.listing", "runs --json"),
        ("shapebench.store.merge", "merge"),
    ],
)
def test_a_command_reading_one_page_fails_the_benchmark(
    data_cache, tmp_path, monkeypatch, module, command
):
    bench = load_benchmark("bench_scale")
    monkeypatch.setattr(f"{module}.search_all_runs", one_page)
    with pytest.raises(bench.ScaleError, match=f"{command} did not see every cell"):
        bench.run([CELLS], PAGE, data_cache, tmp_path / "stores")
