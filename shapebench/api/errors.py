"""Errors a user can act on.

Every error that reaches the command line is a :class:`ShapebenchError`: one message naming the bad
input and, where there is one, a hint saying how to fix it. The CLI prints both and exits with
status 2 instead of showing a traceback (set ``SHAPEBENCH_DEBUG=1`` to see it anyway).
"""

from __future__ import annotations

import warnings
from pathlib import Path


class ShapebenchError(Exception):
    """A problem with the user's input or environment, reported without a traceback."""

    def __init__(self, message: str, hint: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.hint = hint

    def __str__(self) -> str:
        return self.message if not self.hint else f"{self.message}\n  hint: {self.hint}"


class UnknownNameError(ShapebenchError):
    """A method, dataset, metric, profile or option name that nothing provides."""

    def __init__(self, kind: str, name: str, available: list[str], hint: str | None = None) -> None:
        listed = ", ".join(sorted(available)) or "(none installed)"
        super().__init__(
            f"unknown {kind} {name!r}; available: {listed}",
            hint or f"run 'shapebench {kind}s' to see what each {kind} does",
        )
        self.name = name
        self.available = sorted(available)


class PluginConflictError(ShapebenchError):
    """Two installed distributions register the same method, dataset or metric name."""


class DataNotFoundError(ShapebenchError):
    """A dataset's files are missing: the message says where they were looked for."""


class TrackingError(ShapebenchError):
    """The MLflow tracking store cannot be reached or used."""


class ConfigError(ShapebenchError):
    """A configuration file or option value that cannot be used."""


class Interrupted(ShapebenchError):
    """Ctrl-C or SIGTERM stopped the work; the message says what was kept (exit status 130)."""


# -- damaged files ------------------------------------------------------------------------


class CorruptFileWarning(UserWarning):
    """A cached file could not be read; it is deleted and rebuilt (the warning names it)."""


def warn_corrupt(path: Path, reason: str, action: str) -> None:
    """One line naming the damaged file, why it is unusable and what happens instead."""
    warnings.warn(f"{path} is damaged ({reason}); {action}", CorruptFileWarning, stacklevel=3)


def describe(exc: BaseException) -> str:
    """An exception as one short line: its type and the first line of its message."""
    lines = str(exc).strip().splitlines()
    first = lines[0].strip() if lines else ""
    if len(first) > 200:
        first = first[:197] + "..."
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__
