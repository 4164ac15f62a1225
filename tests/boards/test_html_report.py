"""``shapebench report`` as a person uses it: run two methods, build the page, open it in a real
headless Chromium and look: the tables render and sort, the figures and the qualitative grids
are drawn, nothing is fetched from the network. Screenshots are kept with the test's files
(and copied to ``$SHAPEBENCH_TEST_ARTIFACTS`` when set, for CI to upload).

Also: every method's cells picture the same objects, and posterior samples show as a spread
picture in the report.
"""

from __future__ import annotations

import base64
import io
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh
from browser_support import keep_screenshot, launch_chromium
from conftest import TINY, Shapebench
from matplotlib.image import imread

from shapebench.evaluation.pictures import file_stem, is_blank, picture_objects

pytestmark = pytest.mark.slow  # runs the CLI, MLflow and a browser

CONTEXTS = "50,100"


@pytest.fixture(scope="module")
def store(tmp_path_factory, data_cache, example_site) -> Shapebench:
    """Two methods on the tiny benchmark's novel split, and the report built from them."""
    ws = tmp_path_factory.mktemp("report-ws")
    sb = Shapebench(ws, data_cache, (example_site,))
    for method in ("gauss", "example-sphere"):
        res = sb(
            "run",
            "-m",
            method,
            "-d",
            "synthetic",
            *TINY,
            "--contexts",
            CONTEXTS,
            "-q",
            "--split",
            "novel",
        )
        assert res.returncode == 0, res.stderr
    res = sb("report", "-d", "synthetic", "--reference", "gauss")
    assert res.returncode == 0, res.stderr
    print(res.stdout.strip())  # "wrote ... in N s": the report's generation time
    return sb


def _cells(sb: Shapebench, method: str) -> dict[int, object]:
    return {
        int(r.data.tags["context_size"]): r
        for r in sb.cell_runs("synthetic-novel")
        if r.data.tags["method"] == method
    }


def test_every_method_pictures_the_same_objects(store, tmp_path):
    client = store.client()
    seen = {}
    for method in ("gauss", "example-sphere"):
        for k, run in _cells(store, method).items():
            rid = run.info.run_id
            names = sorted(a.path for a in client.list_artifacts(rid, "pictures"))
            print(
                f"{method} k={k}: pictures logged in {run.data.metrics['pictures_seconds']:.2f} s"
            )
            # Four novel objects: the first, one in the middle and the last are pictured, and
            # the cell's worst success when it is not one of them.
            table = client.download_artifacts(rid, "per_object.csv", str(tmp_path / rid))
            ids = pd.read_csv(table)["object"].tolist()  # every object, in the split's order
            fixed = {f"pictures/{file_stem(o)}.png" for o in picture_objects(ids)}
            pngs = {n for n in names if n.endswith(".png")}
            assert len(fixed) == 3 and fixed <= pngs and len(pngs) <= 4
            seen[(method, k)] = sorted(fixed)
            dst = tmp_path / f"{method}-{k}"
            dst.mkdir()
            folder = Path(client.download_artifacts(rid, "pictures", str(dst)))
            contexts = np.load(client.download_artifacts(rid, "contexts.npz", str(dst)))
            by_object = dict(zip(contexts["objects"], contexts["points"], strict=True))
            for png in folder.glob("*.png"):
                assert not is_blank(png.read_bytes())
                assert imread(io.BytesIO(png.read_bytes()), format="png").shape[1] > 300
                arrays = np.load(png.with_suffix(".npz"))
                obj = png.stem.replace("__", "/")
                # The picture shows exactly the points the method was given, and the truth.
                assert np.array_equal(arrays["context"], by_object[obj])
                assert arrays["ground_truth"].shape == (2000, 3)  # -D gt_points=2000
            plys = {Path(a.path).stem for a in client.list_artifacts(rid, "completions")}
            assert plys == {Path(n).stem for n in pngs}
    assert len({tuple(v) for v in seen.values()}) == 1, seen


