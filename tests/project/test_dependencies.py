"""What an install resolves: declared dependencies complete and used (deptry), and the versions
pinned by constraints.txt, the lock that scripts/setup.sh and CI install through."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[2]
LOCK = ROOT / "constraints.txt"
_PYPROJECT = (ROOT / "pyproject.toml").read_text()


def _pins() -> dict[str, str]:
    pins = {}
    for line in LOCK.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, version = line.partition("==")
            assert version, f"constraints.txt: {line!r} is not a pin (name==version)"
            pins[canonicalize_name(name)] = version
    return pins


def _deptry() -> str | None:
    exe = Path(sys.executable).with_name("deptry")
    return str(exe) if exe.exists() else shutil.which("deptry")


def test_declared_dependencies_are_complete_and_used():
    deptry = _deptry()
    if deptry is None:
        pytest.skip("deptry is not installed (it comes with the `test` extra)")
    res = subprocess.run([deptry, "."], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]


def test_every_builtin_package_is_first_party_to_deptry():
    """A new plugin or dataset package under plugins/ or datasets/ must be listed, or deptry
    reports each of its own imports as an undeclared dependency."""
    block = re.search(r"^known_first_party = \[(.*?)\]", _PYPROJECT, re.M | re.S)
    assert block, "pyproject.toml has no [tool.deptry] known_first_party"
    listed = set(re.findall(r'"([\w.]+)"', block.group(1)))
    packages = {
        p.parent.name
        for folder in ("plugins", "datasets")
        for p in (ROOT / folder).glob("shapebench_*/__init__.py")
    }
    assert packages - listed == set(), "add these to [tool.deptry] known_first_party"


def test_the_lock_pins_every_declared_dependency_and_setup_installs_through_it():
    pins = _pins()
    declared = [Requirement(r) for r in metadata.requires("shapebench") or []]
    unpinned = sorted(
        r.name
        for r in declared
        if canonicalize_name(r.name) not in pins
        and canonicalize_name(r.name) != "torch"  # setup.sh keeps the environment's torch
        and (r.marker is None or r.marker.evaluate({"extra": "test"}))
    )
    assert unpinned == [], f"not in constraints.txt (run scripts/lock.sh): {unpinned}"
    assert "torch" not in pins, "constraints.txt must not pin torch (setup.sh keeps the user's)"
    assert "-c constraints.txt" in (ROOT / "scripts" / "setup.sh").read_text()
    assert "scripts/setup.sh" in (ROOT / ".ci" / "run").read_text()


def test_this_environment_has_the_locked_versions():
    """Drift shows here: an environment installed by setup.sh or CI has exactly the pinned
    versions (pins of packages this platform does not install are skipped)."""
    drift = []
    for name, version in _pins().items():
        try:
            installed = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
        if installed != version:
            drift.append(f"{name} {installed} (lock: {version})")
    assert drift == [], (
        "installed versions differ from constraints.txt; reinstall with `bash scripts/setup.sh`, "
        f"or refresh the lock with `bash scripts/lock.sh`: {drift}"
    )
