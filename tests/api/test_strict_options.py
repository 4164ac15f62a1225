"""Plugin options are checked strictly (issue 59): a bool is refused where an int or a float
belongs, list elements are checked, an unknown name is answered with the closest valid one, each
in one line naming the option; and every valid input builds exactly the options it built before
the check was strict (the cell keys hash them)."""

from __future__ import annotations

import dataclasses
import enum
import json
import types
import typing
from pathlib import Path
from typing import Any, Literal

import pytest

from shapebench.api.errors import ConfigError
from shapebench.api.options import as_dict, build, parse_assignments
from shapebench.config import available_profiles, load_profile, plugin_overrides
from shapebench.hashing import stable_hash
from shapebench.registry.discovery import get_registry

ROOT = Path(__file__).resolve().parents[2]


def _options(kind: str, name: str) -> type:
    return get_registry().load(kind, name).Options


def _refused(options_cls: type, assignments: list[str], owner: str = "method 'pcn'") -> ConfigError:
    with pytest.raises(ConfigError) as err:
        build(options_cls, parse_assignments(assignments, "-O"), owner)
    assert "\n" not in err.value.message  # one line
    return err.value


# -- wrong values, named -----------------------------------------------------------------------


def test_a_bool_for_an_int_option_is_refused_naming_the_option_and_its_type():
    err = _refused(_options("method", "pcn"), ["grid_size=true"])
    assert err.message == "option 'grid_size' of method 'pcn' must be int, got True"
    # floats were checked before, and still are; an int is still a float
    err = _refused(_options("method", "gauss"), ["sigma=true"], "method 'gauss'")
    assert err.message == "option 'sigma' of method 'gauss' must be float, got True"


def test_a_list_option_with_a_wrong_element_names_the_element():
    err = _refused(_options("method", "pcn"), ["alpha_steps=[10000, true, 50000]"])
    assert err.message == (
        "option 'alpha_steps' of method 'pcn' must be tuple[int, ...], "
        "got [10000, True, 50000] (item 1: True is not int)"
    )
    err = _refused(_options("method", "pcn"), ["context_sizes=50"])
    assert "'context_sizes' of method 'pcn' must be tuple[int, ...], got 50" in err.message


def test_a_synset_id_yaml_reads_as_an_octal_number_is_refused_with_how_to_quote_it():
    # YAML 1.1 reads 03001627 as the octal 787351: before, a list[str] took it silently.
    err = _refused(
        _options("dataset", "shapenet"), ["categories=[02691156, 03001627]"], "dataset 'shapenet'"
    )
    assert "'categories' of dataset 'shapenet' must be list[str]" in err.message
    assert "(item 1: 787351 is not str)" in err.message
    assert "quote" in err.hint
    ok = build(
        _options("dataset", "shapenet"), parse_assignments(['categories=["03001627"]'], "-D"), ""
    )
    assert ok.categories == ["03001627"]


def test_an_unknown_option_names_the_closest_valid_one():
    err = _refused(_options("method", "pcn"), ["grid_sise=3"])
    assert err.message.startswith(
        "unknown option 'grid_sise' (did you mean 'grid_size'?) for method 'pcn'; valid options: "
    )
    err = _refused(_options("method", "pcn"), ["grid_sise=3", "zzz=1"])
    assert "unknown options 'grid_sise' (did you mean 'grid_size'?), 'zzz' for" in err.message


class Colour(enum.Enum):
    RED = "red"
    GREEN = "green"


class Level(enum.IntEnum):
    LOW = 1
    HIGH = 2


@dataclasses.dataclass(frozen=True)
class ThirdPartyOptions:
    """A plugin's options with the types built-ins do not use (yet)."""

    mode: Literal["fast", "exact"] = "fast"
    order: Literal[1, 2] = 1
    colour: Colour = Colour.RED
    level: Level = Level.LOW
    radius: float | None = None
    scales: tuple[float, ...] = (1.0,)
    pairs: list[tuple[str, int]] = dataclasses.field(default_factory=list)
    weights: dict[str, float] = dataclasses.field(default_factory=dict)
    anything: Any = None


