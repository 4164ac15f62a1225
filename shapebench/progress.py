"""Progress bars that stay out of logs.

A bar redraws itself with carriage returns: in a log file or a pipe (a cluster job, CI, ``| tee``)
that is one endless line, so bars are drawn on a terminal only, and the commands' summaries
say what was done.
"""

from __future__ import annotations

import sys
from typing import Any


def is_terminal() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed stderr
        return False


def progress_bar(
    total: int | None = None,
    desc: str = "",
    quiet: bool = False,
    leave: bool = False,
    unit: str = "obj",
    iterable: Any = None,
) -> Any:
    from tqdm import tqdm

    return tqdm(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        leave=leave,
        file=sys.stderr,
        disable=quiet or not is_terminal(),
    )
