"""Running a sweep's cells in several worker processes on this machine (``--launcher local``).

Each worker is the same ``shapebench sweep`` command run inline: workers coordinate through the
locks every run already takes (:mod:`shapebench.store.locks`): a cell is computed by the first
worker
that claims it and read back by the others, a checkpoint key is trained once while the others
wait for it. Workers visit the sweep's methods in different orders
(:func:`shapebench.sweeps.spec.worker_order`: the second one backwards), so they start on
different methods instead of queueing behind one training, and rarely wait for each other's
cells. Torch gets ``cores // N`` threads
per worker (``OMP_NUM_THREADS``), so N workers do not oversubscribe the machine; ``sweep
--threads`` sets another number (fewer, to evaluate beside a training).

Nothing here is a scheduler: killing a worker loses at most its cell in progress (its lock is
released with it), and rerunning the sweep computes what is missing. The workers die with the
sweep that started them, even when it is killed with ``kill -9``: the kernel sends each one
SIGTERM (:func:`shapebench.train.lifecycle.die_with_parent`), which stops it like Ctrl-C, its
training child included.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

#: Options of ``sweep`` that choose the launcher: stripped from the workers' command line.
LAUNCHER_FLAGS = {"--launcher": True, "--jobs": True, "-j": True, "--slurm": True}


#: Set in the environment of ``--launcher local``'s workers: a worker in which every object of
#: some cell failed exits with :data:`ALL_FAILED_STATUS` (its summary says which), so that any
#: other non-zero status, Python's 1 for an uncaught exception included, is a crashed worker.
WORKER_ENV = "SHAPEBENCH_SWEEP_WORKER"
ALL_FAILED_STATUS = 3


def worker_argv(argv: list[str], index: int) -> list[str]:
    """The sweep's command line for worker ``index``: launcher options replaced by ``--launcher
    inline --worker index`` (``argv`` without the program name)."""
    out: list[str] = []
    skip = False
    for arg in argv:
        if skip:
            skip = False
            continue
        name = arg.split("=", 1)[0]
        if name in LAUNCHER_FLAGS or (arg.startswith("-j") and arg[2:].isdigit()):
            skip = "=" not in arg and name in LAUNCHER_FLAGS
            continue
        out.append(arg)
    return out + ["--launcher", "inline", "--worker", str(index)]


def threads_per_worker(jobs: int, threads: int | None = None) -> int:
    """Torch threads for each of ``jobs`` workers: ``threads`` (``sweep --threads``) where given,
    else the machine's cores shared between them."""
    return threads or max(1, (os.cpu_count() or 1) // max(jobs, 1))


def thread_env(threads: int) -> dict[str, str]:
    """The environment that gives torch, OpenMP and MKL ``threads`` threads in a process that
    loads them after it is set."""
    return {"OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}


def use_threads(threads: int) -> None:
    """Run this process's torch on ``threads`` threads (and the OpenMP and MKL libraries it loads
    from now on): what a local worker gets from its environment."""
    import torch

    os.environ.update(thread_env(threads))
    torch.set_num_threads(threads)


def worker_command(argv: list[str], index: int) -> list[str]:
    """The command line of ``--launcher local``'s worker ``index``."""
    return [sys.executable, "-m", "shapebench", "sweep", *worker_argv(argv, index)]


def run_local(
    argv: list[str],
    jobs: int,
    log_dir: Path,
    echo: Callable[[str], None],
    threads_each: int | None = None,
) -> int:
    """Run ``jobs`` workers of the sweep whose command line is ``argv``, with ``threads_each``
    torch threads each (None: :func:`threads_per_worker`); the number of workers that failed.
    Ctrl-C stops them (each saves its training checkpoint, as on Ctrl-C)."""
    from shapebench.train.lifecycle import die_with_parent

    log_dir.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    env = dict(os.environ)
    threads = threads_per_worker(jobs, threads_each)
    env.update(thread_env(threads), PYTHONSAFEPATH="1")
    env[WORKER_ENV] = "1"
    procs: list[tuple[subprocess.Popen, Path]] = []
    for i in range(jobs):
        log = log_dir / f"sweep-{stamp}-worker{i}.log"
        with open(log, "w") as out:
            cmd = worker_command(argv, i)
            proc = subprocess.Popen(
                cmd, env=env, stdout=out, stderr=subprocess.STDOUT, preexec_fn=die_with_parent()
            )
            procs.append((proc, log))
    echo(f"{jobs} workers, {threads} torch threads each; logs: {log_dir}/sweep-{stamp}-worker*.log")
    try:
        codes = [p.wait() for p, _ in procs]
    except BaseException:
        for p, _ in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p, _ in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
        raise
    failed = 0
    for (_, log), code in zip(procs, codes, strict=True):
        if code not in (0, ALL_FAILED_STATUS):  # all-failed cells: reported by the summary
            failed += 1
            echo(f"worker exited with status {code}: see {log}")
    return failed
