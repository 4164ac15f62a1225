"""The ``shapebench`` command line: thin adapters over functions callable from Python.

:mod:`~shapebench.cli.app` holds the command group and the options every command shares; one
module per command family registers its commands on it.
"""

from shapebench.cli.app import cli, main

__all__ = ["cli", "main"]
