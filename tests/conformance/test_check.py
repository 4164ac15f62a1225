"""``shapebench check`` and :mod:`shapebench.conformance.testing` (issue 12): the built-ins pass;
a plugin that breaks a rule fails that check, with the reason, and the command exits with
status 1."""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from conftest import pip_install_to

from shapebench.api.dataset import Dataset
from shapebench.api.errors import ConfigError, UnknownNameError
from shapebench.api.method import Method
from shapebench.api.metric import UNIT_SPHERE_FRAME, Metric, MetricCard
from shapebench.api.types import (
    NOVEL,
    TRAIN,
    TRAINED,
    Category,
    Completion,
    Context,
    ObjectData,
    ObjectRef,
)
from shapebench.conformance.framework import (
    FAIL,
    PASS,
    SKIP,
    CheckEnv,
    CheckFailed,
    CheckResult,
    summary,
)
from shapebench.conformance.methods import completion_problem
from shapebench.conformance.options import options_roundtrip
from shapebench.conformance.runner import distribution_components
from shapebench.conformance.testing import (
    PluginCheckFailed,
    check_dataset,
    check_method,
    check_metric,
)

# -- a plugin that breaks one rule per component, installed through a real entry point -----------

BAD_PLUGIN = {
    "pyproject.toml": """
        [build-system]
        requires = ["setuptools>=68"]
        build-backend = "setuptools.build_meta"

        [project]
        name = "shapebench-bad"
        version = "0.0.1"

        [project.entry-points.shapebench]
        bad = "shapebench_bad.plugin"

        [tool.setuptools]
        packages = ["shapebench_bad"]
    """,
    "shapebench_bad/__init__.py": "",
    "shapebench_bad/plugin.py": """
        from shapebench import hookimpl

        @hookimpl
        def shapebench_register_methods(register):
            register("ok-sphere", "shapebench_bad.methods:Sphere")
            register("nan-points", "shapebench_bad.methods:NaNPoints")
            register("unseeded", "shapebench_bad.methods:Unseeded")
            register("spread-scaled", "shapebench_bad.methods:SpreadScaled")
            register("path-option", "shapebench_bad.methods:PathOption")
            register("torch-at-import", "shapebench_bad.torchy:TorchAtImport")

        @hookimpl
        def shapebench_register_metrics(register):
            register("constant", "shapebench_bad.metrics:Constant")
    """,
    "shapebench_bad/methods.py": """
        from dataclasses import dataclass, field
        from pathlib import Path

        import numpy as np

        from shapebench import Completion, Method

        def sphere(context, n, rng):
            v = rng.normal(size=(n, 3))
            v /= np.linalg.norm(v, axis=1, keepdims=True)
            return (context.points.mean(axis=0) + 0.5 * v).astype(np.float32)

        class Sphere(Method):
            def complete(self, context, n_points):
                return Completion(sphere(context, n_points, np.random.default_rng(context.seed)))

        class NaNPoints(Method):
            def complete(self, context, n_points):
                return Completion(np.full((n_points, 3), np.nan, dtype=np.float32))

        class Unseeded(Method):
            def complete(self, context, n_points):
                return Completion(sphere(context, n_points, np.random.default_rng()))

        class SpreadScaled(Method):
            # Normalises by the context's spread: NaN when every point is the same.
            def complete(self, context, n_points):
                p = context.points
                unit = (p - p.mean(axis=0)) / p.std(axis=0)
                rng = np.random.default_rng(context.seed)
                out = unit[rng.integers(len(p), size=n_points)] * p.std(axis=0) + p.mean(axis=0)
                return Completion(out.astype(np.float32))

        @dataclass(frozen=True)
        class PathOptions:
            where: Path = field(default=Path("/tmp"), metadata={"help": "not a JSON value"})

        class PathOption(Sphere):
            Options = PathOptions
    """,
    "shapebench_bad/torchy.py": """
        import torch  # noqa: F401  (at import time: what the check catches)

        from shapebench_bad.methods import Sphere

        class TorchAtImport(Sphere):
            pass
    """,
    "shapebench_bad/metrics.py": """
        from shapebench import UNIT_SPHERE_FRAME, Metric, MetricCard

        class Constant(Metric):
            name = "constant"

            def card(self, eval_points):
                return MetricCard(metric=self.name, power=2, reduction="mean",
                                  direction="symmetric", halved=False, scale=1.0,
                                  frame=UNIT_SPHERE_FRAME, eval_points=eval_points)

            def compute(self, prediction, ground_truth, context):
                return 1.0
    """,
}


