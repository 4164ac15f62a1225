"""Shared fixtures: a tiny synthetic benchmark, real pip-installed test plugins, CLI runner.

The CLI tests run ``python -m shapebench`` in processes of their own, as a user would, with the
third-party test plugins under ``tests/plugins/`` installed by pip into temporary folders that are
put on PYTHONPATH (a real install with real entry-point metadata, without touching the venv).
``Shapebench(...)`` forks them from an interpreter that has imported the heavy third-party
modules once (tests/cli_fork.py: most of a command's time here was imports);
``Shapebench.popen`` and ``SHAPEBENCH_TEST_EXEC=1`` start a new interpreter.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import socket
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from cli_fork import ForkServer

ROOT = Path(__file__).resolve().parents[1]
#: The machinery tests run at the quick profile, in this process and in every command they start:
#: the default (standard) generates 2,200 training shapes and 10 test objects per category. A
#: test about the default itself clears it (``extra_env={"SHAPEBENCH_PROFILE": ""}``, or
#: ``monkeypatch.delenv``).
TEST_PROFILE = "quick"
os.environ["SHAPEBENCH_PROFILE"] = TEST_PROFILE
PLUGINS = ROOT / "tests" / "plugins"

#: Dataset options that make the synthetic benchmark tiny: one test object per category.
TINY = [
    "-D",
    "test_per_category=1",
    "-D",
    "train_per_category=1",
    "-D",
    "surface_candidates=3000",
    "-D",
    "gt_points=2000",
]
TINY_CONTEXTS = ["--contexts", "50,100"]
#: A small IGR that trains in seconds (2 epochs of a 2 x 32 network), for CLI tests.
SMALL_IGR = [
    "-O",
    "latent_dim=8",
    "-O",
    "width=32",
    "-O",
    "depth=2",
    "-O",
    "epochs=2",
    "-O",
    "batch_shapes=4",
    "-O",
    "surface_points=128",
    "-O",
    "opt_steps=5",
    "-O",
    "mesh_resolution=24",
]


def load_benchmark(name: str):
    """The script ``benchmarks/<name>.py`` as a module, so tests call its ``main`` in-process.

    Registered in ``sys.modules`` first: dataclasses look their module up while the file runs.
    """
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def pip_install_to(target: Path, project: Path) -> Path:
    # pip builds a local project in its own folder (build/, *.egg-info): two xdist workers
    # installing one plugin at once then share build/bdist.*/wheel, and the second build fails
    # on the first one's files ("File exists"), and a killed build leaves them for the next.
    # Each install builds a copy of its own, so the checkout is never written to.
    source = target.with_name(f"{target.name}-src")
    shutil.copytree(project, source, ignore=shutil.ignore_patterns("build", "*.egg-info"))
    project = source
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--quiet",
            "--no-deps",
            "--no-build-isolation",
            "--disable-pip-version-check",
            "--target",
            str(target),
            str(project),
        ],
        check=True,
        capture_output=True,
        text=True,
    )
    return target


@pytest.fixture(scope="session")
def example_site(tmp_path_factory) -> Path:
    return pip_install_to(tmp_path_factory.mktemp("site-example"), PLUGINS / "shapebench-example")


@pytest.fixture(scope="session")
def broken_site(tmp_path_factory) -> Path:
    return pip_install_to(tmp_path_factory.mktemp("site-broken"), PLUGINS / "shapebench-broken")


@pytest.fixture(scope="session")
def dupe_site(tmp_path_factory) -> Path:
    return pip_install_to(tmp_path_factory.mktemp("site-dupe"), PLUGINS / "shapebench-dupe")


@pytest.fixture(scope="session")
def data_cache(tmp_path_factory) -> Path:
    """One preprocessed-data cache for the whole session: the tiny benchmark is built once."""
    return tmp_path_factory.mktemp("cache")


#: Variables read when a preloaded library is imported: a command that sets one to another value
#: than this process's starts with exec.
EXEC_ONLY_ENV = {"OMP_NUM_THREADS", "MKL_NUM_THREADS", "PYTHONWARNINGS", "PYTHONHASHSEED"}

#: Commands run by ``Shapebench(...)`` fork a pre-imported interpreter (tests/cli_fork.py), unless
#: SHAPEBENCH_TEST_EXEC=1; ``Shapebench.popen`` always starts a new interpreter.
_fork_server = None if os.environ.get("SHAPEBENCH_TEST_EXEC") == "1" else ForkServer()


def pytest_collection_modifyitems(config, items) -> None:
    """Slow tests first (stable otherwise): under xdist the long ones then start early and the
    quick ones fill in behind them, instead of one long test ending the run on one worker."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


def pytest_sessionfinish(session, exitstatus) -> None:
    if _fork_server is not None:
        _fork_server.close()


@dataclass
class Result:
    returncode: int
    stdout: str
    stderr: str


@dataclass
class Shapebench:
    """Runs the CLI in a fresh process with an isolated workspace."""

    workspace: Path
    cache: Path
    sites: tuple[Path, ...] = ()
    #: More environment variables (set after the SHAPEBENCH_ ones are cleared).
    extra_env: dict[str, str] = field(default_factory=dict)

    @property
    def tracking_uri(self) -> str:
        return f"sqlite:///{self.workspace / 'mlflow.db'}"

    def env(self) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith(("MLFLOW_", "SHAPEBENCH_"))}
        env["SHAPEBENCH_WORKSPACE"] = str(self.workspace)
        env["SHAPEBENCH_CACHE_DIR"] = str(self.cache)
        env["SHAPEBENCH_PROFILE"] = TEST_PROFILE
        env["PYTHONPATH"] = os.pathsep.join(str(s) for s in self.sites)
        env.update(self.extra_env)
        return env

    def popen(self, *args: str, **kw) -> subprocess.Popen:
        return subprocess.Popen(
            [sys.executable, "-m", "shapebench", *args],
            env=self.env(),
            cwd=self.workspace,
            text=True,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            **kw,
        )

    def __call__(self, *args: str, timeout: float = 300, fresh: bool = False) -> Result:
        """Run ``shapebench *args``; ``fresh``: in a new interpreter, for a test of what the
        command itself imports (the fork server has imported torch and Lightning already)."""
        env = self.env()
        forkable = all(env.get(k) == os.environ.get(k) for k in EXEC_ONLY_ENV)
        if _fork_server is not None and not fresh and forkable:
            proc = _fork_server.run(list(args), env, self.workspace, timeout)
        else:
            proc = subprocess.run(
                [sys.executable, "-m", "shapebench", *args],
                env=env,
                cwd=self.workspace,
                capture_output=True,
                text=True,
                timeout=timeout,
            )
        return Result(proc.returncode, proc.stdout, proc.stderr)

    def client(self):
        from mlflow.tracking import MlflowClient

        return MlflowClient(self.tracking_uri)

    def cell_runs(self, experiment: str, status: str | None = "FINISHED"):
        client = self.client()
        exp = client.get_experiment_by_name(experiment)
        if exp is None:
            return []
        flt = "tags.`shapebench.kind` = 'cell'"
        if status:
            flt += f" and attributes.status = '{status}'"
        return client.search_runs([exp.experiment_id], filter_string=flt, max_results=1000)


@pytest.fixture
def shapebench(tmp_path, data_cache) -> Shapebench:
    ws = tmp_path / "ws"
    ws.mkdir()
    return Shapebench(ws, data_cache)


@pytest.fixture
def with_example(shapebench, example_site) -> Shapebench:
    shapebench.sites = (example_site,)
    return shapebench


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