@pytest.mark.parametrize(
    "assignment, message",
    [
        ("mode=slow", "option 'mode' of p must be 'fast' | 'exact', got 'slow'"),
        ("order=true", "option 'order' of p must be 1 | 2, got True"),
        ("order=2.0", "option 'order' of p must be 1 | 2, got 2.0"),
        ("colour=blue", "option 'colour' of p must be 'red' | 'green', got 'blue'"),
        ("level=true", "option 'level' of p must be 1 | 2, got True"),
        ("radius=true", "option 'radius' of p must be float | None, got True"),
        ("radius=wide", "option 'radius' of p must be float | None, got 'wide'"),
        ("scales=[1, x]", "must be tuple[float, ...], got [1, 'x'] (item 1: 'x' is not float)"),
        ("pairs=[[a, 1], [b, true]]", "(item 1: item 1: True is not int)"),
        ("pairs=[[a, 1, 2]]", "(item 0: 3 items, not 2)"),
        ("weights={a: true}", "must be dict[str, float], got {'a': True} (key 'a': True is"),
    ],
)
def test_literal_enum_optional_and_nested_fields_are_checked(assignment, message):
    with pytest.raises(ConfigError) as err:
        build(ThirdPartyOptions, parse_assignments([assignment], "-O"), "p")
    assert message in err.value.message


def test_literal_enum_optional_and_nested_fields_take_their_valid_values():
    given = [
        "mode=exact",
        "order=2",
        "colour=green",
        "level=2",
        "radius=null",
        "scales=[1, 2.5]",
        "pairs=[[a, 1]]",
        "weights={a: 1}",
        "anything=[1, x]",
    ]
    built = build(ThirdPartyOptions, parse_assignments(given, "-O"), "p")
    assert built == ThirdPartyOptions(
        "exact", 2, Colour.GREEN, Level.HIGH, None, (1, 2.5), [["a", 1]], {"a": 1}, [1, "x"]
    )
    # elements are checked, never converted: a key hashed from [1, 2.5] before stays the same
    assert type(built.scales[0]) is int and type(built.pairs[0]) is list
    assert build(ThirdPartyOptions, {"radius": 1}, "p").radius == 1.0  # a scalar float: 1.0


def test_a_union_takes_a_value_as_its_first_member_can_as_before():
    @dataclasses.dataclass(frozen=True)
    class IntFirst:
        x: int | float = 0

    @dataclasses.dataclass(frozen=True)
    class FloatFirst:  # int | float == float | int to Python: each keeps its own order
        x: float | int = 0.0

    assert type(build(IntFirst, {"x": 1}, "p").x) is int
    assert type(build(FloatFirst, {"x": 1}, "p").x) is float
    assert type(build(IntFirst, {"x": 1}, "p").x) is int


# -- valid inputs: the same values as before ---------------------------------------------------


def _old_coerce(name: str, value: Any, annotation: Any, owner: str) -> Any:
    """``shapebench.api.options._coerce`` as it was before the strict check (issue 59)."""
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(annotation)
        if value is None and type(None) in args:
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _old_coerce(name, value, arg, owner)
            except ConfigError:
                continue
        raise ConfigError(f"option {name!r} of {owner}: {value!r} is not a {annotation}")
    if annotation is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if origin in (list, tuple) and isinstance(value, (list, tuple)):
        return origin(value)
    target = origin or annotation
    if isinstance(target, type) and not isinstance(value, target):
        raise ConfigError(f"option {name!r} of {owner} must be {target.__name__}, got {value!r}")
    return value


def _old_build(options_cls: type, values: dict[str, Any]) -> Any:
    hints = typing.get_type_hints(options_cls)
    return options_cls(**{k: _old_coerce(k, v, hints[k], "x") for k, v in values.items()})


def _typical(annotation: Any, default: Any) -> list[str]:
    """What a user types for an option of this type (besides its default written as JSON)."""
    base = typing.get_args(annotation)[0] if typing.get_origin(annotation) else annotation
    if annotation is int:
        return ["3", "0", "-1", "100000"]
    if annotation is float:
        return ["0.5", "2", "0", "1.0e-3", "-0.25"]
    if annotation is bool:
        return ["true", "false"]
    if annotation is str:
        return ["paper", "official", "x y"]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return ["null", *_typical(base, default)]
    if typing.get_origin(annotation) is tuple:
        return ["[50, 100]", "[]", "[3000]"]
    if typing.get_origin(annotation) is list:
        return ["[chair, Bus]", "[]", '["03001627"]']
    raise AssertionError(f"no typical value for {annotation}: add one")


