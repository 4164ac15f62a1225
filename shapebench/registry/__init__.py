"""Finding and configuring plugins: entry-point discovery (:mod:`~shapebench.registry.discovery`),
names and overrides to instances (:mod:`~shapebench.registry.resolve`), a leaderboard row's
identity (:mod:`~shapebench.registry.variant`) and the code digest in every key
(:mod:`~shapebench.registry.code_digest`). Imports :mod:`shapebench.api` and nothing above it.
The plugin checks that were here (``check``, ``testing``) are :mod:`shapebench.conformance` now;
their old paths still import, with a warning (``shapebench/_moved.py``).
"""

from __future__ import annotations

from typing import Any

#: The modules of this room, and those that moved out of it (``check`` and ``testing``, answered
#: by shapebench/_moved.py): the import system asks for them here before it imports them.
_MODULES = frozenset({"check", "code_digest", "discovery", "resolve", "testing", "variant"})


def __getattr__(name: str) -> Any:
    # shapebench 0.1's module shapebench.registry is shapebench.registry.discovery now.
    import importlib
    import warnings

    if name.startswith("__") or name in _MODULES:
        raise AttributeError(f"module 'shapebench.registry' has no attribute {name!r}")
    discovery = importlib.import_module("shapebench.registry.discovery")
    if not hasattr(discovery, name):
        raise AttributeError(f"module 'shapebench.registry' has no attribute {name!r}")
    warnings.warn(
        f"shapebench.registry.{name} has moved to shapebench.registry.discovery; import it "
        "from there (the old path works until shapebench 0.3)",
        DeprecationWarning,
        stacklevel=2,
    )
    return getattr(discovery, name)
