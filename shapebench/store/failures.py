"""When the store itself fails: the disk holding it is full, or the tracking server stopped
answering in the middle of a run.

Both reach shapebench as whatever the layer underneath raised (an ``OSError`` from a copy, a
SQLAlchemy error from SQLite, an :class:`mlflow.exceptions.MlflowException` wrapping a
``requests`` connection error), often as the *context* of a second error raised while cleaning
up. :func:`store_failure` recognises them anywhere in that chain and says what happened in one
line, with what to do; the command line and :func:`shapebench.evaluate` raise that instead of
the chain. Nothing is lost: a cell's run is marked finished only after its last artifact is
written, so the cells that were not finished are computed again by the next run, and finished
ones are found.

This module imports nothing heavy: the command line consults it after an error.
"""

from __future__ import annotations

import errno
from collections.abc import Iterator

from shapebench.api.errors import ShapebenchError

_RESUME = "then run the same command again: finished cells are kept, the others are computed"

#: Text of errors that mean the tracking server did not answer (requests, urllib3, MLflow's REST
#: client wraps them in an MlflowException whose message is all that is left of them).
_NO_ANSWER = (
    "Connection refused",
    "Max retries exceeded",
    "Connection aborted",
    "RemoteDisconnected",
    "NewConnectionError",
)


class StoreFailure(ShapebenchError):
    """The store could not be written or reached; the message says which and what to do."""


def _chain(exc: BaseException) -> Iterator[BaseException]:
    seen: set[int] = set()
    todo = [exc]
    while todo:
        e = todo.pop()
        if id(e) in seen:
            continue
        seen.add(id(e))
        yield e
        todo += [c for c in (e.__cause__, e.__context__) if c is not None]


def store_failure(exc: BaseException, uri: str | None = None) -> StoreFailure | None:
    """One clear error for a full disk or a tracking server that stopped answering anywhere in
    ``exc``'s chain, or None when ``exc`` is something else. ``uri``: the tracking URI, named in
    the message; a server's silence is recognised only for an http(s) URI."""
    if isinstance(exc, StoreFailure):
        return exc
    for e in _chain(exc):
        if isinstance(e, OSError) and e.errno == errno.ENOSPC:
            where = getattr(e, "filename2", None) or e.filename
            return StoreFailure(
                "no space left on the device" + (f" writing {where}" if where else ""),
                f"free some space (or move --workspace or --cache-dir to a larger disk), {_RESUME}",
            )
        text = str(e)
        if "database or disk is full" in text:
            return StoreFailure(
                "no space left for the MLflow database" + (f" {uri}" if uri else ""),
                f"free some space (or move --workspace to a larger disk), {_RESUME}",
            )
        # Only a store behind a server can stop answering: a method's own download failing
        # the same way is the method's error, not the store's.
        if not (uri or "").startswith(("http://", "https://")):
            continue
        module = type(e).__module__.split(".")[0]
        if (module in ("requests", "urllib3") and "Connection" in type(e).__name__) or any(
            marker in text for marker in _NO_ANSWER
        ):
            return StoreFailure(
                "the MLflow tracking server"
                + (f" at {uri}" if uri else "")
                + " stopped answering in the middle of the run",
                f"restart it (or check the network), {_RESUME}",
            )
    return None
