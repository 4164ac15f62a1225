"""The ``shapebench`` command line: thin adapters over functions callable from Python.

:mod:`~shapebench.cli.app` holds the command group, the options every command shares and
:func:`main`; each command family registers its commands on the group from a module of its own:

* :mod:`~shapebench.cli.evaluate`: ``run``, ``sweep``, ``train``;
* :mod:`~shapebench.cli.results`: ``leaderboard``, ``report``, ``runs``, ``show``, ``ui``,
  ``merge``;
* :mod:`~shapebench.cli.plugins`: ``plugins``, ``methods``, ``datasets``, ``metrics``,
  ``check``;
* :mod:`~shapebench.cli.data`: ``prepare``;
* :mod:`~shapebench.cli.exchange`: ``export``, ``import`` (contexts out, completions back);
* :mod:`~shapebench.cli.init`: ``init``.

A new command goes in the family it belongs to (or a new module imported here), parses its
options and calls a function of the room below that does the work.
"""

from shapebench.cli import (  # noqa: F401 (register the commands)
    data,
    evaluate,
    exchange,
    init,
    plugins,
    results,
)
from shapebench.cli.app import cli, main

__all__ = ["cli", "main"]
