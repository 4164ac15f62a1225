"""The rules of a method's or dataset's ``Options``: a dataclass whose fields all have defaults,
and options that round-trip through ``-O KEY=VALUE`` strings and the JSON config runs log."""

from __future__ import annotations

import dataclasses
import json
from typing import Any

from shapebench.conformance.framework import CheckFailed


def options_roundtrip(options_cls: type, values: dict[str, Any], owner: str) -> Any:
    """Build options from ``values``, write them as ``-O KEY=VALUE`` strings (JSON values, as a
    training child process receives them), parse those back, and demand the same options."""
    from shapebench.api import options as opts

    built = opts.build(options_cls, values, owner)
    again = opts.build(options_cls, opts.parse_assignments(_as_assignments(built), "-O"), owner)
    if again != built:
        diff = [
            f.name
            for f in dataclasses.fields(built)
            if getattr(built, f.name) != getattr(again, f.name)
        ]
        raise CheckFailed(
            f"option(s) {', '.join(diff)} change when written as KEY=VALUE and parsed back: "
            + ", ".join(f"{k}={getattr(built, k)!r} -> {getattr(again, k)!r}" for k in diff)
        )
    return built


def _as_assignments(options: Any) -> list[str]:
    from shapebench.api import options as opts

    out = []
    for key, value in opts.as_dict(options).items():
        try:
            out.append(f"{key}={json.dumps(value)}")
        except TypeError as exc:
            raise CheckFailed(
                f"option {key}={value!r} is not a JSON value (a number, string, bool, None or a "
                "list of them): runs log options as JSON and pass them to training processes"
            ) from exc
    return out


def check_options_class(cls: type, owner: str) -> None:
    """Part of the ``interface`` check: ``cls.Options`` is a dataclass whose fields all have
    defaults and that ``shapebench methods`` / ``datasets`` can describe."""
    from shapebench.api import options as opts

    options_cls = getattr(cls, "Options", None)
    if not (isinstance(options_cls, type) and dataclasses.is_dataclass(options_cls)):
        raise CheckFailed(f"{owner}: Options must be a dataclass, got {options_cls!r}")
    none = dataclasses.MISSING
    missing = [
        f.name
        for f in dataclasses.fields(options_cls)
        if f.default is none and f.default_factory is none
    ]
    if missing:
        raise CheckFailed(f"{owner}: option(s) {', '.join(missing)} have no default")
    opts.describe(options_cls)  # what `shapebench methods` prints: type names, help texts


def options_message(options_cls: type, tiny: dict[str, Any]) -> str:
    """What a passed ``options`` check says: how many options, and the values it used."""
    n = len(dataclasses.fields(options_cls))
    if not n:
        return "no options"
    shown = ", ".join(f"{k}={v}" for k, v in tiny.items()) or "the defaults"
    return f"{n} option(s) parse and round-trip through the config; checked with {shown}"
