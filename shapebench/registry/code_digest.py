"""A digest of the source code a method's results depend on, for cell and checkpoint keys.

Keys cover a method's options and its distribution's version, but an edited plugin (an editable
install, a local change) keeps its version: without the code in the key its stale cells and
checkpoints would be reused. Like benchopt, which keys its cache on the solver's code, shapebench
hashes the source files of

* the package of every class in the method's MRO (a plugin's package, ``shapebench.implicit``
  for the built-in implicit methods), except the :class:`~shapebench.api.method.Method` interface;
  a class defined in shapebench's core (the top-level package or one of its rooms, such as
  :class:`~shapebench.train.lightning_method.LightningMethod`) contributes its own module file
  only, so unrelated core edits do not invalidate every result;
* the modules the class names in ``code_modules`` (shared training code it imports).

A second digest, :func:`completion_digest`, covers the modules a class names in
``completion_modules``: code that shapes its completions but not its training (mesh extraction,
surface sampling). It enters cell keys only, so an edit there computes the cells again without
retraining (the checkpoint key holds :func:`code_digest` alone).
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.util
import inspect
from pathlib import Path

#: The interface module: editing docs there must not retrain every method.
_EXCLUDED = {"shapebench.api.method", "abc", "builtins"}
#: shapebench's core: a module there stands for its own file, not for its whole package.
_CORE = {"shapebench"} | {
    f"shapebench.{room}"
    for room in (
        "api",
        "registry",
        "store",
        "train",
        "evaluation",
        "boards",
        "sweeps",
        "cli",
        "geometry",
        "exchange",
    )
}


def _module_sources(module_name: str) -> list[tuple[str, Path]]:
    """The files that stand for ``module_name`` (see the module docstring), each with a name that
    does not depend on where it is installed (``package/relative/path.py``)."""
    module = importlib.import_module(module_name)
    file = getattr(module, "__file__", None)
    if not file:
        return []
    path = Path(file)
    package = module_name.rpartition(".")[0] if path.name != "__init__.py" else module_name
    if not package or package in _CORE:  # a top-level module, or a core module
        return [(f"{module_name}.py", path)]
    root = Path(importlib.import_module(package).__file__).parent
    files = sorted(p for p in root.rglob("*.py") if "__pycache__" not in p.parts)
    return [(f"{package}/{f.relative_to(root).as_posix()}", f) for f in files]


@functools.lru_cache(maxsize=64)
def _digest_files(named: tuple[tuple[str, Path], ...]) -> str:
    h = hashlib.sha256()
    for name, path in named:  # sorted by name: the same code gives the same digest anywhere
        h.update(name.encode() + b"\0")
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def digest_sources(cls: type) -> dict[str, Path]:
    """The source files :func:`code_digest` covers for ``cls``, by their installation-independent
    names (``package/relative/path.py``, or ``module.py`` for a core module)."""
    modules = {c.__module__ for c in inspect.getmro(cls)} - _EXCLUDED
    modules |= set(getattr(cls, "code_modules", ()) or ())
    named: dict[str, Path] = {}
    for name in sorted(modules):
        named.update(_module_sources(name))
    return named


def code_digest(cls: type) -> str:
    """SHA-256 (16 hex digits) over the source files ``cls``'s behaviour comes from; it depends
    on the files' contents and their names within their packages, not on where they live."""
    return _digest_files(tuple(sorted(digest_sources(cls).items())))


def completion_digest(cls: type) -> str:
    """SHA-256 (16 hex digits) over the sources of ``cls.completion_modules``, or "" when it
    names none (then cell keys are as they were before the digest existed)."""
    named: dict[str, Path] = {}
    for name in sorted(getattr(cls, "completion_modules", ()) or ()):
        named.update(_module_sources(name))
    return _digest_files(tuple(sorted(named.items()))) if named else ""
