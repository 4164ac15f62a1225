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
from shapebench.train.ticket import apply_trainer, checkpoint_key
from shapebench.train.training import profile_trainer

SWEEPS = sorted((Path(__file__).parents[2] / "configs" / "sweeps").glob("*.yaml"))


@pytest.mark.parametrize("path", SWEEPS, ids=[p.stem for p in SWEEPS])
def test_shipped_sweep_resolves(path, tmp_path):
    spec = load_sweep(path)
    settings = make_settings(workspace=str(tmp_path), profile=spec.profile)
    registry = get_registry()
    for entry in sweep_methods(spec):  # unknown method or dataset names fail here
        resolve_method(registry, entry.name, settings, entry.options)  # unknown options fail


def test_official_test_time_sweep_reuses_the_default_trainings(tmp_path):
    spec = load_sweep(Path(__file__).parents[2] / "configs/sweeps/official-test-time.yaml")
    settings = make_settings(workspace=str(tmp_path), profile=spec.profile)
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


def test_data_scaling_sweep_is_a_cross_over_shared_test_objects(tmp_path):
    from shapebench.sweeps.spec import pairs

    spec = load_sweep(Path(__file__).parents[2] / "configs/sweeps/data-scaling.yaml")
    assert spec.profile == "quick"  # its budgets are quick's, whatever the default is
    settings = make_settings(workspace=str(tmp_path), profile=spec.profile)
    registry = get_registry()
    trainer = profile_trainer(settings, 0)
    runs = pairs(spec, sweep_methods(spec))
    sizes = {ds.label: ds for ds in spec.datasets}
    assert list(sizes) == ["66-shapes", "220-shapes", "660-shapes", "2200-shapes"]
    # Ten methods at every size, and two longer budgets of each at the largest: 10 x 4 + 20 runs.
    assert len(runs) == 10 * 4 + 20
    assert all(ds.label == "2200-shapes" for _, ds, _, m in runs if m.options)

    def resolved(ds):
        return resolve_dataset(registry, ds.name, settings, ds.data_root, ds.options)

    # One set of test objects: a training-only option leaves the evaluation data as it is.
    fingerprints = {resolved(ds).data_fingerprint() for ds in spec.datasets}
    assert len(fingerprints) == 1
    default = resolve_dataset(registry, "synthetic", settings, None, {})
    keys = set()
    for _, ds, _, m in runs:
        method = resolve_method(registry, m.name, settings, m.options)
        keys.add(checkpoint_key(apply_trainer(method, trainer), resolved(ds), trainer))
    # msc-noopt shares msc's trainings, msc-hier-noopt msc-hier's: 8 families x (4 sizes + 2
    # budgets).
    assert len(keys) == 8 * 6
    # The smallest size is the profile's: its runs use the default (shipped) trainings.
    msc = resolve_method(registry, "msc", settings, {})
    assert checkpoint_key(msc, resolved(sizes["66-shapes"]), trainer) == checkpoint_key(
        msc, default, trainer
    )


def test_a_method_entry_may_name_only_datasets_the_sweep_has(tmp_path):
    from shapebench.api.errors import ConfigError

    path = tmp_path / "s.yaml"
    path.write_text(
        "methods: [{name: gauss, datasets: [big]}]\ndatasets: [{name: synthetic, label: small}]\n"
    )
    with pytest.raises(ConfigError, match=r"names datasets \['big'\].*label: big"):
        load_sweep(path)


def test_a_sweep_narrowed_to_some_methods_keeps_their_entries_and_keys(tmp_path):
    """`shapebench sweep -m msc,msc-noopt`: MSC's part of the data-scaling cross, with the same
    entries (options, datasets, labels) as in the whole sweep; an absent name is one clear error."""
    from shapebench.api.errors import ConfigError
    from shapebench.sweeps.spec import only_methods, pairs

    spec = load_sweep(Path(__file__).parents[2] / "configs/sweeps/data-scaling.yaml")
    whole = pairs(spec, sweep_methods(spec))
    part = only_methods(spec, ["msc,msc-noopt"])
    assert only_methods(spec, ["msc", "msc-noopt"]) == part
    kept = pairs(part, sweep_methods(part))
    # Four sizes at the profile's budget and two longer budgets at the largest, for each.
    assert len(kept) == 2 * (4 + 2)
    expected = [(ds, m) for _, ds, _, m in whole if m.name in ("msc", "msc-noopt")]
    assert [(ds, m) for _, ds, _, m in kept] == expected
    assert only_methods(spec, []) is spec
    with pytest.raises(ConfigError, match=r"no entry of method 'mcs'") as err:
        only_methods(spec, ["msc,mcs"])
    assert "msc-noopt" in err.value.hint


def test_a_sweep_narrowed_to_some_seeds_keeps_the_files_order_and_entries():
    """`shapebench sweep --seeds 2,0`: those seeds of the file, in the file's order, every entry
    kept; none keep the sweep; a seed the file lacks is one clear error."""
    from shapebench.api.errors import ConfigError
    from shapebench.sweeps.spec import only_seeds

    spec = load_sweep(Path(__file__).parents[2] / "configs/sweeps/standard.yaml")
    assert spec.seeds == [0, 1, 2]
    part = only_seeds(spec, [2, 0, 2])
    assert part.seeds == [0, 2] and part.methods == spec.methods
    assert only_seeds(spec, []) is spec
    with pytest.raises(ConfigError, match="no seed 3") as err:
        only_seeds(spec, [3])
    assert err.value.hint == "its seeds: 0, 1, 2"


