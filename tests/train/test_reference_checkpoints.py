"""Reference checkpoints: the shipped ones load and hold their keys; a run uses one when (and
only when) its key matches, records where the weights came from, and --retrain trains instead."""

from __future__ import annotations

import json
import shutil

import pandas as pd
import pytest
from conftest import SMALL_IGR, TINY

from shapebench.train import references as refs

RUN = (
    "run",
    "-m",
    "igr",
    "-d",
    "synthetic",
    *TINY,
    *SMALL_IGR,
    "--split",
    "novel",
    "--contexts",
    "50",
    "-q",
)


def _shipped() -> list[refs.Reference]:
    found = []
    for info in sorted(refs.SHIPPED.glob("*/*/" + refs.INFO_FILE)):
        ref = refs.find(info.parent.parent.name, info.parent.name)
        assert ref is not None, f"{info.parent} is not a valid reference folder"
        found.append(ref)
    return found


def test_shipped_references_load_and_hold_their_keys():
    from shapebench.registry.discovery import get_registry
    from shapebench.train.checkpoints import load_module, verify_checkpoint

    shipped = _shipped()
    assert shipped, "shapebench ships no reference checkpoint"
    registry = get_registry()
    for ref in shipped:
        assert refs.file_sha256(ref.checkpoint) == ref.info["sha256"], ref.checkpoint
        verify_checkpoint(ref.checkpoint, ref.folder.name)  # the key stamped in the weights
        method = registry.get("method", ref.info["method"])
        module = load_module(method.load()(None).Module, ref.checkpoint)
        assert sum(p.numel() for p in module.parameters()) > 0
        assert ref.info["command"].startswith("shapebench train")
        assert ref.info["summary"]["wall_seconds"] > 0 and ref.info["versions"]["torch"]


#: The trainable methods whose default-profile (standard) training on the synthetic benchmark
#: ships: every trainable method of configs/sweeps/default.yaml but those whose fit no trainer
#: setting changes (``fit_ignores_trainer``: retrieval's index, which a run builds from the
#: prepared data in half a minute); the test below covers every profile's references.
SHIPPED_METHODS = (
    "igr",
    "deepsdf",
    "msc",
    "msc-noopt",
    "occnet",
    "pcn",
    "convonet",
    "msc-hier",
    "msc-hier-noopt",
    "pointr",
)


@pytest.mark.parametrize("name", SHIPPED_METHODS)
def test_the_default_profile_still_resolves_to_a_shipped_reference(name, tmp_path):
    """A change to a shipped method's code, its default options or the synthetic data changes the
    key: the quickstart would then train that method locally (minutes), and the reference would
    no longer be what the tables say. Retrain it (scripts/reference_checkpoints.py) and commit."""
    from shapebench.config import DEFAULT_PROFILE
    from shapebench.train.ticket import find_reference
    from shapebench.train.training import reference_training

    # The real default, not the quick profile the other tests run at (conftest.py).
    training = reference_training(
        name, "synthetic", DEFAULT_PROFILE, 0, tmp_path, tmp_path / "cache"
    )
    method, key = training.method, training.key
    # the lookup a run makes, so a reference it would not use does not count either
    assert find_reference(method, key) is not None, (
        f"{name}'s default-profile key {key} has no shipped reference; retrain it: "
        f"python scripts/reference_checkpoints.py --methods {method.cls.checkpoint_family or name}"
    )


def test_every_shipped_reference_is_still_the_key_of_its_profile_and_seed(tmp_path):
    """Any profile's, any seed's: a reference whose method, profile or data changed since it was
    trained would never be used again (and its numbers would describe code that is gone)."""
    from shapebench.train.training import reference_training

    for ref in _shipped():
        info = ref.info
        key = reference_training(
            info["method"],
            info["dataset"],
            info["profile"],
            info["seed"],
            tmp_path,
            tmp_path / "cache",
            options=info.get("options"),  # a reference of a larger budget, say (-O)
        ).key
        assert key == info["key"] == ref.folder.name, (
            f"{ref.folder}: {info['method']} at profile {info['profile']!r}, seed "
            f"{info['seed']} now has key {key}; retrain it: python "
            f"scripts/reference_checkpoints.py --methods {info['method']} "
            f"--profile {info['profile']} --seeds {info['seed']}"
        )


