"""A metric that raises costs its own values only: the other metrics stand, the objects are not
marked failed, the cell is not cached as finished for that metric, and --debug shows why."""

from __future__ import annotations

import io
from pathlib import Path

import pandas as pd
import pytest
from conftest import TINY, pip_install_to

PLUGIN = """
from shapebench import UNIT_SPHERE_FRAME, Metric, MetricCard, hookimpl


class Crashy(Metric):
    name = "crashy"
    description = "raises on every object"

    def card(self, eval_points):
        return MetricCard(metric=self.name, power=1, reduction="mean", direction="symmetric",
                          halved=False, scale=1.0, frame=UNIT_SPHERE_FRAME,
                          eval_points=eval_points)

    def compute(self, prediction, ground_truth, context):
        raise RuntimeError("crashy exploded on " + context.ref.id)


@hookimpl
def shapebench_register_metrics(register):
    register("crashy", Crashy)
"""

PYPROJECT = """
[build-system]
requires = ["setuptools>=68"]
build-backend = "setuptools.build_meta"

[project]
name = "shapebench-crashy"
version = "0.1.0"
dependencies = ["shapebench"]

[project.entry-points.shapebench]
crashy = "shapebench_crashy"

[tool.setuptools]
packages = ["shapebench_crashy"]
"""


@pytest.fixture(scope="module")
def crashy_site(tmp_path_factory) -> Path:
    project = tmp_path_factory.mktemp("crashy-project")
    (project / "pyproject.toml").write_text(PYPROJECT)
    (project / "shapebench_crashy").mkdir()
    (project / "shapebench_crashy" / "__init__.py").write_text(PLUGIN)
    return pip_install_to(tmp_path_factory.mktemp("crashy-site"), project)


@pytest.mark.slow
def test_a_crashing_metric_spares_the_other_metrics_and_is_computed_again(shapebench, crashy_site):
    sb = shapebench
    sb.sites = (crashy_site,)
    args = [
        "run",
        "-m",
        "gauss",
        "-d",
        "synthetic",
        *TINY,
        "--split",
        "novel",
        "--contexts",
        "50",
        "--metric",
        "chamfer-l2",
        "--metric",
        "crashy",
    ]
    res = sb(*args)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "a metric raised" in res.stdout
    assert "x metric crashy: RuntimeError: crashy exploded on" in res.stdout
    assert "Traceback" not in res.stdout + res.stderr  # one line per distinct error

    (run,) = sb.cell_runs("synthetic-novel")
    assert run.data.tags["shapebench.metric_errors"] == "crashy"
    assert run.data.metrics["failures"] == 0  # the method did not fail
    assert run.data.metrics["chamfer-l2.mean"] > 0  # the other metric stands
    assert run.data.metrics["crashy.errors"] == run.data.metrics["n_objects"]
    table = pd.read_csv(
        io.StringIO(
            Path(
                sb.client().download_artifacts(run.info.run_id, "per_object.csv", str(sb.workspace))
            ).read_text()
        )
    )
    assert (table["status"] == "ok").all() and table["chamfer-l2"].notna().all()
    assert (
        table["crashy"].isna().all() and table["metric_error.crashy"].str.contains("exploded").all()
    )

    # Not finished for crashy: the next run computes the cell again; --debug shows the traceback.
    again = sb("--debug", *args)
    assert again.returncode == 0, again.stderr[-3000:]
    assert " new " in again.stdout and "Traceback (most recent call last)" in again.stdout
    assert 'raise RuntimeError("crashy exploded on "' in again.stdout

    # The chamfer leaderboard uses the cell; a crashy one leaves it out and says why.
    board = sb(
        "leaderboard",
        "-d",
        "synthetic",
        "--split",
        "novel",
        "--reference",
        "gauss",
        "--out",
        str(sb.workspace / "boards"),
    )
    assert board.returncode == 0, board.stderr[-3000:]
    assert "gauss" in (sb.workspace / "boards" / "synthetic-novel.md").read_text()
    crashy = sb(
        "leaderboard",
        "-d",
        "synthetic",
        "--split",
        "novel",
        "--metric",
        "crashy",
        "--out",
        str(sb.workspace / "boards"),
    )
    assert crashy.returncode != 0
    assert "raised on some object" in crashy.stdout + crashy.stderr