def test_the_data_scaling_cross_at_4x_is_the_standard_profiles_seed_0(tmp_path):
    """A training the data-scaling sweep makes at 2,200 shapes and 4x the steps is the one the
    standard profile's tables need for seed 0: the same key, trained once."""
    from shapebench.sweeps.spec import pairs

    root = Path(__file__).parents[2] / "configs" / "sweeps"
    scaling, standard = load_sweep(root / "data-scaling.yaml"), load_sweep(root / "standard.yaml")
    registry = get_registry()

    def keys(spec, runs) -> dict[str, str]:
        settings = make_settings(workspace=str(tmp_path), profile=spec.profile)
        trainer = profile_trainer(settings, 0)
        out = {}
        for _, ds, _, m in runs:
            method = resolve_method(registry, m.name, settings, m.options)
            if not method.cls.trains:
                continue
            data = resolve_dataset(registry, ds.name, settings, ds.data_root, ds.options)
            out[m.name] = checkpoint_key(apply_trainer(method, trainer), data, trainer)
        return out

    # Not IGR and DeepSDF: the standard profile gives the auto-decoders 64 shapes per batch so
    # that each code moves as often as at quick (configs/profiles/standard.yaml), where the
    # data-scaling sweep keeps one recipe along its axes.
    four_x = {"msc": 10800, "msc-noopt": 10800}
    four_x |= {"msc-hier": 10800, "msc-hier-noopt": 10800, "occnet": 3600, "convonet": 3600}
    four_x |= {"pointr": 3600}
    cross = [
        run
        for run in pairs(scaling, sweep_methods(scaling))
        if run[1].label == "2200-shapes"
        and run[3].name in four_x
        and run[3].options.get("steps") == four_x[run[3].name]
    ]
    assert {run[3].name for run in cross} == set(four_x)
    standard_keys = keys(standard, pairs(standard, sweep_methods(standard)))
    assert keys(scaling, cross) == {name: standard_keys[name] for name in four_x}


def test_the_default_sweep_trains_nothing_from_a_fresh_clone(tmp_path):
    """Every trainable row of configs/sweeps/default.yaml, at the real default profile (not the
    quick one the other tests run at), finds a shipped reference: the quickstart installs weights
    and trains nothing. A change to a method's code or options that moves its key fails here
    until its reference is retrained (scripts/reference_checkpoints.py). A method whose "training"
    no trainer setting changes (``fit_ignores_trainer``: retrieval's index of the training
    shapes) ships none: a run builds it, once for every seed."""
    from shapebench.config import DEFAULT_PROFILE
    from shapebench.train.ticket import find_reference

    spec = load_sweep(Path(__file__).parents[2] / "configs/sweeps/default.yaml")
    assert spec.profile is None  # it follows the default
    settings = make_settings(workspace=str(tmp_path), profile=DEFAULT_PROFILE)
    registry = get_registry()
    dataset = resolve_dataset(registry, "synthetic", settings, None, {})
    assert spec.seeds == [0, 1, 2]  # the committed tables are over three training seeds
    resolved = [
        (entry.name, resolve_method(registry, entry.name, settings, entry.options))
        for entry in sweep_methods(spec)
    ]
    trainable = {name for name, method in resolved if method.cls.trains}
    built = {name for name, method in resolved if method.cls.fit_ignores_trainer} & trainable
    built_keys: dict[str, set[str]] = {name: set() for name in built}
    for seed in spec.seeds:
        trainer = profile_trainer(settings, seed)
        for name, resolved_method in resolved:
            if name in trainable:
                method = apply_trainer(resolved_method, trainer)
                key = checkpoint_key(method, dataset, trainer)
                if name in built:
                    built_keys[name].add(key)
                    continue
                found = find_reference(method, key)
                assert found is not None, f"{name}, seed {seed}: no reference for {key}"
    assert {"igr", "deepsdf", "msc", "occnet", "pcn"} <= trainable - built
    assert "retrieval" in built
    # Built once: one key for the three seeds.
    assert all(len(keys) == 1 for keys in built_keys.values()), built_keys


def test_sweep_dataset_options_shrink_the_benchmark_and_keep_every_key(tmp_path):
    """`shapebench sweep default.yaml -D test_per_category=4` (the quickstart): every dataset entry
    takes the option over its own, the test objects are the first 4 of each category of the
    whole sweep's, and no checkpoint key moves (the same shipped weights serve both)."""
    from shapebench.sweeps.spec import with_dataset_options

    path = tmp_path / "s.yaml"
    path.write_text(
        "methods: [msc]\ndatasets: [{name: synthetic, options: {test_per_category: 3}},"
        " {name: synthetic, label: big, options: {train_per_category: 20}}]\n"
    )
    spec = load_sweep(path)
    small = with_dataset_options(spec, {"test_per_category": 2})
    assert [d.options for d in small.datasets] == [
        {"test_per_category": 2},
        {"train_per_category": 20, "test_per_category": 2},
    ]
    assert [d.label for d in small.datasets] == [None, "big"]
    assert with_dataset_options(spec, {}) is spec
    settings = make_settings(workspace=str(tmp_path), cache_dir=tmp_path / "cache")
    registry = get_registry()
    trainer = profile_trainer(settings, 0)
    msc = apply_trainer(resolve_method(registry, "msc", settings, {}), trainer)
    (whole, part) = (
        resolve_dataset(registry, "synthetic", settings, None, s.datasets[0].options)
        for s in (spec, small)
    )
    assert checkpoint_key(msc, whole, trainer) == checkpoint_key(msc, part, trainer)
    ids = {s: [o.id for o in d.objects("trained")] for s, d in (("whole", whole), ("part", part))}
    assert len(ids["whole"]) == 3 * len(ids["part"]) / 2
    assert set(ids["part"]) <= set(ids["whole"])
