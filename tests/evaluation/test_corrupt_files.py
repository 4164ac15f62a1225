"""Damaged files: a truncated or garbled cache, context order or checkpoint is detected, reported
in one line naming it, and rebuilt (caches) or refused (checkpoints), never a traceback and never
a silently wrong result. Checkpoints are read with ``weights_only=True``: a pickled payload is
refused without running, and a checkpoint of another configuration is refused naming both keys.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import TINY
from shapebench_msc.method import MSC
from shapebench_synthetic.dataset import SyntheticDataset, SyntheticOptions
from tiny_datasets import TINY_MSC, Shapes, meshes

from shapebench.api.contexts import CONTEXTS_VERSION, ContextStore
from shapebench.api.errors import ShapebenchError
from shapebench.api.method import TrainerOptions, TrainingContext
from shapebench.api.types import TRAINED, ObjectData, ObjectRef
from shapebench.train.checkpoints import (
    CorruptFileWarning,
    checkpoint_is_readable,
    key_of,
    verify_checkpoint,
)

SMALL = SyntheticOptions(
    test_per_category=1, train_per_category=1, surface_candidates=2000, gt_points=1000
)


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _flip_in_member(path: Path, member: str, at: int = 8) -> None:
    """Flip one bit ``at`` bytes into the stored data of a zip member: a garbled file whose
    size and structure are intact, as a bad disk sector leaves it."""
    data = bytearray(path.read_bytes())
    info = zipfile.ZipFile(path).getinfo(member)
    start = info.header_offset  # local header: 30 bytes, then the name and the extra field
    name_len, extra_len = struct.unpack("<HH", data[start + 26 : start + 30])
    data[start + 30 + name_len + extra_len + at] ^= 0x40
    path.write_bytes(bytes(data))


def _one_line(exc: ShapebenchError, *needles: str) -> None:
    assert "\n" not in exc.message, exc.message
    for needle in needles:
        assert needle in exc.message, exc.message


# ------------------------------------------------------------------------------ cached arrays


@pytest.mark.parametrize("damage", ["truncated", "garbled"])
def test_a_damaged_cache_npz_is_reported_and_rebuilt_identically(tmp_path, damage):
    ds = SyntheticDataset(SMALL, tmp_path)
    ref = ds.objects(TRAINED)[0]
    before = ds.load(ref)
    path = ds.cache_path(ref)
    if damage == "truncated":
        _truncate(path)
    else:  # same size, one bit off in the middle of the points: only the CRC-32 tells
        _flip_in_member(path, "surface_points.npy", at=400)
    with pytest.warns(CorruptFileWarning, match=f"{path.name} is damaged") as caught:
        after = SyntheticDataset(SMALL, tmp_path).load(ref)
    assert str(path) in str(caught[0].message) and "\n" not in str(caught[0].message)
    for name in ("surface_points", "surface_normals", "gt_points"):
        np.testing.assert_array_equal(getattr(after, name), getattr(before, name))
    with np.load(path) as z:  # the rebuilt file is whole again
        np.testing.assert_array_equal(z["surface_points"], before.surface_points)


# ----------------------------------------------------------------------------- context orders


def _object(n: int = 3000) -> ObjectData:
    pts = np.random.default_rng(0).normal(size=(n, 3)).astype(np.float32)
    return ObjectData(ObjectRef("cat/obj-1", "cat"), pts, pts, pts)


@pytest.mark.parametrize("damage", ["truncated", "garbled", "empty"])
def test_a_damaged_context_order_is_reported_and_drawn_again_identically(tmp_path, damage):
    data = _object()
    store = ContextStore(tmp_path, "fp")
    original = store.order(data).copy()
    path = tmp_path / CONTEXTS_VERSION / "cat__obj-1.npy"
    if damage == "truncated":
        _truncate(path)
    elif damage == "garbled":  # right length, but one index repeated and another lost
        order = np.load(path)
        order[10] = order[11]
        np.save(path, order)
    else:
        path.write_bytes(b"")
    with pytest.warns(CorruptFileWarning, match=f"{path.name} is damaged") as caught:
        again = ContextStore(tmp_path, "fp").order(data)
    assert str(path) in str(caught[0].message)
    np.testing.assert_array_equal(again, original)
    np.testing.assert_array_equal(np.load(path), original)  # stored whole again


# -------------------------------------------------------------------------------- checkpoints


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """One epoch of a tiny MSC, saved by a Trainer that stamps the checkpoint key ``key-a``."""
    # fit_lightning stamps the name of the training's folder (the checkpoint key) into it.
    workdir = tmp_path_factory.mktemp("ckpt") / "key-a"
    trainer_opts = TrainerOptions(accelerator="cpu", devices=1, seed=0)
    method = MSC(MSC.Options(**{**TINY_MSC, "epochs": 1}))
    method.fit(TrainingContext(Shapes(meshes()), trainer_opts, workdir, "", None, True))
    return workdir / "last.ckpt"


def _msc() -> MSC:
    return MSC(MSC.Options(**TINY_MSC))


def test_a_good_checkpoint_loads_with_its_weights(checkpoint):
    method = _msc()
    method.load_checkpoint(checkpoint)
    saved = torch.load(checkpoint, map_location="cpu", weights_only=True)["state_dict"]
    loaded = {k: v.cpu() for k, v in method.module.state_dict().items()}
    assert loaded.keys() == saved.keys()
    assert all(torch.equal(loaded[k], saved[k]) for k in saved)
    assert not method.module.training
    assert checkpoint_is_readable(checkpoint) is None


class _Payload:
    """Unpickling it creates ``marker``: what a malicious checkpoint would do."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch '{self.marker}'",))