@pytest.fixture(scope="module")
def bad_site(tmp_path_factory) -> Path:
    project = tmp_path_factory.mktemp("shapebench-bad")
    for rel, text in BAD_PLUGIN.items():
        (project / rel).parent.mkdir(parents=True, exist_ok=True)
        (project / rel).write_text(textwrap.dedent(text).lstrip())
    return pip_install_to(tmp_path_factory.mktemp("site-bad"), project)


def _lines(stdout: str, component: str) -> list[str]:
    """The check lines printed under ``component``'s heading."""
    lines = stdout.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith(component + " ("))
    out = []
    for ln in lines[start + 1 :]:
        if not ln.startswith("  "):
            break
        out.append(ln.strip())
    return out


def _status(stdout: str, component: str) -> dict[str, str]:
    """check name -> "PASS: reason" for ``component``."""
    out = {}
    for ln in _lines(stdout, component):
        status, name, *reason = ln.split(maxsplit=2)
        out[name] = f"{status}: {reason[0] if reason else ''}"
    return out


@pytest.mark.slow  # runs the CLI in a subprocess; imports torch in the import check
def test_a_plugin_breaking_rules_fails_those_checks_with_reasons(shapebench, bad_site):
    shapebench.sites = (bad_site,)
    res = shapebench("check", "shapebench-bad")
    assert res.returncode == 1, res.stdout + res.stderr
    out = res.stdout

    ok = _status(out, "method ok-sphere")
    assert all(s.startswith(("PASS", "SKIP")) for s in ok.values()), ok
    assert ok["train"].startswith("SKIP: does not train")

    nan = _status(out, "method nan-points")
    assert nan["complete"].startswith("FAIL") and "NaN/inf" in nan["complete"]
    assert nan["deterministic"].startswith("SKIP")

    unseeded = _status(out, "method unseeded")
    assert unseeded["complete"].startswith("PASS")
    assert unseeded["deterministic"].startswith("FAIL")
    assert "context.seed" in unseeded["deterministic"]

    spread = _status(out, "method spread-scaled")
    assert spread["complete"].startswith("PASS")
    assert spread["degenerate"].startswith("FAIL: a context of 50 identical points:")
    assert "are NaN/inf" in spread["degenerate"]
    assert _status(out, "method ok-sphere")["degenerate"].startswith(
        "PASS: contexts of 50 points, duplicated: "
    )

    path = _status(out, "method path-option")
    assert path["options"].startswith("FAIL") and "not a JSON value" in path["options"]

    torchy = _status(out, "method torch-at-import")
    assert torchy["imports"].startswith("FAIL")
    assert "importing shapebench_bad.torchy imports torch" in torchy["imports"]

    constant = _status(out, "metric constant")
    assert constant["card"].startswith("PASS")
    assert constant["identical"].startswith("FAIL") and "expected 0" in constant["identical"]

    failed = [ln for ln in out.splitlines() if ln.startswith("FAILED ")]
    assert len(failed) == 6, failed
    assert "FAILED method nan-points complete:" in out
    assert re.match(r"\d+ passed, 6 failed, \d+ skipped in ", out.rstrip().splitlines()[-1])


@pytest.mark.slow  # runs the CLI in a subprocess
def test_builtins_pass(shapebench):
    res = shapebench("check", "-m", "gauss", "-d", "synthetic", "--metric", "chamfer-l2")
    assert res.returncode == 0, res.stdout + res.stderr
    assert "FAIL" not in res.stdout
    gauss = _status(res.stdout, "method gauss")
    assert list(gauss) == [
        "imports",
        "interface",
        "options",
        "train",
        "checkpoint",
        "complete",
        "degenerate",
        "deterministic",
        "lightning",
    ]
    assert "n = 2000" in gauss["complete"]
    assert _status(res.stdout, "dataset synthetic")["splits"].startswith("PASS: 15 categories")
    metric = _status(res.stdout, "metric chamfer-l2")
    assert metric["identical"].startswith("PASS: 0 on a prediction identical to the ground truth")
    assert res.stdout.rstrip().splitlines()[-1].startswith("17 passed, 2 skipped in ")


