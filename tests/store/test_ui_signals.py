"""`shapebench ui` stopped by a signal to its own PID stops the MLflow server it started (issue 32).

Only the `shapebench ui` process is signalled, as `kill PID`, a service manager or a parent
would do, never its process group: a terminal's Ctrl-C reaches the whole group and would hide
a server left behind.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from itertools import pairwise
from pathlib import Path

import pytest
from browser_support import wait_http
from conftest import Shapebench, free_port

from shapebench.store import ui
from shapebench.store.ui import run_server

pytestmark = [pytest.mark.server, pytest.mark.slow]  # starts servers and CLI subprocesses

#: How long the server's processes may take to go once `shapebench ui` got the signal.
STOP_TIMEOUT = 15.0


def processes_on_port(port: int) -> dict[int, str]:
    """The processes whose command line holds ``--port PORT`` (`shapebench ui`, `mlflow ui`,
    uvicorn), PID to command line."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            args = (entry / "cmdline").read_bytes().decode(errors="replace").split("\0")
        except OSError:  # it exited meanwhile
            continue
        if any(a == "--port" and b == str(port) for a, b in pairwise(args)):
            found[int(entry.name)] = " ".join(args).strip()
    return found


def port_answers(port: int) -> bool:
    with socket.socket() as sock:
        sock.settimeout(1)
        return sock.connect_ex(("127.0.0.1", port)) == 0


def port_bindable(port: int) -> bool:
    with socket.socket() as sock:
        # As `shapebench ui` checks it: a connection in TIME_WAIT does not hold the port.
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind(("127.0.0.1", port))
        except OSError:
            return False
        return True


def kill_leftovers(proc: subprocess.Popen, port: int) -> None:
    """SIGKILL the process group of `shapebench ui` and of anything still serving ``port``.

    A server left behind by the bug must not outlive the test and hold the port, whether it is
    still in the group of `shapebench ui` or in a group of its own.
    """
    groups = {proc.pid}
    for pid in processes_on_port(port):
        with contextlib.suppress(ProcessLookupError):
            groups.add(os.getpgid(pid))
    groups.discard(os.getpgrp())  # never the test run itself
    for pgid in groups:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pgid, signal.SIGKILL)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=10)


@pytest.fixture
def running_ui(
    shapebench: Shapebench, tmp_path: Path
) -> Iterator[tuple[subprocess.Popen, int, Path]]:
    """`shapebench ui` on a free port, answering HTTP; everything it started is gone afterwards."""
    port = free_port()
    log = tmp_path / "ui.log"
    # Output to a file, not a pipe nobody reads: a full pipe would block the server.
    with log.open("w") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "shapebench", "ui", "--port", str(port)],
            env=shapebench.env(),
            cwd=shapebench.workspace,
            stdout=out,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
    try:
        try:
            wait_http(f"http://127.0.0.1:{port}/health", proc)
        except (RuntimeError, TimeoutError) as exc:
            pytest.fail(f"shapebench ui did not start ({exc!r}):\n{log.read_text()}")
        yield proc, port, log
    finally:
        kill_leftovers(proc, port)


def wait_until(condition: Callable[[], bool], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.2)
    return condition()


@pytest.mark.parametrize(
    "signum", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT], ids=["SIGTERM", "SIGHUP", "SIGINT"]
)
def test_signal_to_ui_stops_the_server(
    running_ui: tuple[subprocess.Popen, int, Path], signum: signal.Signals
) -> None:
    proc, port, log = running_ui
    os.kill(proc.pid, signum)  # the PID only, not its group

    try:
        status = proc.wait(timeout=STOP_TIMEOUT)
    except subprocess.TimeoutExpired:
        pytest.fail(f"shapebench ui still runs {STOP_TIMEOUT:.0f} s after {signum.name}")
    assert status == 0, f"shapebench ui exited with status {status} after {signum.name}"

    stopped = wait_until(lambda: not port_answers(port) and port_bindable(port), STOP_TIMEOUT)
    left = processes_on_port(port)
    assert stopped and not left, (
        f"port {port} still served {STOP_TIMEOUT:.0f} s after {signum.name} to shapebench ui, "
        f"by {left}"
    )
    # The server was stopped, not killed or interrupted mid-way: uvicorn's shutdown completed.
    output = log.read_text()
    assert "Application shutdown complete" in output and "Traceback" not in output, output


# run_server itself, on small shell "servers" whose process groups are easy to watch.


def group_gone(pgid: int, timeout: float = 5.0) -> bool:
    def gone() -> bool:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return True
        return False

    return wait_until(gone, timeout)


def test_a_server_returning_by_itself_gives_its_status_and_leaves_nothing(tmp_path: Path) -> None:
    pid_file = tmp_path / "pid"
    # `mlflow ui` dying alone leaves uvicorn, its child, running: the `sleep` here.
    status = run_server(["sh", "-c", f"echo $$ > {pid_file}; sleep 60 & exit 3"], dict(os.environ))
    assert status == 3
    assert group_gone(int(pid_file.read_text()))


def test_a_server_ignoring_the_signal_is_killed_after_the_grace(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(ui, "STOP_GRACE_S", 1.0)
    pid_file = tmp_path / "pid"
    # The server signals `shapebench ui` (this process) itself once it runs, then ignores it.
    script = f"trap '' TERM HUP INT; echo $$ > {pid_file}; sleep 60 & kill -TERM $PPID; wait"
    before = {sig: signal.getsignal(sig) for sig in ui.STOP_SIGNALS}
    started = time.monotonic()
    assert run_server(["sh", "-c", script], dict(os.environ)) is None
    assert time.monotonic() - started < 10
    assert group_gone(int(pid_file.read_text()))
    assert {sig: signal.getsignal(sig) for sig in ui.STOP_SIGNALS} == before


def test_a_second_signal_kills_the_server_at_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(ui, "STOP_GRACE_S", 60.0)
    pid_file = tmp_path / "pid"
    # Ctrl-C pressed again while a server takes its time to stop.
    script = (
        f"trap '' TERM HUP INT; echo $$ > {pid_file}; sleep 60 & "
        "kill -TERM $PPID; sleep 0.5; kill -INT $PPID; wait"
    )
    started = time.monotonic()
    assert run_server(["sh", "-c", script], dict(os.environ)) is None
    assert time.monotonic() - started < 10
    assert group_gone(int(pid_file.read_text()))


def test_an_exception_in_shapebench_ui_stops_the_server(tmp_path: Path) -> None:
    def fail(signum: int, frame: object) -> None:
        raise RuntimeError("shapebench ui failed")

    pid_file = tmp_path / "pid"
    previous = signal.signal(signal.SIGALRM, fail)
    try:
        with pytest.raises(RuntimeError, match="shapebench ui failed"):
            # The delay lets run_server reach its wait before the exception.
            run_server(
                ["sh", "-c", f"echo $$ > {pid_file}; sleep 60 & sleep 0.5; kill -ALRM $PPID; wait"],
                dict(os.environ),
            )
    finally:
        signal.signal(signal.SIGALRM, previous)
    assert group_gone(int(pid_file.read_text()))
