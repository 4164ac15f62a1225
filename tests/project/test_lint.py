"""Style is part of the suite: the whole tree passes ruff."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_ruff_clean():
    ruff = shutil.which("ruff") or str(Path(sys.executable).with_name("ruff"))
    if not Path(ruff).exists():
        pytest.skip("ruff is not installed (pip install -e '.[test]')")
    res = subprocess.run([ruff, "check", str(ROOT)], capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0, res.stdout


def test_ruff_format_clean():
    """The formatter's layout everywhere: no ``# fmt: skip`` is needed (docs/architecture.md)."""
    ruff = shutil.which("ruff") or str(Path(sys.executable).with_name("ruff"))
    if not Path(ruff).exists():
        pytest.skip("ruff is not installed (pip install -e '.[test]')")
    res = subprocess.run(
        [ruff, "format", "--check", str(ROOT)], capture_output=True, text=True, cwd=ROOT
    )
    assert res.returncode == 0, res.stdout + "\nrun: ruff format ."


@pytest.mark.parametrize(
    "script",
    sorted(
        p.relative_to(ROOT).as_posix()
        for d in ("benchmarks", "scripts")
        for p in (ROOT / d).glob("*.sh")
    ),
)
def test_shell_scripts_parse(script):
    """The GPU scripts run only on a lent machine, in minutes no one can spare for a typo."""
    res = subprocess.run(["bash", "-n", script], capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0, res.stderr
