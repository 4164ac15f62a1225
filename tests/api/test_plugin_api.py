"""The plugin API as a new plugin author meets it (issue 12): top-level imports, the guide's
examples as they are, metric cards for any metric, and bad cards that disable one metric with a
warning instead of crashing every run. The API reference's own checks are
tests/project/test_api_docs.py."""

from __future__ import annotations

import re
import subprocess
import sys
import warnings
from dataclasses import replace
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, TINY, pip_install_to

import shapebench
from shapebench.api.errors import ShapebenchError
from shapebench.api.metric import UNIT_SPHERE_FRAME, MetricCard, check_metric
from shapebench.api.types import Completion, Context, ObjectData, ObjectRef
from shapebench.metrics.chamfer import ChamferL1Asym, ChamferL2
from shapebench.metrics.fscore import FScore
from shapebench.registry.discovery import PluginWarning, discover
from shapebench.registry.resolve import resolve_metrics

EXAMPLE = ROOT / "docs" / "examples" / "shapebench-hausdorff"
PLUGIN_API = [
    "Method",
    "Metric",
    "MetricCard",
    "hookimpl",
    "Context",
    "Completion",
    "ObjectData",
    "Supervision",
    "Dataset",
    "MeshDataset",
    "UNIT_SPHERE_FRAME",
]


# -- top-level exports -----------------------------------------------------------------------