@pytest.mark.slow  # trains every built-in method for a few steps (about a minute)
def test_every_builtin_passes(shapebench):
    # A new interpreter: the check tells which Lightning namespace the methods import.
    res = shapebench("check", "shapebench", fresh=True)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "FAIL" not in res.stdout
    titles = [
        ln.split(" (")[0] for ln in res.stdout.splitlines() if ln.endswith("(shapebench 0.1.0)")
    ]
    assert titles[0] == "method convonet" and titles[-1] == "metric normal-consistency"
    assert len(titles) == 31  # 13 methods, 7 datasets, 11 metrics
    # A method that reads a user's input is checked up to its options, then says what it needs.
    files = _status(res.stdout, "method files")
    assert files["options"].startswith("PASS")
    assert files["complete"].startswith("SKIP: needs completions from a user's export folder")
    assert _status(res.stdout, "metric emd")["identical"].startswith("PASS")
    assert _status(res.stdout, "metric dcd")["identical"].startswith("PASS")
    pcn = _status(res.stdout, "method pcn")
    assert pcn["train"].startswith("PASS: 1 epoch(s) on 11 objects")
    assert pcn["checkpoint"].startswith("PASS")
    assert "n = 64" in pcn["complete"]  # 16 coarse points x a 2 x 2 folding grid
    assert pcn["lightning"] == "PASS: does not import lightning.pytorch"
    # The first trainable method imported Lightning: under the one namespace.
    convonet = _status(res.stdout, "method convonet")
    assert convonet["lightning"] == "PASS: uses pytorch_lightning, not lightning.pytorch"
    # Datasets read from a local copy skip their data checks without --data-root.
    assert _status(res.stdout, "dataset shapenet")["load"].startswith("SKIP: reads a local copy")


@pytest.mark.slow  # runs the CLI in subprocesses
def test_unknown_names_are_usage_errors(shapebench):
    res = shapebench("check", "-m", "nope")
    assert res.returncode == 2 and "unknown method 'nope'" in res.stderr
    res = shapebench("check", "shapebench-nope")
    assert res.returncode == 2
    assert "unknown distribution 'shapebench-nope'; available: shapebench" in res.stderr


@pytest.mark.slow  # runs the CLI in a subprocess
def test_a_plugin_that_fails_to_import_fails_its_check(shapebench, broken_site):
    shapebench.sites = (broken_site,)
    res = shapebench("check", "shapebench-broken")
    assert res.returncode == 1
    assert _status(res.stdout, "plugin broken")["imports"].startswith(
        "FAIL: failed to import: ImportError: shapebench_broken needs a library"
    )


# -- shapebench.conformance.testing, in this process --------------------------------------------


class _NaNMethod(Method):
    def complete(self, context: Context, n_points: int) -> Completion:
        return Completion(np.full((n_points, 3), np.nan, dtype=np.float32))


class _HalfMetric(Metric):
    """Symmetric Chamfer-like, but not zero on identical clouds."""

    name = "half"

    def card(self, eval_points: int) -> MetricCard:
        return MetricCard(
            metric="half",
            power=1,
            reduction="mean",
            direction="symmetric",
            halved=False,
            scale=1.0,
            frame=UNIT_SPHERE_FRAME,
            eval_points=eval_points,
        )

    def compute(self, prediction, ground_truth, context) -> float:
        return 0.5


@dataclass(frozen=True)
class _Opts:
    n: int = field(default=60, metadata={"help": "visible points per object"})


class _LeakyDataset(Dataset):
    """A novel-category object in the train split: methods would train on a novel category."""

    name = "leaky"
    Options = _Opts

    def categories(self) -> list[Category]:
        return [Category("ball", TRAINED), Category("cube", NOVEL)]

    def objects(self, split: str) -> list[ObjectRef]:
        return {
            TRAIN: [ObjectRef("cube/0", "cube")],
            TRAINED: [ObjectRef("ball/1", "ball")],
            NOVEL: [],
        }[split]

    def load(self, ref, need=frozenset()) -> ObjectData:
        v = np.random.default_rng(0).normal(size=(self.options.n, 3)).astype(np.float32)
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        return ObjectData(ref, v, v, v)


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    with CheckEnv(workdir=tmp_path_factory.mktemp("check")) as e:
        yield e


