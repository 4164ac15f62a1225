"""Plugin options: a dataclass per plugin, filled from config files and the command line.

A plugin declares its options as a dataclass named ``Options``; each field has a default and may
carry a help text in ``field(metadata={"help": ...})``. Values given as strings on the command line
(``-O sigma=0.02``) are parsed as YAML scalars and checked against the field's type.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any

import yaml

from shapebench.api.errors import ConfigError


@dataclasses.dataclass(frozen=True)
class NoOptions:
    """For plugins without options."""


@dataclasses.dataclass(frozen=True)
class OptionDoc:
    name: str
    type: str
    default: Any
    help: str


def describe(options_cls: type) -> list[OptionDoc]:
    hints = typing.get_type_hints(options_cls)
    docs = []
    for f in dataclasses.fields(options_cls):
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        tname = getattr(hints[f.name], "__name__", str(hints[f.name]))
        docs.append(OptionDoc(f.name, tname, default, f.metadata.get("help", "")))
    return docs


def parse_assignments(pairs: tuple[str, ...] | list[str], flag: str) -> dict[str, Any]:
    """``["a=1", "b=x"]`` -> ``{"a": 1, "b": "x"}``, values parsed as YAML scalars."""
    out: dict[str, Any] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"{flag} expects KEY=VALUE, got {pair!r}", f"e.g. {flag} sigma=0.02")
        out[key.strip()] = yaml.safe_load(value) if value != "" else ""
    return out


def _coerce(name: str, value: Any, annotation: Any, owner: str) -> Any:
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(annotation)
        if value is None and type(None) in args:
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(name, value, arg, owner)
            except ConfigError:
                continue
        raise ConfigError(f"option {name!r} of {owner}: {value!r} is not a {annotation}")
    if annotation is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if origin in (list, tuple) and isinstance(value, (list, tuple)):
        return origin(value)
    target = origin or annotation
    if isinstance(target, type) and not isinstance(value, target):
        raise ConfigError(
            f"option {name!r} of {owner} must be {target.__name__}, got {value!r}",
        )
    return value


def build(options_cls: type, values: dict[str, Any], owner: str) -> Any:
    """Instantiate ``options_cls`` from ``values``, naming unknown keys and bad types."""
    fields = {f.name: f for f in dataclasses.fields(options_cls)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ConfigError(
            f"unknown option(s) {', '.join(unknown)} for {owner}; "
            f"valid options: {', '.join(fields) or '(none)'}",
            f"run 'shapebench methods' or 'shapebench datasets' to see what {owner} accepts",
        )
    hints = typing.get_type_hints(options_cls)
    coerced = {k: _coerce(k, v, hints[k], owner) for k, v in values.items()}
    return options_cls(**coerced)


def as_dict(options: Any) -> dict[str, Any]:
    return dataclasses.asdict(options)


def option(default: Any, help_text: str) -> Any:
    """A dataclass field for a plugin option: its default and the help ``shapebench methods``
    shows (``latent_dim: int = option(256, "latent code size")``)."""
    return dataclasses.field(default=default, metadata={"help": help_text})


def steps_option() -> Any:
    """The ``steps`` option of a trained method: its budget in optimiser steps, which costs the
    same at any training-set size (an epoch is 9 steps on 66 shapes, 3,750 on 30,000). 0 keeps
    the ``epochs`` budget. ``--max-steps`` sets it, ``--max-epochs`` clears it."""
    return option(0, "optimiser steps to train, whatever the training-set size (0: epochs)")


def completion_option(default: Any, help_text: str) -> Any:
    """:func:`option` for an option that acts at completion time only: changing it never
    retrains (it is left out of the checkpoint key)."""
    return dataclasses.field(default=default, metadata={"help": help_text, "completion_only": True})