def test_plugin_api_imports_from_the_top_level_without_torch():
    code = (
        "import sys\n"
        "import shapebench\n"
        "assert 'numpy' not in sys.modules, 'import shapebench must stay light'\n"
        f"from shapebench import {', '.join(PLUGIN_API)}\n"
        "from shapebench.api.metric import Metric as M\n"
        "assert Metric is M\n"
        "heavy = [m for m in ('torch', 'pytorch_lightning', 'mlflow') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_all_lists_exactly_the_exports_and_each_resolves():
    assert set(shapebench.__all__) == {"__version__", "hookimpl", *shapebench._LAZY}
    for name in shapebench.__all__:
        assert getattr(shapebench, name) is not None
        assert name in dir(shapebench)
    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        shapebench.Nope  # noqa: B018


# -- the guide's examples ---------------------------------------------------------------------


def test_plugins_md_shows_the_example_files_as_they_are():
    """Each file of the metric example appears in docs/plugins.md verbatim."""
    doc = (ROOT / "docs" / "plugins.md").read_text().split("## A complete metric plugin")[1]
    for rel in (
        "pyproject.toml",
        "shapebench_hausdorff/plugin.py",
        "shapebench_hausdorff/metric.py",
    ):
        block = re.search(rf"`{re.escape(rel)}`:\n\n```\w*\n(.*?)```", doc, re.DOTALL)
        assert block, f"docs/plugins.md has no block for {rel}"
        assert block.group(1) == (EXAMPLE / rel).read_text(), f"{rel} differs from the docs"


def test_plugins_md_card_table_lists_every_field_and_allowed_value():
    from shapebench.api.metric import COMBINES, DIRECTIONS, REDUCTIONS

    doc = (ROOT / "docs" / "plugins.md").read_text().split("## The Metric interface")[1]
    for field in MetricCard.__dataclass_fields__:
        assert f"| `{field}` |" in doc, field
    for value in [*REDUCTIONS, *DIRECTIONS, *COMBINES]:
        assert f'`"{value}"`' in doc, value


# -- cards for any metric --------------------------------------------------------------------


def _card(**changes) -> MetricCard:
    base = MetricCard(
        metric="m",
        power=1,
        reduction="mean",
        direction="symmetric",
        halved=False,
        scale=1.0,
        frame=UNIT_SPHERE_FRAME,
        eval_points=30000,
    )
    return replace(base, **changes)


HAUSDORFF = _card(metric="hausdorff", reduction="max", combine="max", scale=100.0)
FSCORE_002 = _card(
    metric="fscore-0.02",
    reduction="fraction",
    threshold=0.02,
    combine="harmonic-mean",
    higher_is_better=True,
)
NORMAL_CONSISTENCY = _card(
    metric="normal-consistency",
    power=0,
    combine="mean",
    quantity="|cos| between the normals of nearest neighbours",
    higher_is_better=True,
)


@pytest.mark.parametrize(
    ("card", "text"),
    [
        (
            HAUSDORFF,
            "hausdorff: Euclidean NN distances, max per set, max of both directions; shown x100;",
        ),
        (
            FSCORE_002,
            "fscore-0.02: Euclidean NN distances, fraction below 0.02 per set, harmonic "
            "mean of both directions; higher is better; shown x1;",
        ),
        (
            NORMAL_CONSISTENCY,
            "normal-consistency: |cos| between the normals of nearest "
            "neighbours, mean per set, mean of both directions; higher is better",
        ),
        (_card(direction="pred->gt"), "m: Euclidean NN distances, mean per set, pred->gt;"),
        (
            _card(
                metric="iou",
                power=0,
                reduction="none",
                direction="none",
                quantity="volume IoU",
                higher_is_better=True,
            ),
            "iou: volume IoU; higher is better; shown x1;",
        ),
    ],
    ids=["hausdorff", "fscore", "normal-consistency", "accuracy", "iou"],
)
def test_non_chamfer_cards_validate_describe_and_round_trip(card, text):
    card.validate()
    assert card.describe().startswith(text)
    assert MetricCard.from_tag(card.as_tag()) == card


def test_chamfer_tags_are_unchanged_so_stored_runs_keep_their_keys():
    """The exact tags runs logged before the card gained fields: cell keys hold them."""
    assert ChamferL2().card(30000).as_tag() == (
        "metric=chamfer-l2;power=2;reduction=mean;direction=symmetric;halved=False;"
        "scale=1000.0;frame=unit-radius;eval_points=30000"
    )
    old = (
        "metric=chamfer-l1-asym;power=1;reduction=mean;direction=gt->pred;halved=False;"
        "scale=1000.0;frame=unit-diameter;eval_points=16384"
    )
    card = MetricCard.from_tag(old)
    assert card == ChamferL1Asym().card(16384).in_frame("unit-diameter")
    assert card.as_tag() == old


def test_old_fscore_tags_read_as_todays_fscore_card():
    old = (
        "metric=fscore;power=0;reduction=fraction within tau=0.01;direction=symmetric;"
        "halved=False;scale=1.0;frame=unit-radius;eval_points=30000"
    )
    card = MetricCard.from_tag(old)
    assert card == FScore().card(30000)
    assert card.threshold == 0.01 and card.higher_is_better
    card.validate()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"reduction": "median"}, "reduction='median' is not one of: 'mean', 'sum', 'max'"),
        ({"direction": "both"}, "direction='both' is not one of: 'symmetric', 'gt->pred'"),
        ({"combine": "product"}, "combine='product' is not one of: 'sum', 'mean', 'max'"),
        ({"power": 3}, "power=3 is not one of: 0, 1, 2"),
        ({"power": True}, "power=True is not one of"),
        ({"frame": "unit-cube"}, "frame='unit-cube' is not one of: 'unit-radius'"),
        ({"reduction": "fraction"}, "reduction='fraction' needs a threshold"),
        ({"threshold": 0.01}, "threshold=0.01 is used only by reduction='fraction'"),
        ({"reduction": "fraction", "threshold": -1.0}, "threshold=-1.0 must be a positive number"),
        ({"direction": "gt->pred", "combine": "max"}, "needs direction='symmetric'"),
        ({"halved": True, "combine": "max"}, "halved=True needs direction='symmetric' and combine"),
        ({"power": 0}, "power=0 (not a distance) needs a quantity"),
        ({"scale": 0}, "scale=0 must be a positive number"),
        ({"eval_points": -1}, "eval_points=-1 must not be negative"),
        ({"metric": "a;b"}, "metric='a;b' must be a string without ';'"),
        ({"halved": "no"}, "halved='no' must be True or False"),
    ],
)
def test_bad_cards_are_refused_with_the_allowed_values(changes, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        _card(**changes).validate()


def test_builtin_metrics_pass_the_registry_check():
    for cls in (ChamferL2, ChamferL1Asym, FScore):
        assert check_metric(cls) == cls().card(30000)


# -- the registry disables bad metrics, one at a time -----------------------------------------

GOOD = """
from shapebench import hookimpl

@hookimpl
def shapebench_register_metrics(register):
    register("chamfer-l2", "shapebench.metrics.chamfer:ChamferL2")
"""

BAD = """
from shapebench import UNIT_SPHERE_FRAME, Metric, MetricCard, hookimpl


class Median(Metric):
    name = "median-dist"

    def card(self, eval_points):
        return MetricCard(metric=self.name, power=1, reduction="median", direction="symmetric",
                          halved=False, scale=1.0, frame=UNIT_SPHERE_FRAME,
                          eval_points=eval_points)

    def compute(self, prediction, ground_truth, context):
        return 0.0


class Raises(Metric):
    name = "raises"

    def card(self, eval_points):
        raise RuntimeError("no card today")

    def compute(self, prediction, ground_truth, context):
        return 0.0


class Unsure(Metric):
    name = "unsure"
    higher_is_better = True

    def card(self, eval_points):
        return MetricCard(metric=self.name, power=2, reduction="mean", direction="symmetric",
                          halved=False, scale=1.0, frame=UNIT_SPHERE_FRAME,
                          eval_points=eval_points)

    def compute(self, prediction, ground_truth, context):
        return 0.0


@hookimpl
def shapebench_register_metrics(register):
    register("median-dist", Median)
    register("raises", "sb_badcard_mod:Raises")
    register("unsure", Unsure)
    register("missing", "sb_badcard_mod:NoSuchClass")
"""


@pytest.fixture
def bad_card_registry(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "sb_api_good_mod.py").write_text(GOOD)
    (tmp_path / "sb_badcard_mod.py").write_text(BAD)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # registering checks nothing yet: no warning
        return discover(
            [
                EntryPoint("badcard", "sb_badcard_mod", "shapebench"),
                EntryPoint("good", "sb_api_good_mod", "shapebench"),
            ]
        )


def test_bad_metric_cards_disable_those_metrics_with_warnings(bad_card_registry):
    reg = bad_card_registry
    with pytest.warns(PluginWarning) as caught:
        names = reg.names("metric")
    assert names == ["chamfer-l2"]
    messages = [str(w.message) for w in caught]
    assert len(messages) == 4
    assert all(m.startswith("shapebench plugin 'badcard' (unknown unknown)") for m in messages)
    text = "\n".join(messages)
    assert (
        "metric 'median-dist' is disabled: invalid metric card for 'median-dist': "
        "reduction='median' is not one of: 'mean', 'sum', 'max', 'fraction', 'none'" in text
    )
    assert "metric 'raises' is disabled: Raises().card(30000) raised RuntimeError: no card" in text
    assert "metric 'unsure' is disabled: the card says higher_is_better=False" in text
    assert "metric 'missing' failed to load 'sb_badcard_mod:NoSuchClass'" in text
    assert "median-dist" in reg.plugins[0].error and "raises" in reg.plugins[0].error
    assert reg.plugins[1].error is None

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once, not at every look-up
        assert reg.names("metric") == ["chamfer-l2"]
        # a run computes the metrics that work
        assert [m.name for m in resolve_metrics(reg, None)] == ["chamfer-l2"]
    with pytest.raises(ShapebenchError, match="'median-dist' from plugin 'badcard'.*median"):
        reg.load("metric", "median-dist")


def test_a_metric_asked_for_by_name_reports_its_bad_card(bad_card_registry):
    with pytest.raises(ShapebenchError) as err:
        resolve_metrics(bad_card_registry, ["raises"])
    assert "no card today" in str(err.value)
    assert "SHAPEBENCH_DISABLE_PLUGINS=badcard" in str(err.value)


def _fake_distribution(site: Path, name: str, module: str, body: str) -> Path:
    """A plugin installed by hand: a module and the entry-point metadata pip would write."""
    site.mkdir(parents=True, exist_ok=True)
    (site / f"{module}.py").write_text(body)
    info = site / f"{name.replace('-', '_')}-0.0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.0.1\n")
    (info / "entry_points.txt").write_text(f"[shapebench]\nbadcard = {module}\n")
    return site


