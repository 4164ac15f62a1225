"""A child training's life tied to the process that started it: a killed ``run``, ``sweep`` or
local sweep worker leaves no training behind, and an interrupted one gives its child time to stop
cleanly.

On Linux the kernel sends the child SIGTERM when its parent dies, from the child's first
instruction on (:func:`die_with_parent`, armed between fork and exec); elsewhere, and for a
parent that died before the child was armed, a watchdog thread in the child does
(:func:`watch_parent`). SIGTERM is handled like Ctrl-C: a training saves and stops.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable

#: The pid of the process that started this training and waits for it (see watch_parent).
PARENT_ENV = "SHAPEBENCH_PARENT_PID"
#: How long a child training gets to stop cleanly after its parent was interrupted.
CHILD_GRACE_SECONDS = 30


#: prctl(2) option that has the kernel signal a process when its parent dies.
PR_SET_PDEATHSIG = 1


#: The signal that asked this process to stop, once one did (:func:`note_stop_signal`).
_stop_signal: str | None = None


def note_stop_signal(signum: int) -> None:
    """Remember that ``signum`` (SIGTERM, SIGINT) asked this process to stop.

    The ``KeyboardInterrupt`` such a signal raises can be lost: a signal that arrives while a
    library is being imported lands in code that may catch every exception (an optional import's
    probe), and the process carries on. A training that starts after that still stops
    (:func:`stop_requested`, read by the training before it fits and by ``StopOnSignal``)."""
    global _stop_signal
    _stop_signal = signal.Signals(signum).name


def stop_requested() -> str | None:
    """The name of the signal that asked this process to stop, or None."""
    return _stop_signal


def die_with_parent() -> Callable[[], None] | None:
    """A ``preexec_fn`` for :class:`subprocess.Popen` that has Linux send the child SIGTERM
    (handled like Ctrl-C: a training saves and stops, a sweep worker stops its own training)
    when this process dies, even by ``kill -9``; None where prctl(2) is not available.

    Armed between fork and exec, it covers the child's whole life: a Python-level watchdog only
    starts once the child has imported torch and prepared its data (seconds to minutes), and a
    parent killed before that left the child training on (issue 59). The signal follows the
    death of the forking *thread*, which waits for the child, so it fires when this process
    dies. The ctypes function is looked up here, in the parent: the child only calls it.
    """
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong]
    prctl.restype = ctypes.c_int
    parent = os.getpid()

    def arm() -> None:
        prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        if os.getppid() != parent:  # the parent died between fork and prctl
            os.kill(os.getpid(), signal.SIGTERM)

    return arm


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process reuses the pid
        return True
    return True


def watch_parent() -> None:
    """Stop this training (SIGTERM, handled like Ctrl-C) when the process that started it dies;
    called by the lead process of a training (not by the ranks Lightning launches, which
    Lightning stops with rank 0).

    The parent names itself in ``SHAPEBENCH_PARENT_PID``; a thread polls ``os.getppid()``,
    which changes when the parent dies (the child is re-parented), even after ``kill -9``. A
    parent already gone when this is called (it was killed while this process imported or
    prepared data) stops the training at once: that case used to skip the watchdog, and left an
    orphan training for good (issue 59). A process that inherited the variable from a
    grandparent still alive is not its child, and is not watched. On Linux
    :func:`die_with_parent` normally stops the child first; this is the fallback.
    """
    expected = os.environ.get(PARENT_ENV, "")
    if not expected.isdigit():
        return
    parent = int(expected)
    if os.getppid() != parent:
        if not _alive(parent):
            print(
                f"the process that started this training (pid {parent}) is gone: stopping",
                file=sys.stderr,
                flush=True,
            )
            os.kill(os.getpid(), signal.SIGTERM)
        return

    def poll() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=poll, name="shapebench-parent-watchdog", daemon=True).start()


def wait_child(proc: subprocess.Popen) -> int:
    """Wait for a child training; when this process is interrupted, give the child time to stop
    cleanly (it got the same Ctrl-C, or gets SIGTERM here) before killing it."""
    try:
        return proc.wait()
    except BaseException:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=CHILD_GRACE_SECONDS)
            except subprocess.TimeoutExpired:
                proc.kill()
        raise