@pytest.mark.slow  # builds the tiny dataset and imports plugins in subprocesses
def test_testing_helpers_pass_builtins_and_raise_on_bad_components(env):
    report = check_method("gauss", env=env)
    assert not report.failures and report.results[0].check == "imports"
    check_metric("chamfer-l1", env=env)

    with pytest.raises(PluginCheckFailed) as info:
        check_method(_NaNMethod, env=env)
    assert isinstance(info.value, AssertionError)
    assert "method _NaNMethod (test_check) failed 1 check(s):" in str(info.value)
    assert "2000 of 2000 points are NaN/inf" in str(info.value)

    with pytest.raises(PluginCheckFailed, match="identical: 0.5 on a prediction identical"):
        check_metric(_HalfMetric, env=env)

    with pytest.raises(PluginCheckFailed, match="holds cube/0 of category 'cube'.*not a trained"):
        check_dataset(_LeakyDataset, env=env)


def test_completion_problems_name_the_rule():
    pts = np.zeros((100, 3), np.float32)
    assert completion_problem(Completion(pts), 2000) is None
    assert "shape (100, 2)" in completion_problem(Completion(pts[:, :2]), 2000)
    assert "expected between 50 and 20000" in completion_problem(Completion(pts[:10]), 2000)
    assert "a point 173 from the origin" in completion_problem(Completion(pts + 100), 2000)
    assert "samples[0]" in completion_problem(Completion(pts, samples=[pts * np.nan]), 2000)
    assert "not a Completion" in completion_problem(pts, 2000)


def test_options_that_do_not_round_trip_fail():
    @dataclass(frozen=True)
    class Tupled:
        sizes: tuple[int, ...] = (1, 2)
        where: str = "x"

    assert options_roundtrip(Tupled, {"where": "y: z"}, "m").where == "y: z"

    @dataclass(frozen=True)
    class BareTuple:  # `-O sizes=[1,2]` cannot build it: the check says so
        sizes: tuple = (1, 2)

    with pytest.raises(ConfigError, match="must be tuple, got \\[1, 2\\]"):
        options_roundtrip(BareTuple, {}, "m")

    @dataclass(frozen=True)
    class Bad:
        where: Path = Path("/tmp")

    with pytest.raises(CheckFailed, match="where=PosixPath.*not a JSON value"):
        options_roundtrip(Bad, {}, "m")


def test_unknown_distribution_lists_the_installed_ones():
    from shapebench.registry.discovery import get_registry

    with pytest.raises(UnknownNameError, match="available: .*shapebench"):
        distribution_components(get_registry(), "shapebench-nope")
    kinds = [c.kind for c in distribution_components(get_registry(), "shapebench")]
    assert kinds == sorted(kinds, key=("method", "dataset", "metric").index)


def test_summary_reads_like_pytest():
    results = [
        CheckResult("a", PASS),
        CheckResult("b", FAIL),
        CheckResult("c", SKIP),
        CheckResult("d", PASS),
    ]
    assert summary(results, 1.25) == "2 passed, 1 failed, 1 skipped in 1.2s"


@pytest.mark.slow  # runs pytest on a plugin's test file in a subprocess
def test_a_plugin_test_suite_uses_the_fixture_and_helpers(tmp_path):
    (tmp_path / "conftest.py").write_text('pytest_plugins = ["shapebench.conformance.testing"]\n')
    (tmp_path / "test_plugin.py").write_text(
        textwrap.dedent("""
        import numpy as np
        import pytest
        from shapebench import Completion, Method
        from shapebench.conformance.testing import check_method

        class Wobbly(Method):
            def complete(self, context, n_points):
                return Completion(np.random.default_rng().normal(size=(n_points, 3)) * 0.1)

        def test_gauss(shapebench_check_env):
            check_method("gauss", env=shapebench_check_env)

        def test_wobbly_fails_determinism(shapebench_check_env):
            with pytest.raises(AssertionError, match="deterministic: .*context.seed"):
                check_method(Wobbly, env=shapebench_check_env)
    """)
    )
    res = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert res.returncode == 0, res.stdout + res.stderr
    assert "2 passed" in res.stdout