def test_a_reference_of_other_method_options_has_the_key_of_those_options(tmp_path):
    """scripts/reference_checkpoints.py -O steps=N ships what `shapebench train -O steps=N`
    would train: the options reach the key, and the profile's own values give its key."""
    from shapebench.train.training import reference_training

    def key(**options):
        return reference_training(
            "occnet", "synthetic", "standard", 0, tmp_path, tmp_path / "cache", options=options
        ).key

    default = key()
    assert key(steps=3600) == default  # standard's own budget for OccNet
    assert key(steps=14400) != default
    assert key(steps=14400) == key(steps=14400)


def _make_reference(sb, root) -> refs.Reference:
    """Train the small IGR in a workspace of its own and export it as a reference."""
    trained = sb("train", "-m", "igr", "-d", "synthetic", *TINY, *SMALL_IGR, "-q")
    assert trained.returncode == 0, trained.stderr
    (done,) = (sb.workspace / "checkpoints" / "igr").glob("*/done.json")
    record = json.loads(done.read_text())
    summary = json.loads((done.parent / "summary.json").read_text())
    info = {
        "key": record["key"],
        "method": "igr",
        "command": "shapebench train -m igr",
        "summary": summary,
        "versions": {},
    }
    ref = refs.export(refs.Path(record["path"]), root / "igr" / record["key"], info)
    shutil.rmtree(sb.workspace)
    sb.workspace.mkdir()
    return ref


@pytest.fixture(scope="session")
def small_igr_reference(tmp_path_factory, data_cache) -> refs.Reference:
    """The small IGR trained once (per test process) and exported as a reference: the tests
    below are about using references, not about training."""
    from conftest import Shapebench

    ws = tmp_path_factory.mktemp("reference-training")
    return _make_reference(Shapebench(ws, data_cache), tmp_path_factory.mktemp("refs"))


@pytest.fixture
def with_reference(shapebench, tmp_path, small_igr_reference):
    """The CLI runner, reading references from a folder of its own that holds a copy of the
    small IGR's (a test may damage it)."""
    made = small_igr_reference
    root = tmp_path / "refs"
    shutil.copytree(made.folder.parents[1], root)
    shapebench.extra_env["SHAPEBENCH_REFERENCE_CHECKPOINTS"] = str(root)
    return shapebench, refs.Reference(root / "igr" / made.folder.name, made.info)


#: The tests that use the small IGR's reference run in one worker, which trains it once.
SHARES_THE_REFERENCE = pytest.mark.xdist_group("small-igr-reference")


@pytest.mark.slow
@SHARES_THE_REFERENCE
def test_a_run_uses_the_reference_of_its_key_and_retrain_trains(with_reference):
    sb, ref = with_reference
    used = sb(*RUN)
    assert used.returncode == 0, used.stderr
    assert "using the reference checkpoint" in used.stderr
    assert "no checkpoint for key" not in used.stderr  # nothing trained here
    client = sb.client()
    exp = client.get_experiment_by_name("training/synthetic")
    (training,) = client.search_runs([exp.experiment_id])
    assert training.data.tags["shapebench.reference"] == ref.origin
    assert training.data.metrics["summary/wall_seconds"] == ref.info["summary"]["wall_seconds"]
    (cell,) = sb.cell_runs("synthetic-novel")
    assert cell.data.params["weights"] == ref.origin

    again = sb(*RUN)  # cached: the same cell, not recomputed
    assert again.returncode == 0 and len(sb.cell_runs("synthetic-novel")) == 1

    retrained = sb(*RUN, "--retrain")
    assert retrained.returncode == 0, retrained.stderr
    assert "no checkpoint for key" in retrained.stderr  # it trains
    cells = sb.cell_runs("synthetic-novel")
    assert len(cells) == 2  # another configuration: the weights differ in origin
    assert sb("leaderboard", "-d", "synthetic").returncode == 0
    board = pd.read_csv(sb.workspace / "leaderboards" / "synthetic-novel.csv")
    labels = set(board["label"])
    assert any("weights=local" in str(label) for label in labels), labels
    assert len(labels) == 2


