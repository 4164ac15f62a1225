"""The wheel works anywhere: built from the checkout, installed into a fresh virtual environment,
and run from an empty folder, with no checkout and no configs/ beside it.

The fresh environment reuses this one's installed dependencies (torch, MLflow, ...) through a
.pth line instead of downloading them: what is under test is what the wheel carries. That line
does not process the .pth files of this environment, so the editable shapebench installed here
is not importable there; its dist-info is visible, but importlib.metadata keeps the first
distribution of a name, the wheel's.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from shapebench.config import INIT_FILES, builtin_config_dir, write_editable_configs

ROOT = Path(__file__).resolve().parents[2]


#: Not copied into the build's source tree: environments, stores, caches, earlier builds.
NOT_SOURCE = (".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", "shapebench-runs")
NOT_SOURCE += (".gpu", ".whl", ".pytest_cache", ".ruff_cache")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    # Built from a copy: pip builds in the source tree, and a build/ left in the checkout would
    # feed the next build stale files.
    source = tmp_path_factory.mktemp("source") / "shapebench"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(*NOT_SOURCE))
    out = tmp_path_factory.mktemp("dist")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation"]
        + ["--disable-pip-version-check", "--wheel-dir", str(out), str(source)],
        check=True,
        capture_output=True,
        text=True,
    )
    (path,) = out.glob("shapebench-*.whl")
    return path


def test_the_wheel_carries_what_runs_need(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for profile in (ROOT / "configs" / "profiles").glob("*.yaml"):
        assert f"shapebench/_configs/profiles/{profile.name}" in names
    assert "shapebench/_configs/sweeps/default.yaml" in names
    assert "shapebench/data/paper_results.csv" in names
    assert any(n.startswith("shapebench/reference_checkpoints/msc/") for n in names)
    for plugin in ("shapebench_gauss/plugin.py", "shapebench_synthetic/plugin.py"):
        assert plugin in names


@pytest.fixture(scope="module")
def fresh_env(tmp_path_factory, wheel) -> Path:
    venv = tmp_path_factory.mktemp("venv")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    Path(site, "_shapebench_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet"]
        + ["--no-deps", "--no-index", "--disable-pip-version-check", str(wheel)],
        check=True,
        capture_output=True,
        text=True,
    )
    return venv


@pytest.mark.slow
def test_an_installed_wheel_runs_and_tabulates_from_an_empty_folder(fresh_env, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SHAPEBENCH_", "MLFLOW_"))}
    env.update(
        SHAPEBENCH_WORKSPACE=str(tmp_path / "ws"),
        SHAPEBENCH_CACHE_DIR=str(tmp_path / "cache"),
        PYTHONPATH="",
    )
    python = fresh_env / "bin" / "python"

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [str(python), *args], cwd=empty, env=env, capture_output=True, text=True, timeout=600
        )

    where = run("-c", "import shapebench.config as c; print(c.__file__, c.builtin_config_dir())")
    assert where.returncode == 0, where.stderr
    module, configs = where.stdout.split()
    assert module.startswith(str(fresh_env)) and configs.startswith(str(fresh_env)), where.stdout
    assert configs.endswith("_configs")

    cmd = [str(fresh_env / "bin" / "shapebench")]

    def shapebench(*args: str) -> subprocess.CompletedProcess:
        done = subprocess.run(
            cmd + list(args), cwd=empty, env=env, capture_output=True, text=True, timeout=600
        )
        assert done.returncode == 0, done.stdout + done.stderr
        assert "Traceback" not in done.stderr
        return done

    # A built-in sweep by name, from a folder with no configs/ (gauss's cells of it only).
    shapebench("sweep", "default", "-m", "gauss", "--seeds", "0", "-D", "test_per_category=1")
    shapebench("run", "-m", "gauss", "-d", "synthetic", "--contexts", "50", "--split", "trained",
               "-D", "test_per_category=1", "-O", "sigma=0.05", "-q")  # fmt: skip
    shapebench("leaderboard", "-d", "synthetic", "--split", "trained")
    table = (tmp_path / "ws" / "leaderboards" / "synthetic-trained.md").read_text()
    assert "`gauss`" in table
    assert list(empty.iterdir()) == []  # tables go to the workspace: nothing written here


def test_init_writes_an_editable_copy_and_keeps_edits(tmp_path):
    written, kept = write_editable_configs(tmp_path)
    source = builtin_config_dir()
    expected = sorted(
        tmp_path / "configs" / p.relative_to(source) for pat in INIT_FILES for p in source.glob(pat)
    )
    assert sorted(written) == expected and not kept
    quick = tmp_path / "configs" / "profiles" / "quick.yaml"
    assert quick.read_text() == (source / "profiles" / "quick.yaml").read_text()
    quick.write_text("# mine\n")
    written, kept = write_editable_configs(tmp_path)
    assert quick in kept and quick not in written and quick.read_text() == "# mine\n"
    written, kept = write_editable_configs(tmp_path, overwrite=True)
    assert quick in written and quick.read_text() != "# mine\n"
