"""The Lightning training loop one piece at a time: the data pipeline
(:mod:`shapebench.train.data`), the seeding (:mod:`shapebench.train.seeding`), the fit
(:mod:`shapebench.train.lightning_fit`) with its plan and checkpoint callbacks
(:mod:`shapebench.train.callbacks`), and the resume helpers (:mod:`shapebench.train.checkpoints`).

Everything is the real thing: a handful of small meshes held in memory as a shapebench dataset,
the real data module, and a tiny MSC (its steps draw subsets from the seeded step generator, its
noise from the global one) trained by ``fit_lightning`` on the CPU. The data tests take
milliseconds; each training about a second (marked slow, as every test that trains).
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from shapebench_msc.method import MSC
from tiny_datasets import TINY_MSC, meshes

from shapebench.api.dataset import Dataset, ObjectLoadError
from shapebench.api.errors import CorruptFileWarning, ShapebenchError
from shapebench.api.method import TrainerOptions, TrainingContext
from shapebench.api.types import TRAIN, TRAINED, Category, ObjectData, ObjectRef, Supervision
from shapebench.train.checkpoints import (
    LAST,
    checkpoint_epochs,
    describe_progress,
    kept_message,
    resume_state,
)
from shapebench.train.data import ShapeDataModule
from shapebench.train.seeding import seed_training, step_generator

#: tiny_datasets' four meshes: TINY_MSC takes them in batches of 2, 2 optimiser steps an epoch,
#: 4 in its 2 epochs.
MESHES = meshes()


class _Blobs(Dataset):
    """The meshes above as a dataset's training split, with every kind of supervision (spheres'
    signed distances and occupancies stand in for the shapes': only the arrays' shapes and signs
    matter here). ``broken``: indices of objects whose loading fails."""

    name = "blobs"

    def __init__(self, broken: tuple[int, ...] = ()) -> None:
        super().__init__(None, Path("."))
        self.broken = broken

    def categories(self) -> list[Category]:
        return [Category("blob", TRAINED)]

    def objects(self, split: str) -> list[ObjectRef]:
        if split != TRAIN:
            return []
        return [ObjectRef(f"blob/{i}", "blob") for i in range(len(MESHES))]

    def load(self, ref: ObjectRef, need: frozenset[Supervision] = frozenset()) -> ObjectData:
        i = int(ref.id.split("/")[1])
        if i in self.broken:
            raise ObjectLoadError(f"{ref.id} is broken")
        pts, faces = trimesh.sample.sample_surface(MESHES[i], 500, seed=i)
        normals = MESHES[i].face_normals[faces]
        rng = np.random.default_rng(i)
        extra = {}
        if Supervision.SDF_SAMPLES in need:  # a sphere of radius 0.4
            near = rng.uniform(-0.6, 0.6, (400, 3))
            extra["sdf"] = np.c_[near, np.linalg.norm(near, axis=1) - 0.4].astype(np.float32)
        if Supervision.OCCUPANCY_SAMPLES in need:  # a sphere of radius 0.3: not the SDF's
            box = rng.uniform(-0.6, 0.6, (400, 3))
            extra["occupancy"] = np.c_[box, np.linalg.norm(box, axis=1) < 0.3].astype(np.float32)
        if Supervision.COMPLETE_POINTS in need:
            extra["complete_points"] = pts.astype(np.float32)
        pts = pts.astype(np.float32)
        return ObjectData(ref, pts, normals.astype(np.float32), pts, extra)


# -- the data pipeline ---------------------------------------------------------------------------

ALL = {
    Supervision.SURFACE_POINTS: 64,
    Supervision.SDF_SAMPLES: 32,
    Supervision.OCCUPANCY_SAMPLES: 16,
    Supervision.COMPLETE_POINTS: 48,
}


def _data(
    seed: int = 0, samples=None, batch: int = 3, dataset: Dataset | None = None, **kw
) -> ShapeDataModule:
    samples = ALL if samples is None else samples
    data = ShapeDataModule(
        dataset or _Blobs(), frozenset(samples), samples, batch, seed, True, **kw
    )
    data.load_objects()
    return data


def _epoch(data: ShapeDataModule, epoch: int = 0) -> list[dict[str, torch.Tensor]]:
    loader = data.train_dataloader()
    data.start_epoch(epoch)
    return list(loader)


def _same(a: list[dict], b: list[dict]) -> bool:
    return len(a) == len(b) and all(
        x.keys() == y.keys() and all(torch.equal(x[k], y[k]) for k in x)
        for x, y in zip(a, b, strict=True)
    )


def test_the_batches_hold_every_kind_of_sample_in_the_sizes_asked_for():
    first, last = _epoch(_data())  # 4 objects in batches of 3: the last batch is not dropped
    assert first["index"].shape == (3,) and last["index"].shape == (1,)
    assert sorted(torch.cat([first["index"], last["index"]]).tolist()) == [0, 1, 2, 3]
    assert first["points"].shape == first["normals"].shape == (3, 64, 3)
    assert first["sdf"].shape == (3, 32, 4)
    assert first["occupancy"].shape == (3, 16, 4)
    assert first["complete"].shape == (3, 48, 3)
    # DeepSDF's draw: half of the SDF samples outside, half inside.
    assert (first["sdf"][:, :16, 3] > 0).all() and (first["sdf"][:, 16:, 3] <= 0).all()
    # Every drawn point is one of the object's own.
    objects = _Blobs()
    for row, i in enumerate(first["index"].tolist()):
        own = torch.from_numpy(objects.load(objects.objects(TRAIN)[i]).surface_points)
        assert (first["points"][row][:, None] == own[None]).all(-1).any(-1).all()


def test_without_surface_points_asked_for_a_batch_holds_one_per_object_and_only_what_was_asked():
    (batch,) = _epoch(_data(samples={Supervision.SDF_SAMPLES: 8}, batch=4))
    assert set(batch) == {"index", "points", "normals", "sdf"}
    assert batch["points"].shape == (4, 1, 3) and batch["sdf"].shape == (4, 8, 4)


def test_queries_from_sdf_label_the_sdf_samples_inside_where_the_distance_is_negative():
    samples = {Supervision.SDF_SAMPLES: 0, Supervision.OCCUPANCY_SAMPLES: 64}
    data = _data(samples=samples, batch=4, queries_from_sdf=True)
    (batch,) = _epoch(data)
    assert "sdf" not in batch and batch["occupancy"].shape == (4, 64, 4)
    # Labelled by the SDF's sphere (radius 0.4), not drawn from the dataset's occupancy (0.3).
    radius, inside = batch["occupancy"][..., :3].norm(dim=-1), batch["occupancy"][..., 3] == 1
    clear = (radius - 0.4).abs() > 1e-4
    assert torch.equal(inside[clear], radius[clear] < 0.4) and (inside & (radius > 0.3)).any()


def test_a_broken_training_object_is_skipped_and_none_loadable_is_an_error():
    data = _data(dataset=_Blobs(broken=(1,)))
    assert [r.id for r in data.refs] == ["blob/0", "blob/2", "blob/3"]
    assert sorted(torch.cat([b["index"] for b in _epoch(data)]).tolist()) == [0, 1, 2]
    with pytest.raises(ShapebenchError, match="no training object of 'blobs' could be loaded"):
        _data(dataset=_Blobs(broken=(0, 1, 2, 3)))


def test_the_same_seed_draws_the_same_batches_and_another_seed_or_epoch_others():
    seed3 = _epoch(_data(seed=3))
    assert _same(seed3, _epoch(_data(seed=3)))
    assert not _same(seed3, _epoch(_data(seed=4)))
    data = _data(seed=3)
    epoch1 = _epoch(data, epoch=1)
    assert not _same(seed3, epoch1)
    # The draws are a function of (seed, epoch), not of what was drawn before.
    assert _same(seed3, _epoch(data, epoch=0)) and _same(epoch1, _epoch(data, epoch=1))


def test_an_objects_draws_do_not_depend_on_the_batch_size():
    def by_object(batches):
        return {int(i): b["points"][row] for b in batches for row, i in enumerate(b["index"])}

    one, four = by_object(_epoch(_data(seed=2, batch=1))), by_object(_epoch(_data(seed=2, batch=4)))
    assert one.keys() == four.keys() and all(torch.equal(one[i], four[i]) for i in one)


# -- seeding -------------------------------------------------------------------------------------


def test_seeding_gives_the_same_initial_weights_and_step_draws_for_the_same_seed():
    method = MSC(MSC.Options(**TINY_MSC))

    def start(seed: int) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        seed_training(seed)
        module = method.build_module(4)
        # Outside a fit, a module's step generator is seeded from torch's global seed.
        return module.state_dict(), torch.rand(5, generator=step_generator(module))

    (w3, d3), (again, d3b), (w4, d4) = start(3), start(3), start(4)
    assert all(torch.equal(w3[k], again[k]) for k in w3) and torch.equal(d3, d3b)
    assert not all(torch.equal(w3[k], w4[k]) for k in w3) and not torch.equal(d3, d4)


# -- the fit -------------------------------------------------------------------------------------


def _fit(
    workdir: Path, seed: int = 3, quiet: bool = True, **trainer: object
) -> dict[str, torch.Tensor]:
    """The tiny MSC trained by ``fit_lightning`` in ``workdir``; its saved weights and step."""
    options = TrainerOptions(accelerator="cpu", devices=1, seed=seed, **trainer)
    ctx = TrainingContext(_Blobs(), options, workdir, "", None, quiet)
    path = MSC(MSC.Options(**TINY_MSC)).fit(ctx)
    assert path == workdir / LAST
    state = torch.load(path, map_location="cpu", weights_only=True)
    return {"global_step": torch.tensor(state["global_step"]), **state["state_dict"]}


def _same_weights(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


@pytest.fixture(scope="module")
def straight(tmp_path_factory) -> dict[str, torch.Tensor]:
    """Two uninterrupted epochs (4 optimiser steps) at seed 3."""
    return _fit(tmp_path_factory.mktemp("straight") / "run")


@pytest.mark.slow
def test_the_same_seed_trains_the_same_weights_and_another_seed_others(straight, tmp_path):
    torch.rand(100)  # the global generators' state before a training must not matter
    assert int(straight["global_step"]) == 4
    assert _same_weights(straight, _fit(tmp_path / "again"))
    assert not _same_weights(straight, _fit(tmp_path / "other", seed=4))


@pytest.mark.slow
def test_a_stopped_training_resumes_from_its_checkpoint_to_the_uninterrupted_weights(
    straight, tmp_path, capsys
):
    """Stopped after its first epoch (``--max-epochs 1``), then run again: it resumes from
    ``last.ckpt`` and ends bitwise where the uninterrupted training ends. (A stop mid-epoch, by a
    signal, is tests/train/test_interruptions.py's.)"""
    run = tmp_path / "run"
    first = _fit(run, max_epochs=1)
    assert int(first["global_step"]) == 2 and not _same_weights(first, straight)
    capsys.readouterr()
    resumed = _fit(run, quiet=False)
    err = capsys.readouterr().err
    assert f"resuming from {run / LAST} (1 epochs done, optimiser step 2)" in err
    assert "resuming at step 2" in err  # the plan says where it resumes
    assert _same_weights(resumed, straight)


@pytest.mark.slow
def test_the_plan_and_the_summary_report_the_shapes_and_the_steps(tmp_path, capsys):
    _fit(tmp_path / "run", quiet=False)
    err = capsys.readouterr().err
    assert (
        "training plan: 4 shapes, 4 optimiser steps (2 epochs x 2 batches of 2 shapes per "
        "device), on cpu x1\n" in err
    )
    # The first step pays for start-up: the other three are timed, and the last is left.
    assert re.search(r"s per optimiser step over 2 steps; about \d+ s for the 1 step left", err)
    assert "training done in" in err and "4 shapes, 2 epochs, 4 optimiser steps" in err
    _fit(tmp_path / "steps", quiet=False, max_steps=3)
    err = capsys.readouterr().err
    assert "4 shapes, 3 optimiser steps (about 2 epochs of 2 batches of 2 shapes" in err


# -- resuming: the helpers on a real checkpoint --------------------------------------------------


@pytest.mark.slow
def test_the_resume_helpers_read_a_real_checkpoint(tmp_path):
    run = tmp_path / "run"
    _fit(run, max_epochs=1)  # one epoch of 2 optimiser steps
    last = run / LAST
    assert checkpoint_epochs(last) == 1
    state = resume_state(last, "run")
    assert describe_progress(state) == "1 epochs done, optimiser step 2"
    assert (
        kept_message(last) == f"its checkpoint (1 epochs done, optimiser step 2) is kept at {last}"
    )
    assert resume_state(run / "absent.ckpt", "run") is None
    assert kept_message(run / "absent.ckpt") == "nothing was saved yet"
    # Another key's checkpoint is refused, naming both keys.
    with pytest.raises(ShapebenchError, match="trained under checkpoint key run.*key other"):
        resume_state(last, "other")
    # A damaged checkpoint is reported, deleted, and the training starts over.
    data = last.read_bytes()
    last.write_bytes(data[: len(data) // 2])
    assert checkpoint_epochs(last) is None and kept_message(last) == f"{last} is unreadable"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert resume_state(last, "run") is None
    assert any(issubclass(w.category, CorruptFileWarning) for w in caught)
    assert not last.exists()
