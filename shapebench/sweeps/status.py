"""Where a cluster sweep stands (``shapebench sweep FILE --status``): each cell finished, running,
queued, failed or not submitted, from the store, the cells' claim locks, the sweep's manifest of
submitted jobs (:func:`shapebench.sweeps.cluster.read_manifest`) and SLURM's queue.

A job has ended when it left the queue (``squeue``): this needs no accounting database (``sacct``
is missing on many small clusters). :func:`shapebench.sweeps.cluster.wait_for` reads the queue
the same way.
"""

from __future__ import annotations

import os
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from shapebench.config import Settings
from shapebench.sweeps.plan import CellTask, SweepPlan


def slurm_queue() -> dict[str, str]:
    """SLURM's queue (job id -> state), empty where there is no ``squeue``."""
    try:
        out = subprocess.run(
            ["squeue", "-h", "-o", "%i %T"], capture_output=True, text=True, timeout=30, check=True
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return {}
    states = {}
    for line in out.splitlines():
        if " " in line:
            jid, state = line.split(None, 1)
            states[jid] = state.lower()
    return states


def job_state(job: dict[str, Any], queue: dict[str, str]) -> str:
    jid = job["job_id"]
    if job["launcher"] == "submitit-local":
        try:
            os.kill(int(jid), 0)
            return "running"
        except (ValueError, OSError):
            return "ended"
    if jid in queue:
        return queue[jid]
    base, _, task = jid.partition("_")
    for qid, state in queue.items():  # a pending array shows as 123_[4-7%2]
        if qid.startswith(f"{base}_[") and task:
            return state
    return "ended"


@dataclass
class CellStatus:
    cell: CellTask
    state: str  # finished, running, queued, failed, not submitted
    job: dict[str, Any] | None = None


def sweep_status(
    plan: SweepPlan, settings: Settings, manifest: list[dict[str, Any]]
) -> list[CellStatus]:
    """Each cell's state from the store (finished), its claim lock (running), and the last job
    it was submitted in (queued, or failed when that job ended without finishing it)."""
    from shapebench.store.locks import try_lock
    from shapebench.store.tracking import cell_lock_path

    last_job: dict[str, dict[str, Any]] = {}
    for job in manifest:
        for key in job["keys"]:
            last_job[key] = job
    queue = slurm_queue()
    out = []
    for cell in plan.cells:
        job = last_job.get(cell.key)
        if cell.key in plan.finished:
            out.append(CellStatus(cell, "finished", job))
            continue
        lock = try_lock(cell_lock_path(settings, cell.key))
        if lock is None:
            out.append(CellStatus(cell, "running", job))
            continue
        lock.release()
        if job is None:
            out.append(CellStatus(cell, "not submitted"))
            continue
        state = job_state(job, queue)
        out.append(CellStatus(cell, "failed" if state == "ended" else state, job))
    return out


def print_status(statuses: list[CellStatus], plan: SweepPlan, echo: Callable[[str], None]) -> None:
    counts: dict[str, int] = {}
    for s in statuses:
        counts[s.state] = counts.get(s.state, 0) + 1
    order = ["finished", "running", "pending", "queued", "failed", "not submitted"]
    shown = [f"{counts[k]} {k}" for k in order if k in counts]
    shown += [f"{v} {k}" for k, v in counts.items() if k not in order]
    echo(f"{len(statuses)} cells: " + ", ".join(shown))
    to_train = [t for t in plan.trainings if not t.shipped]
    shipped = [t for t in plan.trainings if t.shipped]
    if to_train:
        echo(f"{len(to_train)} trainings missing: " + ", ".join(t.name for t in to_train))
    if shipped:
        echo(
            f"{len(shipped)} trainings served by shipped reference weights (installed when their "
            "cells run; --retrain trains them instead): " + ", ".join(t.name for t in shipped)
        )
    for s in statuses:
        if s.state == "failed" and s.job is not None:
            echo(f"  failed: {s.cell.name}: job {s.job['job_id']}, log {s.job['stderr']}")
        elif s.state not in ("finished", "not submitted"):
            jid = s.job["job_id"] if s.job else "-"
            echo(f"  {s.state}: {s.cell.name} (job {jid})")
    for error in plan.errors:
        echo(f"  cannot run: {error}")
