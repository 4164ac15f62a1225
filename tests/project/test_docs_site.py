"""The documentation site (mkdocs.yml) builds with warnings as errors: a broken link or anchor, a
page missing from the navigation, or a ``:::`` reference to an object that no longer exists fails
here instead of on the published site."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_the_site_builds_strictly(tmp_path):
    pytest.importorskip("mkdocs", reason="mkdocs comes with the `test` extra")
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "PYTHONDONTWRITEBYTECODE": "1"}
    res = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr[-6000:]
    # The sections outside docs/ and the generated references are there.
    for page in ("results", "changes", "reference/cli", "reference/api/metric"):
        assert (site / page / "index.html").is_file(), page
    api = (site / "reference" / "api" / "metric" / "index.html").read_text()
    assert 'id="shapebench.api.metric.MetricCard"' in api
    cli = (site / "reference" / "cli" / "index.html").read_text()
    for command in ("run", "sweep", "leaderboard", "report"):
        assert f'id="shapebench-{command}"' in cli, command
