"""Against a real `mlflow server` on 127.0.0.1, and the `shapebench ui` command."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from browser_support import stop_server, wait_http
from conftest import TINY, free_port

pytestmark = [pytest.mark.server, pytest.mark.slow]  # starts servers and CLI subprocesses


@pytest.fixture
def mlflow_server(tmp_path):
    port = free_port()
    env = dict(os.environ, MLFLOW_SERVER_ENABLE_JOB_EXECUTION="false")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "mlflow",
            "server",
            "--backend-store-uri",
            f"sqlite:///{tmp_path / 'server.db'}",
            "--artifacts-destination",
            str(tmp_path / "server-artifacts"),
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--workers",
            "1",
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    uri = f"http://127.0.0.1:{port}"
    try:
        wait_http(uri + "/health", proc)
        yield uri
    finally:
        stop_server(proc)


def test_run_and_leaderboard_over_http(shapebench, mlflow_server):
    uri = mlflow_server
    res = shapebench(
        "run",
        "-m",
        "gauss",
        "-d",
        "synthetic",
        *TINY,
        "--contexts",
        "50",
        "--split",
        "novel",
        "--tracking-uri",
        uri,
        "-q",
    )
    assert res.returncode == 0, res.stderr
    assert f"Runs are in {uri}" in res.stdout
    assert not (shapebench.workspace / "mlflow.db").exists()  # nothing went to the local store

    from mlflow.tracking import MlflowClient

    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("synthetic-novel")
    runs = client.search_runs([exp.experiment_id], "tags.`shapebench.kind` = 'cell'")
    assert len(runs) == 1 and runs[0].info.status == "FINISHED"
    # Artifacts went through the server's artifact proxy and come back from it.
    assert {a.path for a in client.list_artifacts(runs[0].info.run_id)} >= {"per_object.csv"}

    res = shapebench(
        "leaderboard", "-d", "synthetic", "--tracking-uri", uri, "--reference", "gauss"
    )
    assert res.returncode == 0, res.stderr
    md = (shapebench.workspace / "leaderboards" / "synthetic-novel.md").read_text()
    assert uri in md and "| Gauss densification (`gauss`) |" in md


def test_ui_serves_the_embedded_store_on_localhost(shapebench):
    port = free_port()
    proc = shapebench.popen("ui", "--port", str(port), start_new_session=True)
    try:
        wait_http(f"http://127.0.0.1:{port}/health", proc)
        first = proc.stdout.readline()
        assert f"MLflow UI: http://127.0.0.1:{port}" in first
        assert shapebench.tracking_uri in first
    finally:
        stop_server(proc)
