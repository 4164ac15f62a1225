"""A real one-node SLURM cluster on 127.0.0.1 for the launcher tests: Debian's ``slurm-wlm`` and
``munge`` (``scripts/ci-system-packages.sh`` installs them), started from a temporary folder
with a ``slurm.conf`` for this machine's CPUs, and stopped afterwards.

Nothing outside the folder is touched: munge runs with its own key and socket, slurmctld and
slurmd with their own ports, state and logs, and every client finds the cluster through
``SLURM_CONF``. Daemons run as root (``SlurmUser=root``), as on a single-user test machine.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

DAEMONS = ("munged", "slurmctld", "slurmd", "sbatch", "squeue", "srun", "scontrol")


def missing_requirements() -> str | None:
    """Why a cluster cannot be started here, or None."""
    missing = [d for d in DAEMONS if shutil.which(d) is None]
    if missing:
        return f"{', '.join(missing)} not installed (bash scripts/ci-system-packages.sh)"
    if os.geteuid() != 0:
        return "slurmd must run as root"
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class SlurmCluster:
    root: Path
    conf: Path

    def env(self) -> dict[str, str]:
        return {"SLURM_CONF": str(self.conf)}

    def run(self, *cmd: str, check: bool = True) -> str:
        env = {**os.environ, **self.env()}
        res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=60)
        if check and res.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)}: {res.stderr}")
        return res.stdout

    def describe(self, job: str | None = None, log: str | Path | None = None) -> str:
        """What the scheduler says about the node (and ``job``), the tail of the job's own log
        and the daemons' logs: the message a timed-out wait prints."""
        parts = [
            "sinfo: " + self.run("sinfo", "-h", "-o", "%T %E", check=False).strip(),
            "squeue: " + self.run("squeue", "-h", "-o", "%i %T %r", check=False).strip(),
        ]
        if job:
            parts.append(self.run("scontrol", "show", "job", job, check=False).strip())
        if log and Path(log).exists():
            parts.append(f"{log}:\n" + Path(log).read_text(errors="replace")[-3000:])
        return "\n".join([*parts, self.logs()])

    def wait_idle(self, timeout: float = 120) -> None:
        """Wait until the node is idle again after a test's jobs (slurmd cleans up a finished
        job's processes before it takes the next); fail naming the node's state otherwise."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.run("sinfo", "-h", "-o", "%T", check=False).split() == ["idle"]:
                return
            time.sleep(0.5)
        raise AssertionError(f"the test SLURM node is not idle:\n{self.describe()}")

    def logs(self) -> str:
        return "\n".join(
            p.read_text(errors="replace")[-3000:] for p in sorted((self.root / "log").glob("*.log"))
        )

    def stop(self) -> None:
        self.run("scancel", "--user", "root", check=False)
        for pidfile in ("slurmd.pid", "slurmctld.pid", "munge/munged.pid"):
            path = self.root / pidfile
            if path.exists():
                with contextlib.suppress(ValueError, OSError):  # already gone
                    os.kill(int(path.read_text().strip()), 15)


def start_cluster(root: Path, cpus: int | None = None) -> SlurmCluster:
    """Start munged, slurmctld and slurmd under ``root``; wait until the node is idle."""
    cpus = cpus or os.cpu_count() or 1
    node = socket.gethostname().split(".")[0]
    for sub in ("state", "spool", "log", "munge"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    munge = root / "munge"
    key = munge / "munge.key"
    key.write_bytes(os.urandom(1024))
    key.chmod(0o600)
    munge.chmod(0o700)
    subprocess.run(
        [
            "munged",
            "--force",
            f"--socket={munge / 'sock'}",
            f"--key-file={key}",
            f"--pid-file={munge / 'munged.pid'}",
            f"--log-file={root / 'log' / 'munged.log'}",
            f"--seed-file={munge / 'seed'}",
        ],
        check=True,
        capture_output=True,
        text=True,
        timeout=30,
    )
    conf = root / "slurm.conf"
    conf.write_text(
        f"""ClusterName=shapebench-test
SlurmctldHost={node}(127.0.0.1)
SlurmUser=root
SlurmdUser=root
SlurmctldPort={_free_port()}
SlurmdPort={_free_port()}
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket={munge / "sock"}
StateSaveLocation={root / "state"}
SlurmdSpoolDir={root / "spool"}
SlurmctldPidFile={root / "slurmctld.pid"}
SlurmdPidFile={root / "slurmd.pid"}
SlurmctldLogFile={root / "log" / "slurmctld.log"}
SlurmdLogFile={root / "log" / "slurmd.log"}
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MpiDefault=none
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
NodeName={node} NodeAddr=127.0.0.1 CPUs={cpus} State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
"""
    )
    cluster = SlurmCluster(root, conf)
    env = {**os.environ, **cluster.env()}
    subprocess.run(["slurmctld", "-c"], env=env, check=True, timeout=30)
    subprocess.run(["slurmd", "-c", "-N", node], env=env, check=True, timeout=30)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        state = cluster.run("sinfo", "-h", "-o", "%T", check=False).strip()
        if state == "idle":
            return cluster
        time.sleep(0.5)
    logs = cluster.logs()
    cluster.stop()
    raise RuntimeError(f"the test SLURM node did not come up (state {state!r}):\n{logs}")


if __name__ == "__main__":  # start one by hand: python tests/slurm_cluster.py /tmp/slurm
    import sys

    c = start_cluster(Path(sys.argv[1] if len(sys.argv) > 1 else "/tmp/shapebench-slurm"))
    print(f"export SLURM_CONF={c.conf}")