def test_a_pickle_payload_is_refused_without_running(tmp_path, checkpoint):
    evil = tmp_path / "evil.ckpt"
    marker = tmp_path / "pwned"
    payload = torch.load(checkpoint, map_location="cpu", weights_only=True)
    payload["hyper_parameters"]["extra"] = _Payload(marker)
    torch.save(payload, evil)
    with pytest.raises(ShapebenchError) as err:
        _msc().load_checkpoint(evil)  # the path `--checkpoint PATH` takes
    _one_line(err.value, str(evil), "posix.system", "could run any code")
    assert not marker.exists()
    # The payload is real: an unrestricted load would have run it.
    torch.load(evil, map_location="cpu", weights_only=False)
    assert marker.exists()


@pytest.mark.parametrize("damage", ["truncated", "garbled", "empty"])
def test_a_damaged_checkpoint_is_one_line_naming_it(tmp_path, checkpoint, damage):
    path = tmp_path / "last.ckpt"
    shutil.copy(checkpoint, path)
    if damage == "truncated":
        _truncate(path)
    elif damage == "garbled":  # one bit of a weight: torch.load alone would load it silently
        tensors = [i for i in zipfile.ZipFile(path).infolist() if "/data/" in i.filename]
        _flip_in_member(path, max(tensors, key=lambda i: i.file_size).filename)
    else:
        path.write_bytes(b"")
    with pytest.raises(ShapebenchError) as err:
        _msc().load_checkpoint(path)
    _one_line(err.value, f"checkpoint {path} is damaged")
    assert "copy or download the file again" in err.value.hint  # a user's file: keep its folder
    assert checkpoint_is_readable(path) == err.value.message
    # One that shapebench trained (done.json beside it) is retrained by deleting its folder.
    (tmp_path / "done.json").write_text(json.dumps({"key": "key-a", "path": str(path)}))
    with pytest.raises(ShapebenchError) as err:
        _msc().load_checkpoint(path)
    assert f"delete {tmp_path} and rerun" in err.value.hint


def test_a_checkpoint_of_another_configuration_is_refused_naming_both_keys(tmp_path, checkpoint):
    assert key_of(checkpoint) == "key-a"
    verify_checkpoint(checkpoint, "key-a")
    with pytest.raises(ShapebenchError) as err:
        verify_checkpoint(checkpoint, "key-b")
    _one_line(err.value, str(checkpoint), "key-a", "key-b")
    # A checkpoint trained before keys were stamped: done.json beside it says which key.
    old = tmp_path / "old" / "last.ckpt"
    old.parent.mkdir()
    unstamped = torch.load(checkpoint, map_location="cpu", weights_only=True)
    del unstamped["shapebench"]
    torch.save(unstamped, old)
    (old.parent / "done.json").write_text(json.dumps({"key": "key-old", "path": str(old)}))
    with pytest.raises(ShapebenchError) as err:
        verify_checkpoint(old, "key-b")
    _one_line(err.value, "key-old", "key-b")
    (old.parent / "done.json").unlink()
    with pytest.raises(ShapebenchError, match="no checkpoint key"):
        verify_checkpoint(old, "key-b")


def test_a_checkpoint_of_another_model_is_one_line(tmp_path, checkpoint):
    from shapebench_igr.method import IGR

    with pytest.raises(ShapebenchError) as err:
        IGR(IGR.Options()).load_checkpoint(checkpoint)
    _one_line(err.value, str(checkpoint), "does not fit IGRModule")


@pytest.mark.slow
def test_run_with_a_pickle_payload_checkpoint_is_one_clean_error(shapebench, tmp_path, checkpoint):
    """The whole ``--checkpoint PATH`` path, as a user runs it: exit status 2, no traceback."""
    evil = tmp_path / "evil.ckpt"
    marker = tmp_path / "pwned"
    payload = torch.load(checkpoint, map_location="cpu", weights_only=True)
    payload["extra"] = _Payload(marker)
    torch.save(payload, evil)
    res = shapebench(
        "run",
        "-m",
        "msc",
        "-d",
        "synthetic",
        *TINY,
        "--split",
        "novel",
        "--contexts",
        "50",
        "--checkpoint",
        str(evil),
    )
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert "Traceback" not in res.stderr
    assert f"Error: checkpoint {evil} holds Python objects" in res.stderr
    assert not marker.exists()


@pytest.mark.parametrize("name", ["deepsdf", "igr", "msc", "occnet", "pcn"])
def test_every_trainable_method_saves_only_what_weights_only_loads(tmp_path, name):
    """Hyper-parameters are plain values: a checkpoint of each built-in module loads with
    ``weights_only=True`` into the same weights (a dataclass or numpy value would be refused)."""
    from shapebench.registry.discovery import get_registry

    cls = get_registry().load("method", name)
    method = cls(cls.Options())
    module = method.build_module(3)
    path = tmp_path / "last.ckpt"
    torch.save({"hyper_parameters": dict(module.hparams), "state_dict": module.state_dict()}, path)
    method.load_checkpoint(path)
    loaded = method.module.state_dict()
    assert all(torch.equal(loaded[k].cpu(), v) for k, v in module.state_dict().items())
