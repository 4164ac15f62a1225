"""Start ``python -m shapebench`` commands for the tests by forking a pre-imported interpreter.

Most of a CLI test's time on a 2-core machine went into importing, not into shapebench: a cached
``shapebench run -m gauss`` spent 8.8 of its 9.2 s importing MLflow's SQL store, pandas, trimesh,
torch and Lightning (``python -X importtime``). :class:`ForkServer` starts one interpreter per
pytest process that imports those third-party modules once and then forks a child per command.
The child is a process of its own, as with ``subprocess.run``: its own environment, working
directory, ``sys.argv``, stdout and stderr (files), exit status and pid (a test can kill it). It
imports shapebench itself and every plugin fresh, after the fork, from the ``sys.path`` the
command's ``PYTHONPATH`` gives, so an edited or pip-installed plugin is seen as in a new
interpreter. The server runs no torch operation before forking (no thread pool to inherit).

What differs from ``exec``: the third-party modules above are already in ``sys.modules``, and
their import-time reads of the environment (OpenMP's ``OMP_NUM_THREADS``) come from the test
process's environment. A command that depends on those starts with ``exec`` instead
(:meth:`Shapebench.__call__` decides), and ``SHAPEBENCH_TEST_EXEC=1`` makes every command do so.

Protocol: one JSON request per line on the server's stdin; for each, a line ``{"pid": ...}``
when the child starts and ``{"rc": ...}`` when it ends, on the file descriptor named by the
server's argument.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

#: Imported once by the server: what every command imports and nothing of shapebench's.
PRELOAD = (
    "numpy",
    "scipy.spatial",
    "scipy.stats",
    "pandas",
    "yaml",
    "click",
    "pluggy",
    "trimesh",
    "sqlalchemy",
    "mlflow",
    "mlflow.tracking",
    "mlflow.store.tracking.sqlalchemy_store",
    "torch",
    "pytorch_lightning",
)


def _child(request: dict[str, Any], channel: int) -> int:
    """Become the command: environment, directory, files, path; run it; its exit status."""
    import importlib
    import runpy

    os.close(channel)
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    for fd, path in ((1, request["stdout"]), (2, request["stderr"])):
        out = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(out, fd)
        os.close(out)
    sys.stdin = open(0, closefd=False)  # noqa: SIM115
    sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115
    sys.stderr = open(2, "w", closefd=False, buffering=1)  # noqa: SIM115
    sys.__stdout__, sys.__stderr__ = sys.stdout, sys.stderr
    # `python -m`: the working directory first, then PYTHONPATH, then the installed packages.
    extra = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    sys.path[:] = [os.getcwd(), *extra, *request["base_path"]]
    importlib.invalidate_caches()
    sys.argv = [request["argv0"], *request["args"]]
    try:
        runpy.run_module("shapebench", run_name="__main__", alter_sys=True)
        return 0
    except SystemExit as exc:
        code = exc.code
        if code is None:
            return 0
        if isinstance(code, int):
            return code
        print(code, file=sys.stderr)
        return 1


def _exit(code: int) -> None:
    """End the child as the interpreter would (threads joined, atexit handlers run, streams
    flushed), without tearing down the thousands of modules it inherited: that took a second."""
    import atexit

    threading._shutdown()  # type: ignore[attr-defined]  # what Py_FinalizeEx does first
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a stream the command closed
            stream.flush()
    os._exit(code)


def serve(channel: int) -> None:
    """The server's loop (``python tests/cli_fork.py FD``: replies go to file descriptor FD)."""
    import importlib

    for name in PRELOAD:
        importlib.import_module(name)
    base_path = [p for p in sys.path[1:]]  # without this script's folder
    reply = os.fdopen(os.dup(channel), "w", buffering=1)
    for line in sys.stdin:
        request = json.loads(line)
        request["base_path"] = base_path
        pid = os.fork()
        if pid == 0:
            reply.close()
            code = _child(request, channel)
            _exit(code)
        reply.write(json.dumps({"pid": pid}) + "\n")
        _, status = os.waitpid(pid, 0)
        reply.write(json.dumps({"rc": os.waitstatus_to_exitcode(status)}) + "\n")


class ForkServer:
    """One server per pytest process, started on first use; one command at a time."""

    def __init__(self) -> None:
        self._proc: subprocess.Popen | None = None
        self._replies = None
        self._lock = threading.Lock()

    def _start(self) -> None:
        read, write = os.pipe()
        self._proc = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), str(write)],
            stdin=subprocess.PIPE,
            text=True,
            pass_fds=(write,),
        )
        os.close(write)
        self._replies = os.fdopen(read, "r")

    def _read(self, timeout: float | None) -> dict[str, Any] | None:
        assert self._replies is not None
        if timeout is not None:
            ready, _, _ = select.select([self._replies], [], [], max(timeout, 0))
            if not ready:
                return None
        line = self._replies.readline()
        if not line:
            raise RuntimeError("the CLI fork server died (rerun with SHAPEBENCH_TEST_EXEC=1)")
        return json.loads(line)

    def run(
        self, args: list[str], env: dict[str, str], cwd: Path, timeout: float
    ) -> subprocess.CompletedProcess:
        """Like ``subprocess.run([python, -m, shapebench, *args], capture_output=True)``."""
        import tempfile

        with self._lock:
            if self._proc is None or self._proc.poll() is not None:
                self._start()
            assert self._proc is not None and self._proc.stdin is not None
            with tempfile.TemporaryDirectory(prefix="sb-cli-") as tmp:
                out, err = Path(tmp) / "stdout", Path(tmp) / "stderr"
                request = {
                    "args": list(args),
                    "env": env,
                    "cwd": str(cwd),
                    "stdout": str(out),
                    "stderr": str(err),
                    "argv0": str(Path(sys.executable).parent / "shapebench"),
                }
                self._proc.stdin.write(json.dumps(request) + "\n")
                self._proc.stdin.flush()
                started = self._read(60)
                if started is None:
                    raise RuntimeError("the CLI fork server did not start the command")
                done = self._read(timeout)
                if done is None:
                    os.kill(started["pid"], 9)
                    self._read(None)
                    raise subprocess.TimeoutExpired(
                        ["shapebench", *args], timeout, out.read_text(), err.read_text()
                    )
                return subprocess.CompletedProcess(
                    ["shapebench", *args], done["rc"], out.read_text(), err.read_text()
                )

    def close(self) -> None:
        if self._proc is not None and self._proc.stdin is not None:
            self._proc.stdin.close()
            try:
                self._proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self._proc.kill()
        if self._replies is not None:
            self._replies.close()


if __name__ == "__main__":
    serve(int(sys.argv[1]))
