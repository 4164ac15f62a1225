"""`sweep --launcher slurm` on a real one-node SLURM cluster (tests/slurm_cluster.py).

CI installs slurm-wlm and munge (scripts/ci-system-packages.sh); run just this file with
``.venv/bin/python -m pytest tests/sweeps/test_slurm.py``.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
from slurm_cluster import missing_requirements, start_cluster
from test_soak import SWEEP, all_runs, cell_runs, leaderboard

#: One cluster on this machine at a time: every test of this file runs in the same xdist worker
#: (`--dist loadgroup`), which starts the module's cluster once.
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("slurm")]

DDP = ["--devices", "2", "--strategy", "ddp", "--accelerator", "cpu"]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    why = missing_requirements()
    if why:
        pytest.skip(f"no SLURM here: {why}")
    c = start_cluster(tmp_path_factory.mktemp("slurm"), cpus=2)
    yield c
    c.stop()


@pytest.fixture
def idle_cluster(cluster):
    """The module's cluster, its node idle: each test starts after the last one's jobs are gone."""
    cluster.wait_idle()
    return cluster


def test_slurm_sweep_trains_once_on_two_ranks_and_logs_each_cell_once(
    shapebench, idle_cluster, tmp_path, monkeypatch
):
    cluster = idle_cluster
    monkeypatch.setenv("SLURM_CONF", str(cluster.conf))
    sb = shapebench
    body = SWEEP.replace("epochs: 60", "epochs: 4")
    shared = tmp_path / "shared-sqlite.yaml"
    shared.write_text(body + "launcher: {name: slurm, time: 20}\n")
    res = sb("sweep", str(shared), "-q")
    assert res.returncode != 0 and "SQLite" in res.stderr and "per-job" in res.stderr

    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(body + "launcher: {name: slurm, time: 20, tracking: per-job}\n")
    res = sb("sweep", str(sweep), "-q", "--wait", *DDP, timeout=900)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:] + cluster.logs()
    assert "1 trainings to submit" in res.stdout and "8 cells: 8 finished" in res.stdout

    # The training was one job of two ranks started by srun, seen by Lightning as such.
    logs = sb.workspace / "logs" / "submitit" / "soak"
    rank_logs = "".join(p.read_text() for p in logs.glob("*_log.err"))
    assert "GLOBAL_RANK: 1, MEMBER: 2/2" in rank_logs
    per_cell = Counter(
        (r.data.tags["method"], r.data.tags["split"], r.data.tags["context_size"])
        for r in cell_runs(sb)
    )
    assert len(per_cell) == 8 and set(per_cell.values()) == {1}
    training = [
        r for r in all_runs(sb, "FINISHED") if r.data.tags.get("shapebench.kind") == "training"
    ]
    assert len(training) == 1
    assert training[0].data.params["training.world_size"] == "2"
    assert all_runs(sb, "RUNNING") == []
    board = leaderboard(sb, tmp_path / "board")
    assert board["method"].str.startswith("igr").any() and (board["method"] == "gauss").any()

    res = sb("sweep", str(sweep), "--status", *DDP)
    assert res.returncode == 0 and "8 cells: 8 finished" in res.stdout, res.stderr
    res = sb("sweep", str(sweep), *DDP)  # resubmitting a finished sweep submits nothing
    assert res.returncode == 0 and "nothing to submit" in res.stdout, res.stderr


def test_a_preempted_training_stops_after_its_step_requeues_and_resumes(
    shapebench, idle_cluster, tmp_path, monkeypatch
):
    """SLURM's pre-emption warning (SIGUSR1, as `--signal=USR1@90` sends it): the training
    writes its checkpoint, its job is requeued by rank 0, and the requeued job resumes."""
    import json
    import time

    from processes import wait_for

    cluster = idle_cluster
    monkeypatch.setenv("SLURM_CONF", str(cluster.conf))
    sb = shapebench
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(
        SWEEP.replace("epochs: 60", "epochs: 400")
        .replace("batch_shapes: 4", "batch_shapes: 1")
        .replace("  - gauss\n", "")
        .replace("[trained, novel]", "[novel]")
        .replace("[50, 100]", "[50]")
        + "launcher: {name: slurm, time: 20, tracking: per-job}\n"
    )
    res = sb("sweep", str(sweep))
    assert res.returncode == 0 and "1 trainings to submit" in res.stdout, res.stderr
    manifest = [
        json.loads(line)
        for line in (sb.workspace / "sweeps" / "soak.jsonl").read_text().splitlines()
    ]
    job = next(j for j in manifest if j["kind"] == "training")
    jid, log = job["job_id"], job["stderr"]
    ckpts = sb.workspace / "checkpoints"
    wait_for(
        lambda: list(ckpts.glob("*/*/last.ckpt")),
        timeout=300,
        what="a first checkpoint",
        explain=lambda: cluster.describe(jid, log),
    )
    cluster.run("scancel", "--signal=USR1", jid)

    def requeued() -> bool:
        out = cluster.run("squeue", "-h", "-j", jid, "-o", "%T %r", check=False)
        return "requeueing job" in Path(log).read_text() and out.startswith("PENDING")

    wait_for(
        requeued,
        timeout=120,
        what="the training job requeued",
        explain=lambda: cluster.describe(jid, log),
    )

    def node_idle() -> bool:
        return cluster.run("sinfo", "-h", "-o", "%T", check=False).split() == ["idle"]

    # SLURM holds a requeued job back for a while (reason BeginTime): release it early, but only
    # once the node has cleaned up the killed instance and a couple of seconds have passed.
    # slurmd refuses a launch whose credential is not newer, to the second, than the kill of
    # the job's previous instance ("Job N already killed, do not launch batch job"), and the
    # cell then fails; that race reddened one CI run.
    wait_for(
        node_idle,
        timeout=120,
        what="the node idle after the kill",
        explain=lambda: cluster.describe(jid, log),
    )
    time.sleep(2.5)
    cluster.run("scontrol", "update", f"JobId={jid}", "StartTime=now")
    deadline = time.monotonic() + 600
    while "1 cells: 1 finished" not in (status := sb("sweep", str(sweep), "--status").stdout):
        assert time.monotonic() < deadline, status + cluster.describe(jid, log)
        time.sleep(5)
    text = Path(log).read_text()
    assert "SIGUSR1: stopping after the current optimiser step" in text
    assert "resuming from" in text and "last.ckpt" in text
    summary = json.loads(next(ckpts.glob("*/*/summary.json")).read_text())
    assert summary["resumed_from_epoch"] >= 1
    training = [
        r for r in all_runs(sb, "FINISHED") if r.data.tags.get("shapebench.kind") == "training"
    ]
    assert len(training) == 1 and training[0].data.tags.get("resumed") == "true"
