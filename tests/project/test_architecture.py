"""The house's rules (docs/architecture.md), checked on the code as it stands: the layers and the
MLflow contract of pyproject.toml through import-linter, no cycle between rooms, the store as the
only place that names a tag or reaches the MLflow client, and no built-in plugin named by the
core."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "shapebench"
#: Modules that may sit directly in shapebench/ (the rest live in rooms).
MAX_TOP_LEVEL_MODULES = 12
#: The built-in plugin packages: import-linter's root packages other than the core itself (read
#: from pyproject.toml as text: tomllib is 3.11+), so a built-in added there, as every new one
#: must be for the contracts to cover it, is checked here too.
_PYPROJECT = (ROOT / "pyproject.toml").read_text()
_ROOT_PACKAGES = re.search(r"^root_packages = \[(.*?)\]", _PYPROJECT, re.M | re.S)
BUILTIN_PLUGINS = tuple(
    name for name in re.findall(r'"([\w.]+)"', _ROOT_PACKAGES.group(1)) if name != "shapebench"
)


def _sources(exclude: tuple[str, ...] = ()) -> list[Path]:
    return [
        p
        for p in sorted(PACKAGE.rglob("*.py"))
        if not any(p.relative_to(PACKAGE).as_posix().startswith(e) for e in exclude)
    ]


def _strings(path: Path) -> list[tuple[int, str]]:
    """Every string constant of a module, f-string pieces included, with its line."""
    tree = ast.parse(path.read_text())
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    return [
        (node.lineno, node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str)
        if id(node) not in docstrings
    ]


def test_the_layer_contracts_hold():
    lint = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    assert lint, "import-linter is part of the test extra: pip install -e '.[test]'"
    done = subprocess.run([lint], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
    assert "0 broken" in done.stdout


def test_no_import_cycle_between_rooms_function_local_imports_included():
    grimp = pytest.importorskip("grimp")
    graph = grimp.build_graph("shapebench", include_external_packages=False)

    def room(module: str) -> str:
        parts = module.split(".")
        return ".".join(parts[:2])

    edges: dict[str, set[str]] = {}
    for module in graph.modules:
        for imported in graph.find_modules_directly_imported_by(module):
            a, b = room(module), room(imported)
            if a != b and imported.startswith("shapebench"):
                edges.setdefault(a, set()).add(b)
    # A cycle between two rooms shows as a room that reaches itself.
    cycles = []
    for start in edges:
        seen, stack = set(), list(edges[start])
        while stack:
            node = stack.pop()
            if node == start:
                cycles.append(start)
                break
            if node not in seen:
                seen.add(node)
                stack.extend(edges.get(node, ()))
    assert not cycles, f"rooms on an import cycle: {sorted(cycles)}"


def test_the_top_level_holds_few_modules():
    modules = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(modules) <= MAX_TOP_LEVEL_MODULES, modules


def test_only_the_store_reaches_the_mlflow_client():
    offenders = []
    for path in _sources(exclude=("store/",)):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr == "client":
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not offenders, "use a Tracker method (shapebench/store/tracking.py): " + str(offenders)


def test_only_records_names_a_tag():
    from shapebench.store import records

    tags = {
        value
        for name, value in vars(records).items()
        if name.endswith(("_TAG", "_PREFIX")) and isinstance(value, str)
    }
    # Plain words ("method", "split") are also column and option names: the namespaced tags,
    # and the search filters that name a tag, are what must not be spelled outside records.
    namespaced = {t for t in tags if "." in t}
    offenders = []
    for path in _sources(exclude=("store/records.py",)):
        for line, text in _strings(path):
            if text in namespaced or re.search(r"tags\.`[^`{]+`", text):
                offenders.append(f"{path.relative_to(ROOT)}:{line}: {text!r}")
    assert not offenders, offenders
    # Every tag the records name is distinct: two constants for one tag would drift apart.
    names = [v for k, v in vars(records).items() if k.endswith("_TAG")]
    assert len(names) == len(set(names))


def test_the_core_names_no_builtin_plugin():
    offenders = []
    for path in _sources():
        for line, text in _strings(path):
            if any(plugin in text for plugin in BUILTIN_PLUGINS):
                offenders.append(f"{path.relative_to(ROOT)}:{line}")
    assert not offenders, "a built-in declares what it needs itself (check_options): " + str(
        offenders
    )


def test_every_builtin_entry_point_is_a_root_package_of_the_contracts():
    """A built-in registered in pyproject.toml but left out of import-linter's root packages
    would be checked by no contract and by no test above."""
    block = re.search(r"^\[project\.entry-points\.shapebench\]\n(.*?)\n\n", _PYPROJECT, re.M | re.S)
    packages = {m.split(".")[0] for m in re.findall(r'= "([\w.]+)"', block.group(1))}
    packages.discard("shapebench")
    assert packages, "no built-in entry point found in pyproject.toml"
    assert packages <= set(BUILTIN_PLUGINS), sorted(packages - set(BUILTIN_PLUGINS))


def test_the_import_paths_of_0_1_still_work_and_warn():
    import importlib
    import warnings

    from shapebench._moved import MOVED

    for old, new in MOVED.items():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            sys.modules.pop(old, None)
            module = importlib.import_module(old)
        assert module is importlib.import_module(new), old
        assert module.__spec__.name == new  # pickling and reloads see the real name
        assert any(
            issubclass(w.category, DeprecationWarning) and new in str(w.message) for w in caught
        ), old
    # The documented idioms of 0.1, as a plugin wrote them.
    with pytest.warns(DeprecationWarning, match="shapebench.conformance.testing"):
        sys.modules.pop("shapebench.testing", None)
        from shapebench.testing import check_method
    # The plugin checks' paths in registry/ before they became the conformance room.
    with pytest.warns(DeprecationWarning, match="shapebench.conformance.testing"):
        sys.modules.pop("shapebench.registry.testing", None)
        from shapebench.registry.testing import check_method as old_check_method
    assert old_check_method is check_method
    import shapebench.registry
    from shapebench import conformance

    with pytest.warns(DeprecationWarning, match="shapebench.conformance"):
        sys.modules.pop("shapebench.registry.check", None)
        vars(shapebench.registry).pop("check", None)  # bound by the loop's import above
        from shapebench.registry import check
    # The package hands on the old module's public names, wherever they live now.
    assert check is conformance and check.CheckEnv is conformance.framework.CheckEnv
    assert check.completion_problem is conformance.methods.completion_problem
    with pytest.warns(DeprecationWarning, match="shapebench.train.lightning_method"):
        from shapebench.implicit.method_base import LightningMethod
    from shapebench.train.lightning_method import LightningMethod as moved

    assert LightningMethod is moved
    with pytest.warns(DeprecationWarning, match="shapebench.registry.discovery"):
        from shapebench.registry import get_registry  # noqa: F401
    from shapebench.cli import cli, main  # noqa: F401 (0.1's module is a package with both)


@pytest.mark.slow  # a fresh interpreter importing torch, Lightning and MLflow: ~10 s
def test_every_room_imports_its_modules_in_a_fresh_interpreter():
    """``from shapebench.<room> import <module>`` as the first import of a process, for every
    module of every room (a room's ``__getattr__`` must not shadow its own modules)."""
    lines = []
    # registry/ first: its __getattr__ hands on the names of 0.1's shapebench.registry.
    rooms = sorted(p.parent for p in PACKAGE.glob("*/__init__.py"))
    for room in sorted(rooms, key=lambda r: r.name != "registry"):
        modules = sorted(p.stem for p in room.glob("*.py") if p.stem != "__init__")
        if modules:
            lines.append(f"from shapebench.{room.name} import {', '.join(modules)}")
    code = "import warnings; warnings.simplefilter('error', DeprecationWarning)\n" + "\n".join(
        lines
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