def _same(a: Any, b: Any) -> bool:
    """Equal values of identical types, down to each element (1 == 1.0 == True, but not here)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return a == b


def _valid_inputs(kind: str, name: str, options_cls: type) -> list[dict[str, Any]]:
    hints = typing.get_type_hints(options_cls)
    inputs: list[dict[str, Any]] = [{}]
    defaults = as_dict(options_cls())
    inputs.append(defaults)  # every default given explicitly (a logged config, built again)
    inputs.append(json.loads(json.dumps(defaults)))  # ... through JSON, as a child process
    for f in dataclasses.fields(options_cls):
        given = [json.dumps(defaults[f.name]), *_typical(hints[f.name], defaults[f.name])]
        inputs += [parse_assignments([f"{f.name}={v}"], "-O") for v in given]
    for profile in available_profiles():  # what the shipped configs and profiles set
        inputs.append(plugin_overrides(kind, name, load_profile(profile)))
    return inputs


def _builtins() -> list[tuple[str, str]]:
    registry = get_registry()
    return [(kind, name) for kind in ("method", "dataset") for name in registry.names(kind)]


@pytest.mark.parametrize("kind, name", _builtins())
def test_every_valid_input_of_a_builtin_builds_the_options_it_built_before(kind, name):
    options_cls = _options(kind, name)
    for values in _valid_inputs(kind, name, options_cls):
        try:
            old = _old_build(options_cls, values)
        except ConfigError:  # refused by the plugin itself (its __post_init__): still refused
            with pytest.raises(ConfigError):
                build(options_cls, values, f"{kind} {name!r}")
            continue
        new = build(options_cls, values, f"{kind} {name!r}")
        assert _same(as_dict(new), as_dict(old)), (values, as_dict(new), as_dict(old))
        assert stable_hash(as_dict(new)) == stable_hash(as_dict(old))


def test_the_shipped_sweeps_options_build_what_they_built_before():
    from shapebench.sweeps.spec import load_sweep

    checked = 0
    for path in sorted((ROOT / "configs" / "sweeps").glob("*.yaml")):
        spec = load_sweep(path)
        entries = [("dataset", d) for d in spec.datasets]
        if spec.methods != "all":
            entries += [("method", m) for m in spec.methods]
        for kind, entry in entries:
            options_cls = _options(kind, entry.name)
            new = build(options_cls, entry.options, entry.name)
            assert _same(as_dict(new), as_dict(_old_build(options_cls, entry.options)))
            checked += bool(entry.options)
    assert checked  # the shipped sweeps do set options


def test_strings_from_the_command_line_become_the_field_type():
    pcn = build(
        _options("method", "pcn"),
        parse_assignments(["grid_size=3", "grid_scale=1", "context_sizes=[50, 100]"], "-O"),
        "method 'pcn'",
    )
    assert (pcn.grid_size, pcn.grid_scale, pcn.context_sizes) == (3, 1.0, (50, 100))
    assert type(pcn.grid_scale) is float and type(pcn.context_sizes) is tuple


def test_a_float_in_exponent_notation_is_a_number_for_a_float_option_only():
    # YAML 1.1 reads 1e-3 (no dot) as text; 1.0e-3 was always a float.
    gauss = build(_options("method", "gauss"), parse_assignments(["sigma=1e-3"], "-O"), "g")
    assert gauss.sigma == 0.001 and type(gauss.sigma) is float
    err = _refused(_options("method", "pcn"), ["grid_size=1e3"])
    assert err.message == "option 'grid_size' of method 'pcn' must be int, got '1e3'"


# -- the command line ----------------------------------------------------------------------------


@pytest.mark.slow  # runs the CLI in a subprocess
def test_train_with_a_bool_for_an_int_option_is_one_line_and_no_traceback(shapebench):
    res = shapebench("train", "-m", "pcn", "-d", "synthetic", "-O", "grid_size=true")
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert res.stderr.strip().splitlines() == [
        "Error: option 'grid_size' of method 'pcn' must be int, got True"
    ]
    assert not (shapebench.workspace / "mlflow.db").exists()  # refused before any work
