"""Plugin discovery through real entry points of pip-installed distributions."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from importlib.metadata import EntryPoint

import pytest
from conftest import TINY

from shapebench.api.errors import PluginConflictError, UnknownNameError
from shapebench.registry.discovery import PluginWarning, discover


@pytest.mark.slow  # runs the CLI in subprocesses
def test_builtins_register_through_entry_points(shapebench):
    res = shapebench("plugins")
    assert res.returncode == 0, res.stderr
    for ep, provides in (
        ("gauss", "methods: gauss"),
        ("synthetic", "datasets: synthetic"),
        ("metrics", "chamfer-l2"),
    ):
        line = next(ln for ln in res.stdout.splitlines() if ln.startswith(ep + " "))
        assert "shapebench" in line and "0.1.0" in line
        assert provides in res.stdout


@pytest.mark.slow  # runs the CLI in subprocesses
def test_third_party_plugin_is_listed_described_and_runs(with_example):
    res = with_example("plugins")
    assert res.returncode == 0, res.stderr
    line = next(ln for ln in res.stdout.splitlines() if ln.startswith("example "))
    assert "shapebench-example" in line and "0.3.1" in line and "shapebench_example.plugin" in line
    assert "methods: example-sphere, example-template, example-flaky" in res.stdout

    res = with_example("methods")
    assert res.returncode == 0, res.stderr
    assert "example-sphere  (shapebench-example 0.3.1)" in res.stdout
    assert "radius_scale (float, 1.0)" in res.stdout  # the value in effect (the default)
    assert "trains: yes; needs: surface_points" in res.stdout  # example-template

    res = with_example("run", "-m", "example-sphere", "-d", "synthetic", *TINY, "--contexts", "50")
    assert res.returncode == 0, res.stderr
    assert "example-sphere on synthetic/novel" in res.stdout
    run = with_example.cell_runs("synthetic-novel")[0]
    assert run.data.tags["plugin.distribution"] == "shapebench-example"
    assert run.data.tags["plugin.version"] == "0.3.1"


@pytest.mark.slow  # runs the CLI in subprocesses
def test_plugin_that_raises_on_import_is_a_warning(with_example, broken_site):
    with_example.sites = (*with_example.sites, broken_site)
    res = with_example("plugins")
    assert res.returncode == 0, res.stderr
    assert "Warning: shapebench plugin 'broken' (shapebench-broken 0.0.1) failed to import" in (
        res.stderr
    )
    assert "Traceback" not in res.stderr
    assert "error: failed to import: ImportError" in res.stdout
    assert "methods: example-sphere" in res.stdout  # the others still load
    assert with_example("methods").returncode == 0


@pytest.mark.slow  # runs the CLI in subprocesses
def test_two_distributions_with_one_name_is_an_error_naming_both(shapebench, dupe_site):
    shapebench.sites = (dupe_site,)
    res = shapebench("run", "-m", "gauss", "-d", "synthetic")
    assert res.returncode == 2
    assert "method 'gauss' is provided by more than one installed distribution" in res.stderr
    assert "shapebench 0.1.0" in res.stderr and "shapebench-dupe 1.0.0" in res.stderr
    listing = shapebench("plugins")
    assert "conflict: method 'gauss'" in listing.stdout


#: What start-up must not pay for: torch and Lightning take seconds to import, MLflow about one.
HEAVY = ("torch", "pytorch_lightning", "lightning", "mlflow")


def _run_fresh(code: str) -> object:
    """Run ``code`` in a fresh interpreter (a clean sys.modules: this test process has long
    imported torch) and return the JSON value it prints last."""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_cli_startup_imports_neither_torch_nor_mlflow():
    code = (
        "import json, sys\n"
        "from shapebench.cli import cli\n"
        "from shapebench.registry.discovery import get_registry\n"
        "reg = get_registry(); assert reg.names('method')\n"
        f"print(json.dumps([m for m in {(*HEAVY, 'trimesh')!r} if m in sys.modules]))\n"
    )
    assert _run_fresh(code) == []


def test_loading_every_registered_class_imports_no_torch():
    """The lazy-torch rule (see shapebench.api.method) for every method, dataset and metric that the
    entry points register, built-ins included: importing the class's module must not import
    torch, since ``shapebench methods`` loads every method class to describe it."""
    code = (
        "import json, sys\n"
        "from shapebench.registry.discovery import KINDS, get_registry\n"
        "reg = get_registry()\n"
        "loaded, heavy = [], {}\n"
        "for kind in KINDS:\n"
        "    for name in reg.names(kind):\n"
        "        reg.get(kind, name).load()\n"
        "        loaded.append(f'{kind} {name}')\n"
        f"        new = [m for m in {HEAVY!r} if m in sys.modules and m not in heavy]\n"
        "        heavy.update({m: f'{kind} {name}' for m in new})\n"
        "print(json.dumps({'loaded': loaded, 'heavy': heavy}))\n"
    )
    out = _run_fresh(code)
    for expected in (
        "method igr",
        "method pcn",
        "method gauss",
        "dataset synthetic",
        "metric chamfer-l2",
    ):
        assert expected in out["loaded"]  # the check below is not vacuous
    assert out["heavy"] == {}, f"module imported by the first class that pulled it: {out['heavy']}"


def test_methods_command_imports_no_torch():
    """``shapebench methods`` run to its end, as the console script runs it."""
    code = (
        "import atexit, json, sys\n"
        f"atexit.register(lambda: print(json.dumps([m for m in {HEAVY!r} if m in sys.modules])))\n"
        "sys.argv = ['shapebench', 'methods']\n"
        "from shapebench.cli import main\n"
        "main()\n"
    )
    assert _run_fresh(code) == []


# -- in-process checks of the loader ------------------------------------------------------------


def _write_module(tmp_path, name: str, body: str) -> None:
    (tmp_path / f"{name}.py").write_text(body)


def test_discover_survives_a_broken_entry_point(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    _write_module(tmp_path, "sb_bad_mod", "raise RuntimeError('boom')\n")
    _write_module(
        tmp_path,
        "sb_good_mod",
        "from shapebench import hookimpl\n"
        "@hookimpl\n"
        "def shapebench_register_metrics(register):\n"
        "    register('good-metric', 'shapebench.metrics.chamfer:ChamferL2')\n",
    )
    eps = [
        EntryPoint("bad", "sb_bad_mod", "shapebench"),
        EntryPoint("good", "sb_good_mod", "shapebench"),
    ]
    with pytest.warns(PluginWarning, match="'bad'.*RuntimeError: boom"):
        reg = discover(eps)
    assert reg.names("metric") == ["good-metric"]
    assert [p.error is None for p in reg.plugins] == [False, True]


def test_misspelled_hook_is_reported(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    _write_module(
        tmp_path,
        "sb_typo_mod",
        "from shapebench import hookimpl\n"
        "@hookimpl\n"
        "def shapebench_register_method(register):\n"
        "    pass\n",
    )
    with pytest.warns(PluginWarning, match="unknown hook"):
        reg = discover([EntryPoint("typo", "sb_typo_mod", "shapebench")])
    assert "unknown hook" in reg.plugins[0].error


def test_unknown_and_conflicting_names(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("sb_a_mod", "sb_b_mod"):
        _write_module(
            tmp_path,
            name,
            "from shapebench import hookimpl\n"
            "@hookimpl\n"
            "def shapebench_register_methods(register):\n"
            "    register('same', 'shapebench_gauss.method:GaussDensification')\n",
        )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        reg = discover(
            [EntryPoint("a", "sb_a_mod", "shapebench"), EntryPoint("b", "sb_b_mod", "shapebench")]
        )
    with pytest.raises(PluginConflictError):
        reg.get("method", "same")
    with pytest.raises(UnknownNameError, match="available: same"):
        reg.get("method", "other")


def test_metrics_listing_names_the_frames_and_each_metrics_factor(capsys):
    """`shapebench metrics`: every card depends on a frame, and the paper's figures are only
    comparable in unit-diameter; squared values convert by 1/4, unsquared by 1/2."""
    from shapebench.cli.printing import describe_kind

    describe_kind("metric")
    out = capsys.readouterr().out
    assert "unit-radius [default]: coordinates x 1" in out
    assert "unit-diameter [the paper's tables]: coordinates x 0.5" in out
    blocks = {b.split()[0]: b for b in out.split("\n\n") if b.strip()}
    assert "x 0.25 (distances squared: 1/4)" in blocks["chamfer-l2"]
    assert "x 0.5 (distances: 1/2)" in blocks["chamfer-l1"]
    assert "not a fixed factor" in blocks["fscore"]
