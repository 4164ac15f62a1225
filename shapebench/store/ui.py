"""``shapebench ui``: the MLflow UI on the workspace's store, with direct links.

The port is checked before anything is printed: MLflow's server would otherwise print its
banner, fail inside uvicorn with a traceback, and leave the caller with a URL that shows
someone else's server. The links open each experiment's runs page in shapebench's view (the
primary metric as a column, see :func:`shapebench.store.urls.view_state`), and the chart view
where
each method variant is one line of Chamfer distance against context size.
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from types import FrameType

from shapebench.api.errors import ShapebenchError
from shapebench.config import Settings
from shapebench.store.paging import search_all_experiments, search_all_runs
from shapebench.store.records import VIEW_TAG_PREFIX
from shapebench.store.urls import VIEW_KEY, experiment_url


def check_port(host: str, port: int) -> None:
    """Raise a :class:`ShapebenchError` naming the fix when ``host:port`` cannot be bound."""
    if not 0 < port < 65536:
        raise ShapebenchError(f"--port {port} is not a TCP port", "use a number from 1 to 65535")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise ShapebenchError(
            f"--host {host!r} is not an address of this machine ({exc})",
            "use 127.0.0.1, or 0.0.0.0 for every interface",
        ) from exc
    family, _, _, _, address = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        # The server binds with SO_REUSEADDR too: a port in TIME_WAIT is free for both.
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind(address)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise ShapebenchError(
                    f"port {port} on {host} is already in use (another MLflow UI, or another "
                    "program, is listening there)",
                    f"pick a free one: shapebench ui --port {port + 1}",
                ) from exc
            raise ShapebenchError(
                f"cannot listen on {host}:{port} ({exc.strerror})", "use another --host or --port"
            ) from exc


@dataclass
class ExperimentLink:
    name: str
    experiment_id: str
    runs: int
    url: str
    #: The chart view (one line per variant), for experiments shapebench set a view on.
    charts: str = ""


def experiment_links(client: object, base: str) -> list[ExperimentLink]:
    """A link per active experiment of the store, evaluations first, then trainings."""
    links = []
    for exp in search_all_experiments(client):
        has_view = VIEW_TAG_PREFIX + VIEW_KEY in exp.tags
        runs = len(search_all_runs(client, [exp.experiment_id]))
        links.append(
            ExperimentLink(
                exp.name,
                exp.experiment_id,
                runs,
                experiment_url(base, exp.experiment_id, view=has_view),
                experiment_url(base, exp.experiment_id, charts=True) if has_view else "",
            )
        )
    return sorted(links, key=lambda link: (not link.charts, link.name))


def shown_host(host: str) -> str:
    """The host to put in a URL: a wildcard address is reached on the loopback."""
    if host in ("0.0.0.0", "::", ""):
        return "127.0.0.1"
    return f"[{host}]" if ":" in host else host


def print_links(links: list[ExperimentLink], echo: Callable[[str], None]) -> None:
    if not links:
        echo("No experiments yet: run one (shapebench run -m gauss -d synthetic) and reload.")
        return
    echo(
        "Experiments (runs table; the charts link draws the primary metric against context "
        "size, one line per method variant):"
    )
    for link in links:
        echo(f"  {link.name} ({link.runs} runs): {link.url}")
        if link.charts:
            echo(f"  {'':<{len(link.name)}}   charts: {link.charts}")


#: The signals that stop `shapebench ui`: kill's default, Ctrl-C and a closed terminal.
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
#: Seconds the server's processes get to exit after the stop signal, before SIGKILL.
STOP_GRACE_S = 10.0


def serve(
    settings: Settings, host: str, port: int, workers: int, echo: Callable[[str], None]
) -> int:
    """Start the MLflow UI on the embedded store and wait until a signal stops it; return 0.

    Raises a :class:`ShapebenchError` when the server stops by itself."""
    from shapebench.store.tracking import open_client

    check_port(host, port)
    settings.artifact_root.mkdir(parents=True, exist_ok=True)
    # Opening the store creates (or upgrades) its schema under shapebench's lock, and retires
    # MLflow's empty "Default" experiment, before the server reads it.
    client = open_client(settings.tracking_uri)
    base = f"http://{shown_host(host)}:{port}"
    echo(f"MLflow UI: {base}  (store {settings.tracking_uri}; Ctrl-C stops)")
    print_links(experiment_links(client, base), echo)
    cmd = [
        sys.executable,
        "-m",
        "mlflow",
        "ui",
        "--backend-store-uri",
        settings.tracking_uri,
        "--default-artifact-root",
        settings.artifact_root.as_uri(),
        "--host",
        host,
        "--port",
        str(port),
        "--workers",
        str(workers),
    ]
    # The background job runner serves MLflow's GenAI features, not run comparison; without it
    # the UI starts in seconds with a fraction of the memory.
    env = dict(os.environ)
    env.setdefault("MLFLOW_SERVER_ENABLE_JOB_EXECUTION", "false")
    sys.stdout.flush()  # the links first, even into a pipe, then the server's own output
    status = run_server(cmd, env)
    if status is not None:
        # A server that returns by itself failed, even with status 0: mlflow exits 0 when
        # uvicorn cannot bind (a program that took the port after our check).
        raise ShapebenchError(
            f"the MLflow server on {host}:{port} stopped by itself (status {status})",
            "its own messages above say why; a port taken meanwhile: try another --port",
        )
    # Stopped by Ctrl-C, `kill` or a closed terminal: the way the UI is meant to end, so status 0
    # (not 128 + the signal's number, which would read as a failure to scripts and services).
    return 0


class _StopRequested(Exception):
    """A stop signal reached `shapebench ui` while it waited for the server."""


def run_server(cmd: list[str], env: dict[str, str]) -> int | None:
    """Run the server ``cmd`` until it exits or a stop signal reaches this process, then make
    sure none of its processes is left; return its exit status, or ``None`` when stopped.

    The server gets a session (and process group) of its own, and SIGTERM, SIGINT and SIGHUP
    stop that whole group: `mlflow ui` runs uvicorn as a child process, which a signal to this
    process alone (``kill PID``, a service manager) would otherwise leave running on the port,
    re-parented to init. Main thread only (it installs signal handlers).
    """
    received: list[int] = []
    proc: subprocess.Popen[bytes] | None = None
    waiting = False  # for the server to return: a stop signal ends that wait

    def stop_group() -> None:
        # SIGTERM whichever signal came: uvicorn shuts down cleanly on it, while on SIGINT it
        # at times skips its shutdown and prints a KeyboardInterrupt traceback. A second
        # signal (Ctrl-C again) means "now".
        if proc is not None:
            _signal_group(proc.pid, signal.SIGTERM if len(received) == 1 else signal.SIGKILL)

    def on_stop_signal(signum: int, frame: FrameType | None) -> None:
        nonlocal waiting
        received.append(signum)
        stop_group()  # without a process yet, done as soon as the server has one
        # Raised once, and only out of the wait: a later signal must not cut the clean-up in
        # _end_group short.
        if waiting:
            waiting = False
            raise _StopRequested

    # Installed before the server starts: no signal can come between its start and handlers
    # that stop it.
    previous = {sig: signal.signal(sig, on_stop_signal) for sig in STOP_SIGNALS}
    status = None
    try:
        try:
            proc = subprocess.Popen(cmd, env=env, start_new_session=True)
            # Set before looking at `received`, so that a signal after the look is not missed.
            waiting = True
            if received:  # it came while the server was being started
                stop_group()
            else:
                status = proc.wait()
            waiting = False  # in the try: a signal just before this is still caught below
        except _StopRequested:
            pass
        finally:
            waiting = False
            # Also when this process fails (an exception in the wait): the server must not
            # outlive it.
            if proc is not None:
                _end_group(proc, signalled=bool(received))
    finally:
        for sig, handler in previous.items():
            if handler is not None:  # None: set outside Python, cannot be put back from here
                signal.signal(sig, handler)
    return None if received else status


def _signal_group(pgid: int, signum: int) -> None:
    with contextlib.suppress(ProcessLookupError):  # the whole group is gone already
        os.killpg(pgid, signum)


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def _end_group(proc: subprocess.Popen[bytes], signalled: bool) -> None:
    """Stop the server's process group (SIGTERM unless a stop signal was forwarded to it already)
    and wait for it, SIGKILLing whatever is left after :data:`STOP_GRACE_S` seconds."""
    deadline = time.monotonic() + STOP_GRACE_S
    if not signalled:
        # A server that returned by itself may still have a child running (uvicorn, when the
        # `mlflow ui` process died alone).
        _signal_group(proc.pid, signal.SIGTERM)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=STOP_GRACE_S)
    # uvicorn is not our child, so it cannot be waited for: the port is free once the group is
    # empty (a zombie not yet reaped by init counts as alive, hence the deadline).
    while _group_alive(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    if _group_alive(proc.pid):
        _signal_group(proc.pid, signal.SIGKILL)
        proc.wait()
