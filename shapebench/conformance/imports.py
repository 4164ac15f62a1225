"""The ``imports`` check of every component: its modules import, in a fresh interpreter, without
torch or Lightning (``shapebench --help`` imports every plugin)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from shapebench.conformance.framework import CheckFailed, CheckSkipped, Component

#: Modules no plugin may import when it is imported (``shapebench --help`` imports every plugin).
HEAVY_MODULES = ("torch", "pytorch_lightning", "lightning")

#: Run in a fresh interpreter: which of the heavy modules each module brought in.
_IMPORT_PROBE = """
import importlib, json, sys
heavy = {heavy!r}
found = []
for module in {modules!r}:
    importlib.import_module(module)
    found.append([module, [m for m in heavy if m in sys.modules]])
print(json.dumps(found))
"""


def check_imports(comp: Component) -> str:
    """Import the component's modules in a fresh interpreter (this one may hold torch already):
    ``shapebench --help`` imports every plugin, so none may import torch or Lightning."""
    modules = comp.modules()
    if not modules:
        raise CheckSkipped(
            f"{comp.name} is defined in {comp.cls and comp.cls.__module__}, "
            "which another interpreter cannot import"
        )
    code = _IMPORT_PROBE.format(heavy=HEAVY_MODULES, modules=modules)
    env = dict(os.environ)
    # The same modules as this process sees (a test's sys.path, a target install).
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300
    )
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise CheckFailed(f"importing {', '.join(modules)} failed: {last}")
    found = json.loads(proc.stdout.strip().splitlines()[-1])
    seen: list[str] = []
    for module, heavy in found:
        new = [m for m in heavy if m not in seen]
        if new:
            raise CheckFailed(
                f"importing {module} imports {', '.join(new)}: import it inside the methods that "
                "use it (shapebench --help imports every plugin)"
            )
        seen = heavy
    return f"{', '.join(modules)} import without {', '.join(HEAVY_MODULES)}"