@pytest.mark.slow
def test_cli_lists_the_good_metrics_and_warns_about_bad_cards(shapebench, tmp_path):
    shapebench.sites = (_fake_distribution(tmp_path / "site", "sb-badcard", "sb_badcard_mod", BAD),)
    res = shapebench("metrics")
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    assert "Warning: shapebench plugin 'badcard' (sb-badcard 0.0.1): metric 'median-dist'" in (
        res.stderr
    )
    assert "no card today" in res.stderr
    assert "chamfer-l2" in res.stdout and "fscore" in res.stdout
    assert "median-dist" not in res.stdout


# -- the documented metric example runs ---------------------------------------------------------


@pytest.fixture(scope="module")
def hausdorff_module(tmp_path_factory):
    site = pip_install_to(tmp_path_factory.mktemp("site-hausdorff"), EXAMPLE)
    sys.path.insert(0, str(site))
    try:
        import shapebench_hausdorff.metric as module

        yield module, site
    finally:
        sys.path.remove(str(site))
        for name in [m for m in sys.modules if m.startswith("shapebench_hausdorff")]:
            del sys.modules[name]


def test_example_hausdorff_metric_computes_the_hausdorff_distance(hausdorff_module):
    module, _ = hausdorff_module
    rng = np.random.default_rng(0)
    gt = rng.uniform(-1, 1, (500, 3)).astype(np.float32)
    pred = gt[:400] + np.float32(0.01)  # 100 GT points have no close prediction
    ref = ObjectRef("o", "c")
    data = ObjectData(ref, gt, gt, gt)
    ctx = Context(ref, gt[:10], None, 0)
    value = module.Hausdorff().compute(Completion(points=pred), data, ctx)
    full = np.linalg.norm(gt[:, None] - pred[None], axis=-1)  # every pairwise distance
    expected = max(full.min(axis=1).max(), full.min(axis=0).max())
    assert value == pytest.approx(expected, rel=1e-5)
    assert "hausdorff.gt_tree" in data.cache
    card = check_metric(module.Hausdorff)
    assert (card.reduction, card.combine, card.higher_is_better) == ("max", "max", False)


