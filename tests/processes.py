"""Watching the processes a test started: wait for a condition, find live processes by their
command line, and read how far a tiny IGR training in a workspace has got."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

from shapebench.train.checkpoints import checkpoint_epochs


def wait_for(
    condition: Callable[[], object],
    timeout: float = 120,
    what: str = "",
    explain: Callable[[], str] | None = None,
) -> object:
    """Poll ``condition`` until it is truthy; on timeout fail with ``what`` and, from
    ``explain``, what the test can say about why (a job's log, the scheduler's view)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    why = f"\n{explain()}" if explain else ""
    raise AssertionError(f"timed out waiting for {what or condition}{why}")


def processes_mentioning(text: str, parent: int | None = None) -> list[int]:
    """Live processes whose command line contains ``text`` (zombies excluded); with ``parent``,
    only that process's children, so that a test never signals a process it did not start (a
    user's own sweep on the same machine, say)."""
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit() or int(proc.name) == os.getpid():
            continue
        try:
            cmdline = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            state, ppid = (proc / "stat").read_text().rsplit(")", 1)[1].split()[:2]
        except OSError:
            continue
        if text in cmdline and state != "Z" and (parent is None or int(ppid) == parent):
            found.append(int(proc.name))
    return found


def lock_holders(folder: Path, pattern: str = "*.lock") -> dict[int, list[Path]]:
    """The processes holding a POSIX lock on a file of ``folder`` matching ``pattern``, read
    from ``/proc/locks``: unlike trying the lock, looking takes nothing from its holder (a
    worker that found its cell's lock taken would leave the cell for later)."""
    files = {}
    for path in Path(folder).glob(pattern):
        try:
            files[path.stat().st_ino] = path
        except OSError:
            continue
    held: dict[int, list[Path]] = {}
    for line in Path("/proc/locks").read_text().splitlines():
        fields = line.split()
        if "->" in fields or len(fields) < 6 or fields[1] != "POSIX":
            continue  # a waiter's line, or another kind of lock
        pid, inode = int(fields[4]), int(fields[5].rsplit(":", 1)[1])
        if inode in files:
            held.setdefault(pid, []).append(files[inode])
    return held


def last_ckpt(sb) -> Path | None:
    found = list((sb.workspace / "checkpoints" / "igr").glob("*/last.ckpt"))
    return found[0] if found else None


def saved_epochs(sb) -> int:
    path = last_ckpt(sb)
    return (checkpoint_epochs(path) or 0) if path else 0
