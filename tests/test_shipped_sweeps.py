"""The sweep files shipped in configs/sweeps/ load, name installed methods and datasets, and
their options are options of those methods; the official test-time sweep adds test time only
(its rows use the default sweep's trainings, as its comment promises)."""

from __future__ import annotations

from pathlib import Path

import pytest

from shapebench.config import make_settings
from shapebench.registry.discovery import get_registry
from shapebench.registry.resolve import resolve_dataset, resolve_method
from shapebench.sweeps.spec import load_sweep, sweep_methods
from shapebench.train.training import apply_trainer, checkpoint_key, profile_trainer

SWEEPS = sorted((Path(__file__).parent.parent / "configs" / "sweeps").glob("*.yaml"))


@pytest.mark.parametrize("path", SWEEPS, ids=[p.stem for p in SWEEPS])
def test_shipped_sweep_resolves(path, tmp_path):
    spec = load_sweep(path)
    settings = make_settings(workspace=str(tmp_path), profile=spec.profile)
    registry = get_registry()
    for entry in sweep_methods(spec):  # unknown method or dataset names fail here
        resolve_method(registry, entry.name, settings, entry.options)  # unknown options fail


def test_official_test_time_sweep_reuses_the_default_trainings(tmp_path):
    spec = load_sweep(Path(__file__).parent.parent / "configs/sweeps/official-test-time.yaml")
    settings = make_settings(workspace=str(tmp_path))
    registry = get_registry()
    dataset = resolve_dataset(registry, "synthetic", settings, None, {})
    trainer = profile_trainer(settings, 0)

    def key(name: str, options: dict) -> str:
        method = resolve_method(registry, name, settings, options)
        return checkpoint_key(apply_trainer(method, trainer), dataset, trainer)

    entries = sweep_methods(spec)
    assert {e.options.get("opt_steps") for e in entries} == {800}
    for entry in entries:
        assert key(entry.name, entry.options) == key(entry.name, {}), entry.name
