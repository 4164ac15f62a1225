"""``shapebench ui`` as a person uses it: start it on a free port, open the links it prints in a
real headless Chromium (Debian's, driven by playwright), and look: the runs table shows the run
names and the Chamfer column, the chart view draws one line per method variant. Screenshots are
kept with the test's files (and copied to ``$SHAPEBENCH_TEST_ARTIFACTS`` when set, for CI to
upload; docs/images/ui-*.png are copies of them). A taken port is refused before anything is
printed.
"""

from __future__ import annotations

import re
import socket
import subprocess

import pytest
from browser_support import keep_screenshot, launch_chromium, stop_server, wait_http
from conftest import TINY, Shapebench, free_port

#: The React app loads and queries the store after the page: generous on 2 shared cores.
UI_TIMEOUT_MS = 90_000
VARIANTS = {"gauss": [], "gauss[sigma=0.05]": ["-O", "sigma=0.05"]}


@pytest.fixture(scope="module")
def store(tmp_path_factory, data_cache) -> Shapebench:
    """Two variants of gauss at three context sizes on the tiny benchmark's novel split."""
    sb = Shapebench(tmp_path_factory.mktemp("ui-ws"), data_cache)
    for extra in VARIANTS.values():
        res = sb(
            "run",
            "-m",
            "gauss",
            "-d",
            "synthetic",
            *TINY,
            "--split",
            "novel",
            "--contexts",
            "50,100,300",
            "-q",
            *extra,
        )
        assert res.returncode == 0, res.stderr
    return sb


def _links(proc: subprocess.Popen, port: int) -> tuple[str, str]:
    """The runs-table and chart links ``shapebench ui`` printed for synthetic-novel."""
    first = proc.stdout.readline()
    assert first.startswith(f"MLflow UI: http://127.0.0.1:{port}  (store sqlite:///"), first
    lines = [proc.stdout.readline() for _ in range(3)]
    runs = re.search(r"synthetic-novel \(\d+ runs\): (\S+)", lines[1])
    charts = re.search(r"charts: (\S+)", lines[2])
    assert runs and charts, lines
    return runs.group(1), charts.group(1)


@pytest.mark.slow
@pytest.mark.server
def test_ui_links_open_runs_table_and_charts_in_chromium(store, tmp_path):
    from playwright.sync_api import sync_playwright

    client = store.client()
    exp = client.get_experiment_by_name("synthetic-novel")
    parents = {
        r.info.run_name: r
        for r in client.search_runs([exp.experiment_id], "tags.`shapebench.kind` = 'parent'")
    }
    names = {f"{v} on synthetic/novel" for v in VARIANTS}
    assert set(parents) == names
    port = free_port()
    proc = store.popen("ui", "--port", str(port), start_new_session=True)
    shots = tmp_path / "screenshots"
    shots.mkdir()
    try:
        runs_url, charts_url = _links(proc, port)
        base = f"http://127.0.0.1:{port}/#/experiments/{exp.experiment_id}/runs"
        assert runs_url.startswith(base) and charts_url.startswith(base)
        wait_http(f"http://127.0.0.1:{port}/health", proc)
        with sync_playwright() as p:
            browser = launch_chromium(p)
            page = browser.new_page(viewport={"width": 1600, "height": 820})
            page.goto(runs_url, timeout=UI_TIMEOUT_MS)
            # The runs table: a row per variant (children folded under it), and the Chamfer
            # column shown without opening "Columns".
            for name in names:
                page.get_by_text(name, exact=True).first.wait_for(timeout=UI_TIMEOUT_MS)
            assistant = page.get_by_role("button", name="Close", exact=True)
            if assistant.count():  # MLflow's chat panel, opened on a first visit: room for runs
                assistant.first.click()
            header = page.get_by_role("columnheader", name=re.compile(r"chamfer-l2\.mean"))
            header.first.wait_for(timeout=UI_TIMEOUT_MS)
            for run in parents.values():
                # The grid's rows are keyed by run id; the parent's value is its latest step:
                # the cells' mean at k=300.
                cell = page.locator(
                    f'[role=row][row-id="{run.info.run_id}"] [col-id="metrics.`chamfer-l2.mean`"]'
                )
                shown = float(cell.first.inner_text(timeout=UI_TIMEOUT_MS))
                assert shown == pytest.approx(run.data.metrics["chamfer-l2.mean"], rel=1e-9)
            page.screenshot(path=shots / "ui-runs-table.png")
            keep_screenshot(shots / "ui-runs-table.png")

            # The chart view: the metric against context size, one line per variant.
            page.goto(charts_url, timeout=UI_TIMEOUT_MS)
            for name in names:
                page.get_by_text(f"{name} (chamfer-l2.mean)").first.wait_for(timeout=UI_TIMEOUT_MS)
            page.get_by_text("Step", exact=True).first.wait_for(timeout=UI_TIMEOUT_MS)
            page.screenshot(path=shots / "ui-charts.png")
            keep_screenshot(shots / "ui-charts.png")
            browser.close()
    finally:
        stop_server(proc)
    for shot in ("ui-runs-table.png", "ui-charts.png"):
        assert (shots / shot).stat().st_size > 10_000  # a drawn page, not an empty one


def test_ui_refuses_a_taken_port_before_printing_anything(shapebench):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        res = shapebench("ui", "--port", str(port), timeout=60)
    assert res.returncode == 2
    assert res.stdout == ""  # no URL of a server that is not ours
    assert f"port {port} on 127.0.0.1 is already in use" in res.stderr
    assert f"shapebench ui --port {port + 1}" in res.stderr
