"""The dataset plugin example of docs/plugins.md, pip-installed and used like a third party's."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import ROOT, pip_install_to

EXAMPLE = ROOT / "docs" / "examples" / "shapebench-primitives"

pytestmark = pytest.mark.slow  # pip installs and starts the CLI


@pytest.fixture(scope="module")
def primitives_site(tmp_path_factory) -> Path:
    return pip_install_to(tmp_path_factory.mktemp("site-primitives"), EXAMPLE)


def test_the_example_dataset_is_listed_and_evaluated(shapebench, primitives_site):
    sb = shapebench
    sb.sites = (primitives_site,)
    listed = sb("datasets")
    assert listed.returncode == 0 and "primitives" in listed.stdout
    assert "shapebench-primitives" in sb("plugins").stdout
    res = sb(
        "run",
        "-m",
        "gauss",
        "-d",
        "primitives",
        "-D",
        "surface_candidates=3000",
        "-D",
        "gt_points=2000",
        "--contexts",
        "50",
        "-q",
    )
    assert res.returncode == 0, res.stderr[-3000:]
    assert "primitives/trained: 2 objects in 2 categories" in res.stdout
    assert "primitives/novel: 1 objects in 1 categories" in res.stdout
    runs = sb.cell_runs("primitives-trained") + sb.cell_runs("primitives-novel")
    assert len(runs) == 2 and all(r.data.metrics["failures"] == 0 for r in runs)


def test_the_docs_show_the_example_files_as_they_are():
    docs = (ROOT / "docs" / "plugins.md").read_text()
    for name in ("dataset.py", "plugin.py"):
        code = (EXAMPLE / "shapebench_primitives" / name).read_text().strip()
        assert code in docs, f"docs/plugins.md does not show {name} as it is"