def test_report_opens_in_chromium_with_tables_figures_and_grids(store, tmp_path):
    from playwright.sync_api import sync_playwright

    page_path = store.workspace / "leaderboards" / "synthetic-report.html"
    text = page_path.read_text()
    # Self-contained: no remote scripts, styles or images (XML namespaces are names, not links).
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)|url\(\s*["']?https?:""", text)
    assert "<script src" not in text and "<link" not in text
    shots = tmp_path / "screenshots"
    shots.mkdir()
    requests, errors = [], []
    with sync_playwright() as p:
        browser = launch_chromium(p)
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        page.on("request", lambda r: requests.append(r.url))
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(page_path.as_uri())
        page.wait_for_load_state("load")

        # The raw table: one row per method, one column per context size, the winner marked.
        raw = page.locator("#raw-novel")
        assert raw.is_visible()
        heads = raw.locator("thead th").all_inner_texts()
        assert heads[:3] == ["method", "50", "100"] and "test time / object" in heads
        labels = raw.locator("tbody tr td:first-child").all_inner_texts()
        assert sorted(labels) == ["example-sphere", "gauss"]
        assert raw.locator("td.best").count() == 2  # one winner per context size
        assert page.locator("ul.winners li").count() == 2
        assert page.locator("#norm-novel tbody tr").count() == 2

        # Sorting: click the "100" header, ascending then descending by the numbers.
        def column(i: int) -> list[float]:
            return [
                float(v)
                for v in raw.locator(f"tbody tr td:nth-child({i})").evaluate_all(
                    "cells => cells.map(c => c.dataset.sort)"
                )
            ]

        raw.locator("thead th", has_text="100").click()
        assert column(3) == sorted(column(3))
        raw.locator("thead th", has_text="100").click()
        assert column(3) == sorted(column(3), reverse=True)
        page.screenshot(path=str(shots / "report-top.png"))

        # Figures: two inline SVGs per split, laid out with a real size, with both rows named.
        for name in ("chamfer", "pareto"):
            fig = page.locator(f"#fig-{name}-novel svg")
            fig.scroll_into_view_if_needed()
            box = fig.bounding_box()
            assert box and box["width"] > 300 and box["height"] > 150
            assert "gauss" in fig.inner_html() and "example-sphere" in fig.inner_html()
            fig.screenshot(path=str(shots / f"figure-{name}.png"))
        # The qualitative grids: decoded images (data URIs), not broken ones.
        grids = page.locator("img[alt^='qualitative grid']")
        assert grids.count() == 3
        widths = grids.evaluate_all("imgs => imgs.map(i => i.complete ? i.naturalWidth : 0)")
        assert all(w > 300 for w in widths), widths
        grids.first.scroll_into_view_if_needed()
        grids.first.screenshot(path=str(shots / "grid.png"))
        page.screenshot(path=str(shots / "report-full.png"), full_page=True)
        browser.close()
    assert not errors, errors
    assert all(u.startswith(("file:", "data:")) for u in requests), requests
    for shot in sorted(shots.glob("*.png")):
        assert not is_blank(shot.read_bytes()), shot
        keep_screenshot(shot)
    # The screenshot of a figure shows the plot, not an empty box: many distinct colours.
    pixels = imread(str(shots / "figure-chamfer.png"))[..., :3].reshape(-1, 3)
    assert len(np.unique(np.round(pixels, 2), axis=0)) > 30


def test_report_and_its_figures_are_logged_to_mlflow(store):
    client = store.client()
    exp = client.get_experiment_by_name("synthetic-novel")
    runs = client.search_runs([exp.experiment_id], "tags.`shapebench.kind` = 'leaderboard'")
    assert len(runs) == 1
    names = {a.path for a in client.list_artifacts(runs[0].info.run_id)}
    assert "synthetic-report.html" in names
    assert {"synthetic-novel-chamfer.svg", "synthetic-novel-pareto.png"} <= names
    assert any(n.startswith("synthetic-novel-grid-") for n in names)
    out = store.workspace / "leaderboards"
    assert (out / "synthetic-novel-chamfer.png").exists()
    # Provenance: the data version and the code that computed the runs.
    page = (out / "synthetic-report.html").read_text()
    tags = store.cell_runs("synthetic-novel")[0].data.tags
    assert f"fingerprint <code>{tags['dataset.fingerprint']}</code>" in page
    assert f"<code>{tags['git_commit']}</code>" in page
    assert "shapebench 0." in page and "mlflow " in page


def test_each_rows_worst_object_is_named_and_pictured_where_its_cell_pictured_it(store):
    """Per row its worst (object, seed) at the largest size, read from the per-object tables,
    and pictured from the cell's own picture of it."""
    from shapebench.boards.leaderboard import BoardQuery, build_board
    from shapebench.boards.report_pictures import worst_pictures
    from shapebench.config import make_settings
    from shapebench.store.tracking import Tracker

    settings = make_settings(store.tracking_uri, store.cache, "quick", store.workspace)
    tracker = Tracker(settings)
    board = build_board(tracker, BoardQuery("synthetic", "gauss"), "novel")
    worst = worst_pictures(tracker, board)
    assert [w[0] for w in worst] == [r.label for r in board.rows]
    pictured = 0
    for (_, obj, seed, value, status, uri), row in zip(worst, board.rows, strict=True):
        cell = board.scored[(board.scored.variant == row.variant) & (board.scored.context == 100)]
        assert value == pytest.approx(cell["scored"].max() * board.scale)
        assert cell.set_index(["object", "seed"]).loc[(obj, seed), "scored"] == cell["scored"].max()
        assert status == "ok"
        # Every cell pictures its worst success (the fixed objects' or one more).
        pictured += 1
        png = base64.b64decode(uri.split(",", 1)[1])
        assert not is_blank(png)
    page = (store.workspace / "leaderboards" / "synthetic-report.html").read_text()
    assert "Worst objects at 100 points" in page
    assert page.count('alt="worst object of ') == pictured


class _Primitives:
    """A tiny mesh dataset of four real primitives (one novel category)."""

    @staticmethod
    def build(tmp_path: Path):
        from shapebench.api.dataset import MeshDataset
        from shapebench.api.types import NOVEL, Category, ObjectRef

        shapes = {
            "box": lambda: trimesh.creation.box((1.0, 0.6, 0.4)),
            "ball": lambda: trimesh.creation.icosphere(3, 0.6),
            "can": lambda: trimesh.creation.cylinder(0.4, 1.2),
            "pill": lambda: trimesh.creation.capsule(0.8, 0.3),
        }

        class Primitives(MeshDataset):
            name = "primitives"

            def categories(self):
                return [Category("misc", NOVEL)]

            def objects(self, split):
                return [ObjectRef(k, "misc") for k in shapes] if split == NOVEL else []

            def mesh(self, ref):
                return shapes[ref.id]()

        options = Primitives.Options(surface_candidates=3000, gt_points=2000)
        return Primitives(options, tmp_path / "cache")


def test_posterior_samples_show_as_spread_pictures_in_the_report(tmp_path):
    from shapebench.api.method import Method
    from shapebench.api.types import NOVEL, Completion
    from shapebench.boards.html_report import build_report
    from shapebench.boards.leaderboard import BoardQuery
    from shapebench.config import make_settings
    from shapebench.evaluation.plan import RunPlan
    from shapebench.evaluation.runner import Runner
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_method, resolve_metrics
    from shapebench.registry.variant import make_variant
    from shapebench.store.tracking import Tracker

    class Posterior(Method):
        """Completions with posterior samples whose spread grows with the height (y); fails on
        one pictured object, which must not change which objects the others picture."""

        def complete(self, context, n_points):
            if context.ref.id == "can":
                raise RuntimeError("no posterior for cans")
            rng = np.random.default_rng(0)
            base = np.repeat(context.points, -(-n_points // len(context.points)), axis=0)
            base = base[:n_points]
            scale = 0.02 * (1 + 3 * (base[:, 1:2] - base[:, 1].min()))
            samples = [base + scale * rng.standard_normal(base.shape) for _ in range(4)]
            return Completion(points=base, samples=samples)

    dataset = _Primitives.build(tmp_path)
    settings = make_settings(
        f"sqlite:///{tmp_path / 'mlflow.db'}", tmp_path / "cache", "quick", tmp_path
    )
    registry = get_registry()
    method = resolve_method(registry, "gauss", settings)
    plan = RunPlan(method, dataset, [NOVEL], [50, 100], [0], resolve_metrics(registry, None))
    plan.variant = make_variant("posterior", method.config(), {}, plan.protocol, "quick")
    cells = Runner(Tracker(settings), echo=lambda _: None).run(plan, Posterior)
    assert [c.metrics["failures"] for c in cells] == [1.0, 1.0]
    client = Tracker(settings).client
    names = {a.path for a in client.list_artifacts(cells[0].run_id, "pictures")}
    # Objects 0, 2 and 3 of [box, ball, can, pill] are pictured; the can failed. The ball is
    # pictured too when it is the cell's worst success (it is not a fixed object).
    fixed = {f"pictures/{o}.{ext}" for o in ("box", "pill") for ext in ("png", "npz")}
    table = pd.read_csv(client.download_artifacts(cells[0].run_id, "per_object.csv", str(tmp_path)))
    ok = table[table["status"] == "ok"].set_index("object")["chamfer-l2"]
    extra = {f"pictures/ball.{ext}" for ext in ("png", "npz")} if ok.idxmax() == "ball" else set()
    assert names == fixed | extra, table
    # The .ply examples are filled up with another success (the ball), not left at two.
    plys = {a.path for a in client.list_artifacts(cells[0].run_id, "completions")}
    assert {f"completions/{o}.ply" for o in ("box", "pill", "ball")} <= plys
    arrays = np.load(client.download_artifacts(cells[0].run_id, "pictures/box.npz", str(tmp_path)))
    assert arrays["spread"].shape == (len(arrays["completion"]),)
    assert np.corrcoef(arrays["completion"][:, 1], arrays["spread"])[0, 1] > 0.5  # taller: wider

    page, seconds = build_report(
        settings, BoardQuery("primitives", "posterior"), None, tmp_path / "o"
    )
    text = page.read_text()
    assert "Posterior uncertainty" in text
    assert text.count('alt="posterior, 50 points: box"') == 1
    # The cell logged the picture's caption beside its arrays, and the report embeds the PNG
    # the cell drew with that caption instead of drawing it again.
    assert str(arrays["title"]) == "posterior k=50: box"
    from shapebench.boards.report_pictures import data_uri

    logged = Path(client.download_artifacts(cells[0].run_id, "pictures/box.png", str(tmp_path)))
    uri = data_uri(logged.read_bytes())
    assert f'<img alt="posterior, 50 points: box" src="{uri}">' in text
    assert text.count('<img alt="qualitative grid') == 2
    print(f"report built in {seconds:.1f} s")


def test_a_spread_picture_is_the_cells_png_only_under_the_caption_it_was_drawn_with():
    """The report reuses a cell's PNG when it would draw the same caption; under another
    caption (a relabelled row, an older cell without one) it draws the arrays anew."""
    from shapebench.boards.report_pictures import data_uri, spread_picture

    rng = np.random.default_rng(0)
    cloud = rng.normal(size=(200, 3)).astype(np.float32)
    arrays = {
        "context": cloud[:50],
        "completion": cloud,
        "spread": rng.random(200).astype(np.float32),
        "title": np.array("msc k=50: chair/test-000"),
        "png": np.frombuffer(b"the cell's picture", dtype=np.uint8),
    }
    assert spread_picture(arrays, "msc k=50: chair/test-000") == data_uri(b"the cell's picture")
    drawn = spread_picture(arrays, "msc-renamed k=50: chair/test-000")
    png = base64.b64decode(drawn.split(",", 1)[1])
    assert png.startswith(b"\x89PNG") and not is_blank(png)
    del arrays["title"]
    assert spread_picture(arrays, "msc k=50: chair/test-000") != data_uri(b"the cell's picture")
