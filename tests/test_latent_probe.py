"""benchmarks/latent_probe.py gives the same numbers on every run: its searches are seeded as
the runner seeds a completion, whatever torch's generator holds before; and its validation
objects are neither training nor test objects."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import SMALL_IGR, TINY, load_benchmark

from shapebench.config import make_settings
from shapebench.types import NOVEL, TRAIN, TRAINED


def test_validation_objects_are_held_out_of_every_split(tmp_path):
    from shapebench.registry import get_registry
    from shapebench.resolve import resolve_dataset

    probe = load_benchmark("latent_probe")
    settings = make_settings(f"sqlite:///{tmp_path}/m.db", tmp_path, "quick", tmp_path)
    data = resolve_dataset(get_registry(), "synthetic", settings, None,
                           {"train_per_category": 40, "test_per_category": 40})  # fmt: skip
    val = probe.validation_refs(data, 3)
    ids = {r.id for r in val}
    assert len(ids) == 3 * len({r.category for r in data.objects(TRAINED)})
    assert {r.category for r in val} == {r.category for r in data.objects(TRAINED)}
    for split in (TRAIN, TRAINED, NOVEL):
        assert not ids & {r.id for r in data.objects(split)}, split
    # a held-out object is a different object (its mesh is generated from its id)
    held_out, trained = data.mesh(val[0]), data.mesh(data.objects(TRAIN)[0])
    assert not np.allclose(held_out.vertices[:5], trained.vertices[:5])


def test_saved_rows_are_paired_by_label_and_size(tmp_path, capsys):
    probe = load_benchmark("latent_probe")
    saved = tmp_path / "before.json"
    saved.write_text(json.dumps([{"label": "search, validation 50 steps", "k": 50,
                                  "scores": [3.0, 4.0, 5.0, 6.0, 7.0, 8.0]}]))  # fmt: skip
    now = [("search, validation 50 steps", 50, [1.0, 2.0, 3.0, 4.0, 5.0, 9.0]),
           ("search, validation 50 steps", 1000, [1.0])]  # fmt: skip
    probe.compare_saved(now, saved)
    out = capsys.readouterr().out
    assert "wins 5/6" in out and "5.50 ->     4.00" in out
    assert "1000  not in before.json" in out


@pytest.mark.slow  # trains a small IGR, then searches its codes twice
def test_probe_searches_are_repeatable(shapebench, data_cache):
    trained = shapebench("train", "-m", "igr", "-d", "synthetic", *TINY, *SMALL_IGR, "-q")
    assert trained.returncode == 0, trained.stderr
    (ckpt,) = (shapebench.workspace / "checkpoints" / "igr").glob("*/last.ckpt")
    argv = ["-m", "igr", "--checkpoint", str(ckpt), "--train-only", "--objects", "3",
            "--contexts", "50", "--steps", "5", "--cache-dir", str(data_cache),
            *TINY, *SMALL_IGR]  # fmt: skip
    probe = load_benchmark("latent_probe")
    first = probe.main(argv)
    torch.manual_seed(12345)  # work before the second run leaves the generator elsewhere
    torch.rand(1000)
    second = probe.main(argv)
    assert [label for label, _, _ in first] == ["search, train obj 5 steps"]
    assert first == second
