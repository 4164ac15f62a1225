"""Inter-process locks on files: one training per checkpoint key, one computation per cell.

A lock is an exclusive POSIX record lock (``fcntl.lockf``) on a small file that also holds the
owner's host and pid, for messages. The kernel releases the lock when its process dies, even
by ``kill -9``, so a lock can never be left stale: there is no timeout to guess and nothing to
clean up. POSIX locks work across the nodes of a cluster on NFS v4 and Lustre; on filesystems
without them (some FUSE mounts) :func:`try_lock` raises ``OSError`` and callers fall back to
running without one.

POSIX locks belong to a (process, file) pair: closing *any* descriptor of the file drops the
lock, so a process opens each lock file once (:class:`FileLock` keeps the descriptor).
"""

from __future__ import annotations

import fcntl
import os
import socket
import time
from collections.abc import Callable
from pathlib import Path


class FileLock:
    """A held lock; :meth:`release` (or leaving the ``with`` block) gives it back."""

    def __init__(self, path: Path, fd: int) -> None:
        self.path = path
        self._fd: int | None = fd

    def release(self) -> None:
        if self._fd is not None:
            fcntl.lockf(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> FileLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def owner(path: Path) -> str:
    """Who holds (or last held) the lock at ``path``: ``host pid N``, or ``""``."""
    try:
        return Path(path).read_text().strip()
    except OSError:
        return ""


def try_lock(path: Path) -> FileLock | None:
    """Take the lock at ``path`` if it is free; ``None`` if another process holds it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        if exc.errno in (11, 13):  # EAGAIN / EACCES: held by another process
            return None
        raise
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{socket.gethostname()} pid {os.getpid()}\n".encode(), 0)
    return FileLock(path, fd)


def wait_lock(
    path: Path, on_wait: Callable[[str], None] | None = None, poll: float = 0.5
) -> FileLock:
    """Take the lock at ``path``, waiting while another process holds it; ``on_wait`` is called
    once, with the holder, when there is a wait. Polling (rather than a blocking ``lockf``)
    keeps Ctrl-C and signal handlers working while waiting."""
    told = False
    while True:
        lock = try_lock(path)
        if lock is not None:
            return lock
        if on_wait is not None and not told:
            on_wait(owner(path) or "another process")
            told = True
        time.sleep(poll)