@pytest.mark.slow
def test_example_hausdorff_plugin_installs_and_is_described(shapebench, hausdorff_module):
    _, site = hausdorff_module
    shapebench.sites = (site,)
    res = shapebench("metrics")
    assert res.returncode == 0, res.stderr
    assert "hausdorff  (shapebench-hausdorff 0.1.0)" in res.stdout
    assert (
        "hausdorff: Euclidean NN distances, max per set, max of both directions; "
        "shown x100" in res.stdout
    )
    assert "Warning" not in res.stderr


@pytest.mark.slow
def test_a_run_computes_the_example_metric_and_skips_a_bad_card(
    shapebench, hausdorff_module, tmp_path
):
    """Both plugins installed: the run warns about the bad cards, computes hausdorff beside the
    built-in metrics, and the leaderboard ranks by it."""
    _, site = hausdorff_module
    bad = _fake_distribution(tmp_path / "site-bad", "sb-badcard", "sb_badcard_mod", BAD)
    shapebench.sites = (site, bad)
    args = ("-d", "synthetic", *TINY, "--contexts", "50", "--split", "novel")
    res = shapebench("run", "-m", "gauss", *args)
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    assert "metric 'median-dist' is disabled" in res.stderr
    run = shapebench.cell_runs("synthetic-novel")[0]
    assert run.data.tags["card.hausdorff"].startswith("metric=hausdorff;power=1;reduction=max;")
    assert run.data.metrics["hausdorff.mean"] > 0
    assert "card.median-dist" not in run.data.tags and "card.chamfer-l2" in run.data.tags
    board = shapebench(
        "leaderboard",
        "-d",
        "synthetic",
        "--split",
        "novel",
        "--metric",
        "hausdorff",
        "--out",
        str(tmp_path / "boards"),
    )
    assert board.returncode == 0, board.stderr
    text = (tmp_path / "boards" / "synthetic-novel.md").read_text()
    assert "**Metric card**: hausdorff: Euclidean NN distances, max per set, max of both" in text