@pytest.mark.slow
@SHARES_THE_REFERENCE
def test_a_reference_of_another_key_or_a_damaged_one_is_not_used(with_reference):
    sb, ref = with_reference
    other = sb(*RUN, "-O", "epochs=3")  # another key: trains
    assert other.returncode == 0, other.stderr
    assert "using the reference" not in other.stderr
    assert "no checkpoint for key" in other.stderr

    ref.checkpoint.write_bytes(ref.checkpoint.read_bytes()[:-10] + b"0123456789")
    damaged = sb(*RUN)
    assert damaged.returncode != 0
    assert "does not match its reference.json" in damaged.stderr
    assert "--retrain" in damaged.stderr and "Traceback" not in damaged.stderr


def test_the_export_script_ships_only_trainings_of_the_clean_tree_it_runs_in():
    import importlib.util

    from conftest import ROOT

    spec = importlib.util.spec_from_file_location(
        "reference_checkpoints_script", ROOT / "scripts" / "reference_checkpoints.py"
    )
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    head = "a" * 40
    clean = {"mlflow.source.git.commit": head, "git.dirty": "False"}
    assert script.provenance_problem(clean, head) is None
    assert "modified tree" in script.provenance_problem({**clean, "git.dirty": "True"}, head)
    assert "trained at bbbbbbbb" in script.provenance_problem(
        {**clean, "mlflow.source.git.commit": "b" * 40}, head
    )
    assert "records no git commit" in script.provenance_problem({}, head)
    assert "commit first" in script.provenance_problem(clean, head + "-dirty")


def test_half_precision_storage_ships_rounded_weights_and_installs_float32(tmp_path):
    """A network too large for a shipped file is stored in float16: the file shrinks, the
    reference records it, and installing gives float32 tensors holding the rounded values."""
    import torch

    from shapebench.train.checkpoints import STAMP, load_safely

    weights = {"layer.weight": torch.randn(256, 256), "steps": torch.tensor(7)}
    last = tmp_path / "last.ckpt"
    torch.save({"state_dict": weights, STAMP: {"key": "k1"}, "optimizer_states": [1]}, last)
    full = refs.export(last, tmp_path / "refs" / "fam" / "k1", {"key": "k1"})
    half = refs.export(last, tmp_path / "half" / "fam" / "k1", {"key": "k1"}, "float16")
    assert full.info["storage"] == "float32" and half.info["storage"] == "float16"
    assert half.info["bytes"] < 0.6 * full.info["bytes"]
    stored = load_safely(half.checkpoint)
    assert stored["state_dict"]["layer.weight"].dtype == torch.float16
    assert stored["state_dict"]["steps"].dtype == torch.int64  # only float32 tensors are rounded
    assert "optimizer_states" not in stored

    installed = load_safely(refs.install(half, tmp_path / "ws"))["state_dict"]
    assert installed["layer.weight"].dtype == torch.float32
    rounded = weights["layer.weight"].half().float()
    assert torch.equal(installed["layer.weight"], rounded)
    assert not torch.equal(rounded, weights["layer.weight"])
    assert torch.equal(installed["steps"], weights["steps"])
    with pytest.raises(ValueError, match="float16"):
        refs.export(last, tmp_path / "bad", {"key": "k1"}, "int8")
