"""Plugin options: a dataclass per plugin, filled from config files and the command line.

A plugin declares its options as a dataclass named ``Options``; each field has a default and may
carry a help text in ``field(metadata={"help": ...})``. Values given as strings on the command line
(``-O sigma=0.02``) are parsed as YAML scalars, then checked strictly against the field's type
(with pydantic): a bool is not an int or a float, an int is a float, list and tuple elements,
``X | None``, ``Literal`` and enum fields are checked. A wrong type or an unknown name is one
error naming the option, the type it needs and, for a typo, the closest valid name.
"""

from __future__ import annotations

import collections.abc
import dataclasses
import difflib
import enum
import re
import types
import typing
from collections.abc import Iterable
from typing import Annotated, Any, Literal

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


def build(options_cls: type, values: dict[str, Any], owner: str) -> Any:
    """Instantiate ``options_cls`` from ``values``: unknown keys and values of the wrong type are
    refused in one line naming the option (and the closest valid name), never passed on to fail
    deep inside a training."""
    fields = {f.name: f for f in dataclasses.fields(options_cls)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ConfigError(
            f"unknown option{'s' if len(unknown) > 1 else ''} "
            f"{', '.join(suggest(k, fields) for k in unknown)} for {owner}; "
            f"valid options: {', '.join(fields) or '(none)'}",
            f"run 'shapebench methods' or 'shapebench datasets' to see what {owner} accepts",
        )
    hints = typing.get_type_hints(options_cls, include_extras=True)
    checked = {k: check_value(v, hints[k], f"option {k!r} of {owner}") for k, v in values.items()}
    return options_cls(**checked)


def suggest(name: str, valid: Iterable[str]) -> str:
    """``'grid_sise' (did you mean 'grid_size'?)``: an unknown name, with the closest valid one
    when there is a close one (a typo is the usual cause)."""
    close = difflib.get_close_matches(name, list(valid), n=1)
    return f"{name!r} (did you mean {close[0]!r}?)" if close else repr(name)


# -- typed checks ------------------------------------------------------------------------------
#
# A field's annotation becomes a pydantic TypeAdapter with Python's leniencies removed: a bool is
# an int to Python (``True + 1 == 2``) and to pydantic's lax mode, so ``-O grid_size=true``
# reached torch as 1 and failed there. Scalars are strict (an int is still accepted for a float);
# list and tuple elements, Literal choices and enum values are checked; unions are tried left to
# right, as the code before pydantic tried them, so a valid value keeps the value it had.


#: ``1e-3``, ``-2E5``, ``1.5e-3``: what a float option given in exponent notation looks like.
_EXPONENT_FLOAT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def check_value(value: Any, annotation: Any, label: str, convert: bool = True) -> Any:
    """``value`` checked against ``annotation``; a :class:`ConfigError` ``"<label> must be <type>,
    got <value>"`` (and which element, in a list) otherwise.

    ``convert``: the value as options hold it (an int given for a float becomes a float, a list
    given for a tuple a tuple, an enum's value its member); elements of a list or tuple are
    checked but passed on as given, as before the check existed, so that a cell key hashed from
    them does not move. ``convert=False`` returns ``value`` itself once it is known to be right.
    """
    from pydantic import ValidationError

    leaves = _leaves(annotation)
    if (
        isinstance(value, str)
        and float in leaves
        and str not in leaves
        and _EXPONENT_FLOAT.fullmatch(value.strip())
    ):
        # YAML 1.1 reads ``1e-3`` (no dot) as text: for a float option it is the number meant.
        value = float(value)
    adapter = _adapter(annotation)
    if adapter is None:  # a type pydantic cannot describe: the isinstance check it always had
        target = typing.get_origin(annotation) or annotation
        if isinstance(target, type) and not isinstance(value, target):
            raise ConfigError(f"{label} must be {type_name(annotation)}, got {value!r}")
        return value
    try:
        out = adapter.validate_python(value)
    except ValidationError:
        where, leaf, leaf_type = _first_bad(value, annotation)
        detail = f" ({where})" if where else ""
        quote = (
            isinstance(leaf, (int, float))
            and not isinstance(leaf, bool)
            and str in _leaves(leaf_type)
        )
        raise ConfigError(
            f"{label} must be {type_name(annotation)}, got {value!r}{detail}",
            "YAML reads unquoted digits as a number (and a leading 0 as octal): quote the "
            "text, e.g. '[\"03001627\"]'"
            if quote
            else None,
        ) from None
    if not convert:
        return value
    if isinstance(value, (list, tuple)) and isinstance(out, (list, tuple, set, frozenset)):
        return type(out)(value)
    if isinstance(value, dict) and type(out) is dict:
        return value
    return out


def type_name(annotation: Any) -> str:
    """How an error names a type: ``int``, ``float | None``, ``tuple[int, ...]``, ``'a' | 'b'``."""
    if annotation is None or annotation is type(None):
        return "None"
    if annotation is Any:
        return "Any"
    if annotation is Ellipsis:
        return "..."
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is Annotated:
        return type_name(args[0])
    if origin in (typing.Union, types.UnionType):
        return " | ".join(type_name(a) for a in args)
    if origin is Literal:
        return " | ".join(repr(a) for a in args)
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return " | ".join(repr(m.value) for m in annotation)
    if origin is not None:
        base = getattr(origin, "__name__", str(origin))
        return f"{base}[{', '.join(type_name(a) for a in args)}]" if args else base
    return getattr(annotation, "__name__", str(annotation))


_SCALARS = (int, float, str, bool, bytes)
_BARE = (list, tuple, dict, set, frozenset)
_SEQUENCES = (list, tuple, set, frozenset, collections.abc.Sequence, collections.abc.Set)
_MAPPINGS = (dict, collections.abc.Mapping)
_ADAPTERS: dict[Any, Any] = {}


def _adapter(annotation: Any) -> Any:
    """The strict TypeAdapter of ``annotation`` (built once per annotation: ``build`` runs for
    every run, sweep entry and child process), or None for a type pydantic cannot describe."""
    # ``int | float == float | int`` to Python, but the order decides which one a value takes:
    # the repr keeps them apart (and the annotation itself two classes of one name).
    key = (annotation, repr(annotation))
    try:
        return _ADAPTERS[key]
    except KeyError:
        pass
    except TypeError:  # unhashable metadata in an Annotated: build it each time
        return _new_adapter(annotation)
    _ADAPTERS[key] = adapter = _new_adapter(annotation)
    return adapter


def _new_adapter(annotation: Any) -> Any:
    from pydantic import ConfigDict, PydanticUserError, TypeAdapter

    try:
        strict = _strict(annotation)
    except Exception:  # noqa: BLE001 - a plugin's exotic annotation keeps the check it had
        return None
    try:
        return TypeAdapter(strict, config=ConfigDict(arbitrary_types_allowed=True))
    except PydanticUserError:
        pass  # a dataclass, model or TypedDict carries its own config
    except Exception:  # noqa: BLE001
        return None
    try:
        return TypeAdapter(strict)
    except Exception:  # noqa: BLE001
        return None


def _strict(annotation: Any) -> Any:
    """``annotation`` as pydantic should check it here: strict scalars, lists and tuples only
    from lists and tuples, Literal choices and enum values without bool-for-int, unions tried in
    order."""
    from pydantic import BeforeValidator, Field, Strict

    if annotation in _SCALARS or annotation in _BARE:
        # A bare ``tuple`` takes a tuple only, as it always did: ``-O sizes=[1,2]`` cannot build
        # it (shapebench check says so); ``tuple[int, ...]`` takes a list.
        return Annotated[annotation, Strict()]
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return Annotated[annotation, BeforeValidator(_exact_choice(tuple(annotation), enum=True))]
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is Annotated:
        return Annotated[(_strict(args[0]), *annotation.__metadata__)]
    if origin in (typing.Union, types.UnionType):
        members = [_strict(a) for a in args if a is not type(None)]
        core = (
            members[0]
            if len(members) == 1
            else Annotated[typing.Union[tuple(members)], Field(union_mode="left_to_right")]  # noqa: UP007
        )
        return typing.Optional[core] if type(None) in args else core  # noqa: UP045
    if origin is Literal:
        return Annotated[annotation, BeforeValidator(_exact_choice(args))]
    if origin in _SEQUENCES or origin in _MAPPINGS:
        rebuilt = (
            origin[tuple(a if a is Ellipsis else _strict(a) for a in args)] if args else origin
        )
        if origin in (list, tuple):
            return Annotated[rebuilt, BeforeValidator(_list_or_tuple)]
        return rebuilt
    return annotation


def _list_or_tuple(value: Any) -> Any:
    """A list or tuple option is given as a list (YAML, JSON) or a tuple, never a string or set."""
    if not isinstance(value, (list, tuple)):
        raise ValueError("not a list")  # pydantic reports it as a validation error
    return value


def _exact_choice(choices: tuple[Any, ...], enum: bool = False) -> Any:
    """A check that ``value`` is one of ``choices`` (or, for an enum, one of its values) by type as
    well as by equality: ``True == 1`` and ``1.0 == 1``, but neither picks the choice ``1``."""
    targets = [c.value for c in choices] if enum else list(choices)

    def check(value: Any) -> Any:
        if enum and any(value is c for c in choices):  # a member itself
            return value
        for target in targets:
            if type(value) is type(target) and value == target:
                return value
        raise ValueError("not one of the choices")

    return check


def _first_bad(value: Any, annotation: Any) -> tuple[str, Any, Any]:
    """Where in ``value`` the check failed, for the error: ``("item 1: True is not int", True,
    int)``; ``("", value, annotation)`` when the value as a whole is wrong."""
    ann = _unoptional(annotation, value)
    origin, args = typing.get_origin(ann), typing.get_args(ann)
    pairs: list[tuple[str, Any, Any]] = []
    if origin in _SEQUENCES and args and isinstance(value, (list, tuple)):
        if origin is tuple and not (len(args) == 2 and args[1] is Ellipsis):
            if len(value) != len(args):
                return f"{len(value)} items, not {len(args)}", value, ann
            pairs = [(f"item {i}", v, a) for i, (v, a) in enumerate(zip(value, args, strict=True))]
        else:
            pairs = [(f"item {i}", v, args[0]) for i, v in enumerate(value)]
    elif origin in _MAPPINGS and len(args) == 2 and isinstance(value, dict):
        for k, v in value.items():
            if not _valid(k, args[0]):
                return f"key {k!r} is not {type_name(args[0])}", k, args[0]
            pairs.append((f"key {k!r}", v, args[1]))
    for where, v, a in pairs:
        if not _valid(v, a):
            inner, leaf, leaf_type = _first_bad(v, a)
            return f"{where}: {inner or f'{v!r} is not {type_name(a)}'}", leaf, leaf_type
    return "", value, annotation


def _unoptional(annotation: Any, value: Any) -> Any:
    """``annotation`` without ``Annotated`` and, for a value that is not None, without ``None``
    (a one-member union is that member)."""
    while typing.get_origin(annotation) is Annotated:
        annotation = typing.get_args(annotation)[0]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType) and value is not None:
        members = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(members) == 1:
            return _unoptional(members[0], value)
    return annotation


def _valid(value: Any, annotation: Any) -> bool:
    from pydantic import ValidationError

    adapter = _adapter(annotation)
    if adapter is None:
        return True
    try:
        adapter.validate_python(value)
    except ValidationError:
        return False
    return True


def _leaves(annotation: Any) -> set[Any]:
    """The plain types a (possibly Optional or Annotated) annotation accepts."""
    origin = typing.get_origin(annotation)
    if origin is Annotated:
        return _leaves(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType):
        return set().union(*(_leaves(a) for a in typing.get_args(annotation)))
    return {annotation}


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
