"""Plugin discovery through real entry points of pip-installed distributions."""

from __future__ import annotations

import subprocess
import sys
import warnings
from importlib.metadata import EntryPoint

import pytest
from conftest import TINY

from shapebench.errors import PluginConflictError, UnknownNameError
from shapebench.registry import PluginWarning, discover


def test_builtins_register_through_entry_points(shapebench):
    res = shapebench("plugins")
    assert res.returncode == 0, res.stderr
    for ep, provides in (("gauss", "methods: gauss"), ("synthetic", "datasets: synthetic"),
                         ("metrics", "chamfer-l2")):  # fmt: skip
        line = next(ln for ln in res.stdout.splitlines() if ln.startswith(ep + " "))
        assert "shapebench" in line and "0.1.0" in line
        assert provides in res.stdout


def test_third_party_plugin_is_listed_described_and_runs(with_example):
    res = with_example("plugins")
    assert res.returncode == 0, res.stderr
    line = next(ln for ln in res.stdout.splitlines() if ln.startswith("example "))
    assert "shapebench-example" in line and "0.3.1" in line and "shapebench_example.plugin" in line
    assert "methods: example-sphere, example-template, example-flaky" in res.stdout

    res = with_example("methods")
    assert res.returncode == 0, res.stderr
    assert "example-sphere  (shapebench-example 0.3.1)" in res.stdout
    assert "radius_scale (float, default 1.0)" in res.stdout
    assert "trains: yes; needs: surface_points" in res.stdout  # example-template

    res = with_example("run", "-m", "example-sphere", "-d", "synthetic", *TINY, "--contexts", "50")
    assert res.returncode == 0, res.stderr
    assert "example-sphere on synthetic/novel" in res.stdout
    run = with_example.cell_runs("synthetic-novel")[0]
    assert run.data.tags["plugin.distribution"] == "shapebench-example"
    assert run.data.tags["plugin.version"] == "0.3.1"


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


def test_two_distributions_with_one_name_is_an_error_naming_both(shapebench, dupe_site):
    shapebench.sites = (dupe_site,)
    res = shapebench("run", "-m", "gauss", "-d", "synthetic")
    assert res.returncode == 2
    assert "method 'gauss' is provided by more than one installed distribution" in res.stderr
    assert "shapebench 0.1.0" in res.stderr and "shapebench-dupe 1.0.0" in res.stderr
    listing = shapebench("plugins")
    assert "conflict: method 'gauss'" in listing.stdout


def test_cli_startup_imports_neither_torch_nor_mlflow():
    code = (
        "import sys\n"
        "from shapebench.cli import cli\n"
        "from shapebench.registry import get_registry\n"
        "reg = get_registry(); assert reg.names('method')\n"
        "heavy = ('torch', 'mlflow', 'trimesh', 'pytorch_lightning')\n"
        "heavy = [m for m in heavy if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


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
    eps = [EntryPoint("bad", "sb_bad_mod", "shapebench"),
           EntryPoint("good", "sb_good_mod", "shapebench")]  # fmt: skip
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
        reg = discover([EntryPoint("a", "sb_a_mod", "shapebench"),
                        EntryPoint("b", "sb_b_mod", "shapebench")])  # fmt: skip
    with pytest.raises(PluginConflictError):
        reg.get("method", "same")
    with pytest.raises(UnknownNameError, match="available: same"):
        reg.get("method", "other")
