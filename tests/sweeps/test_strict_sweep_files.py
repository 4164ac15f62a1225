"""A sweep file's launcher block, its entries and their options are checked strictly (issue 59):
a list or a bool where a number belongs, an unknown key, an option of the wrong type are each
refused in one line naming the key (and the closest valid name), before any job or cell; valid
blocks give the launcher config they gave before."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest

from shapebench.api.errors import ConfigError
from shapebench.api.options import parse_assignments
from shapebench.sweeps.cluster import LauncherConfig, launcher_config
from shapebench.sweeps.spec import load_sweep, sweep_methods, with_dataset_options


def _refused(block: dict[str, Any], overrides: dict[str, Any] | None = None) -> ConfigError:
    with pytest.raises(ConfigError) as err:
        launcher_config(block, overrides or {}, None)
    assert "\n" not in err.value.message  # one line
    return err.value


@pytest.mark.parametrize(
    "block, message",
    [
        ({"time": [1]}, "launcher: time must be int, got [1]"),
        ({"gpus_per_node": True}, "launcher: gpus_per_node must be int, got True"),
        ({"time": 1.5}, "launcher: time must be int, got 1.5"),
        ({"mem_gb": True}, "launcher: mem_gb must be float | None, got True"),
        ({"partition": 3}, "launcher: partition must be str | None, got 3"),
        ({"setup": "module load cuda"}, "launcher: setup must be list[str], got 'module load"),
        ({"setup": ["module load cuda", 12]}, "(item 1: 12 is not str)"),
        ({"extra": ["mail-type=END"]}, "launcher: extra must be dict[str, Any], got ['mail"),
        ({"methods": {"igr": {"time": [1]}}}, "launcher.methods.igr: time must be int, got [1]"),
        ({"methods": {"igr": 4}}, "launcher: methods must be dict[str, dict[str, Any]], got"),
        ({"time": "two hours"}, "launcher: time must be a number (int), got 'two hours'"),
    ],
)
def test_a_wrong_type_in_the_launcher_block_is_named(block, message):
    assert message in _refused(block).message


def test_a_per_method_block_is_checked_before_any_job_is_submitted():
    # before, `time: [1]` under methods.igr passed until igr's job reached submitit
    err = _refused({"methods": {"igr": {"gpu": 1}}})
    assert "launcher.methods.igr: unknown launcher keys ['gpu']" in err.message


def test_an_unknown_launcher_key_names_the_closest_one():
    err = _refused({"partiton": "gpu", "gpus_per_nod": 1})
    assert err.message == (
        "launcher: unknown launcher keys ['gpus_per_nod', 'partiton']: 'gpus_per_nod' (did you "
        "mean 'gpus_per_node'?), 'partiton' (did you mean 'partition'?)"
    )
    err = _refused({}, {"tme": 30})
    assert err.message.startswith("--slurm: unknown launcher keys ['tme']: 'tme' (did you mean")


def _old_apply(cfg: LauncherConfig, values: dict[str, Any]) -> LauncherConfig:
    """``shapebench.sweeps.cluster._apply`` as it was before the strict check (issue 59)."""
    out = {}
    for key, value in values.items():
        default = getattr(cfg, key)
        if isinstance(default, bool) or default is None or isinstance(default, (dict, list)):
            out[key] = value
        elif isinstance(default, (int, float)) and isinstance(value, str):
            out[key] = type(default)(value)
        else:
            out[key] = value
    return dataclasses.replace(cfg, **out)


def test_a_valid_launcher_block_gives_the_config_it_gave_before():
    block = {
        "name": "slurm",
        "partition": "gpu",
        "time": 240,
        "gpus_per_node": 1,
        "cpus_per_task": 8,
        "mem_gb": 16,  # an int stays an int: sbatch gets --mem=16GB, not 16.0GB
        "account": "lab",
        "qos": "normal",
        "constraint": "a100",
        "array_parallelism": 8,
        "cells_per_job": 4,
        "signal_delay_s": 120,
        "tracking": "per-job",
        "setup": ["module load cuda"],
        "extra": {"mail-type": "END", "exclusive": True},
        "methods": {"igr": {"time": 600, "mem_gb": 32.5}},
    }
    slurm = parse_assignments(["time=30", "mem_gb=24", "qos=high"], "--slurm")
    given = [(block, {}), (block, slurm), ({"time": "30", "mem_gb": "16"}, {}), ({}, {})]
    for b, o in given:
        new = launcher_config(b, o, None)
        old = _old_apply(_old_apply(LauncherConfig(), b), o)
        if b.get("mem_gb") == "16":  # text became a number: the same sbatch --mem
            old = dataclasses.replace(old, mem_gb=16)
        assert new == old
        assert [type(getattr(new, f.name)) for f in dataclasses.fields(new)] == [
            type(getattr(old, f.name)) for f in dataclasses.fields(old)
        ]
        for method in new.methods:
            assert new.for_method(method) == _old_apply(new, new.methods[method])
    assert launcher_config(block, slurm, None).for_method("igr").mem_gb == 32.5


# -- sweep files ---------------------------------------------------------------------------------


def _sweep(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "s.yaml"
    path.write_text(text)
    return path


def _load_refused(path: Path) -> ConfigError:
    with pytest.raises(ConfigError) as err:
        load_sweep(path)
    assert "\n" not in err.value.message and str(path) in err.value.message
    return err.value


def test_a_launcher_block_is_checked_when_the_file_is_read(tmp_path):
    text = "methods: [gauss]\ndatasets: [synthetic]\nlauncher: {name: slurm, time: [1]}\n"
    err = _load_refused(_sweep(tmp_path, text))
    assert err.message == f"{tmp_path / 's.yaml'}: launcher: time must be int, got [1]"
    text = "methods: [gauss]\ndatasets: [synthetic]\nlauncher: {gpus_per_node: true}\n"
    err = _load_refused(_sweep(tmp_path, text))
    assert err.message.endswith("launcher: gpus_per_node must be int, got True")


def test_an_unknown_sweep_key_names_the_closest_one(tmp_path):
    err = _load_refused(
        _sweep(tmp_path, "methods: [gauss]\ndatasets: [synthetic]\ncontext: [50]\n")
    )
    assert err.message.endswith("unknown keys ['context']: 'context' (did you mean 'contexts'?)")
    text = "methods: [{name: gauss, option: {sigma: 0.1}}]\ndatasets: [synthetic]\n"
    err = _load_refused(_sweep(tmp_path, text))
    assert "'option' (did you mean 'options'?)" in err.message


@pytest.mark.parametrize(
    "entry, message",
    [
        (
            "{name: gauss, options: [sigma]}",
            "'options' of a 'methods' entry must be dict[str, Any]",
        ),
        ("{name: [gauss]}", "'name' of a 'methods' entry must be str, got ['gauss']"),
        ("{name: gauss, label: 3}", "'label' of a 'methods' entry must be str | None, got 3"),
    ],
)
def test_an_entry_of_the_wrong_type_is_named(tmp_path, entry, message):
    err = _load_refused(_sweep(tmp_path, f"methods: [{entry}]\ndatasets: [synthetic]\n"))
    assert message in err.message


def test_entry_options_and_dash_d_are_checked_before_any_work(tmp_path):
    text = "methods: [{name: pcn, options: {grid_size: true}}]\ndatasets: [synthetic]\n"
    spec = load_sweep(_sweep(tmp_path, text))
    with pytest.raises(ConfigError) as err:
        sweep_methods(spec)
    assert (
        err.value.message == "option 'grid_size' of method 'pcn' of sweep 's' must be int, got True"
    )

    spec = load_sweep(_sweep(tmp_path, "methods: [gauss]\ndatasets: [synthetic]\n"))
    sweep_methods(spec)  # no options: fine
    dash_d = with_dataset_options(spec, parse_assignments(["test_per_categry=1"], "-D"))
    with pytest.raises(ConfigError) as err:
        sweep_methods(dash_d)
    assert "'test_per_categry' (did you mean 'test_per_category'?)" in err.value.message
    good = with_dataset_options(spec, parse_assignments(["test_per_category=1"], "-D"))
    assert sweep_methods(good)[0].name == "gauss"
