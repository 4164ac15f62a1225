"""The plugin API reference (docs/reference/api/, rendered from the docstrings by mkdocstrings)
says everything a plugin author needs: the checks no generator makes.

The site build itself (broken links, stale ``:::`` references) is tests/project/test_docs_site.py.
"""

from __future__ import annotations

import importlib
import inspect
import re
import textwrap
from pathlib import Path

import pytest

import shapebench
from shapebench.api import hookspecs
from shapebench.api.metric import COMBINES, DIRECTIONS, POWERS, REDUCTIONS, check_metric

ROOT = Path(__file__).resolve().parents[2]
API_PAGES = ROOT / "docs" / "reference" / "api"
EXTENSION = ROOT / "docs" / "reference" / "_griffe_shapebench.py"


def _directives() -> set[str]:
    """The objects the API pages render (`::: shapebench.api.metric`)."""
    return {
        match
        for page in API_PAGES.glob("*.md")
        for match in re.findall(r"^::: ([\w.]+)\s*$", page.read_text(), re.MULTILINE)
    }


def test_every_export_is_on_an_api_reference_page():
    documented = _directives()
    missing = []
    for name in shapebench.__all__:
        if name == "__version__":
            continue
        module = shapebench._LAZY.get(name, "shapebench.api.hookspecs")  # hookimpl
        if module not in documented and f"{module}.{name}" not in documented:
            missing.append(f"{name} ({module})")
    assert missing == [], f"add a `::: module` directive under docs/reference/api/: {missing}"


def _args_section(doc: str) -> list[str]:
    _, sep, tail = doc.partition("\nArgs:\n")
    assert sep, "no Args: section"
    return re.findall(r"^(\w+): ", textwrap.dedent(tail), re.MULTILINE)


def test_every_hook_spec_documents_every_argument():
    specs = [f for f in vars(hookspecs).values() if hasattr(f, "shapebench_spec")]
    assert {f.__name__ for f in specs} >= {
        "shapebench_register_methods",
        "shapebench_register_datasets",
        "shapebench_register_metrics",
    }
    for func in specs:
        params = list(inspect.signature(func).parameters)
        assert _args_section(inspect.getdoc(func) or "") == params, func.__name__


def test_option_metadata_table_lists_exactly_the_keys_the_code_reads():
    read = {
        key
        for path in (ROOT / "shapebench").rglob("*.py")
        for key in re.findall(r'\bmetadata\.get\("(\w+)"', path.read_text())
    }
    page = (API_PAGES / "options.md").read_text()
    listed = set(re.findall(r"^\| `(\w+)` \|", page, re.MULTILINE))
    assert listed == read, f"docs/reference/api/options.md: listed {listed}, read {read}"


def _builtin_metrics() -> list[tuple[str, type]]:
    from shapebench.metrics import plugin

    targets: list[tuple[str, object]] = []
    plugin.shapebench_register_metrics(lambda name, target: targets.append((name, target)))
    out = []
    for name, target in targets:
        if isinstance(target, str):
            module, _, attr = target.partition(":")
            target = getattr(importlib.import_module(module), attr)
        out.append((name, target))
    return out


@pytest.mark.parametrize(("name", "cls"), _builtin_metrics(), ids=lambda v: str(v))
def test_builtin_metric_cards_take_allowed_values(name, cls):
    card = check_metric(cls)  # validates every field against the allowed values
    assert card.metric == name
    assert card.power in POWERS and card.reduction in REDUCTIONS
    assert card.direction in DIRECTIONS and card.combine in (None, *COMBINES)
    assert card.describe().startswith(f"{name}: ")


def _load(module: str):
    griffe = pytest.importorskip("griffe", reason="griffe comes with the `test` extra")
    extensions = griffe.load_extensions(f"{EXTENSION}:ShapebenchDocstrings")
    return griffe.load(module, search_paths=[str(ROOT)], extensions=extensions)


def test_every_field_of_the_data_a_plugin_handles_is_documented():
    """What the reference shows for each field: its docstring or ``#:`` comment."""
    undocumented = []
    for module, classes in (
        ("shapebench.api.metric", ["MetricCard"]),
        ("shapebench.api.types", ["Context", "Completion", "ObjectData", "ObjectRef"]),
    ):
        tree = _load(module)
        for cls in classes:
            fields = importlib.import_module(module).__dict__[cls].__dataclass_fields__
            for field in fields:
                if tree[f"{cls}.{field}"].docstring is None:
                    undocumented.append(f"{module}.{cls}.{field}")
    assert undocumented == [], f"add a `#:` comment above: {undocumented}"


def test_the_card_value_tables_are_documented():
    tree = _load("shapebench.api.metric")
    for name in ("POWERS", "REDUCTIONS", "DIRECTIONS", "COMBINES"):
        assert tree[name].docstring is not None, name
