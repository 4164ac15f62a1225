"""benchmarks/latent_probe.py gives the same numbers on every run: its searches are seeded as
the runner seeds a completion, whatever torch's generator holds before; and its validation
objects are neither training nor test objects."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import SMALL_IGR, TINY, load_benchmark

from shapebench.api.types import NOVEL, TRAIN, TRAINED
from shapebench.config import make_settings


def test_validation_objects_are_held_out_of_every_split(tmp_path):
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset

    probe = load_benchmark("latent_probe")
    settings = make_settings(f"sqlite:///{tmp_path}/m.db", tmp_path, "quick", tmp_path)
    data = resolve_dataset(
        get_registry(),
        "synthetic",
        settings,
        None,
        {"train_per_category": 40, "test_per_category": 0},
    )
    val = probe.validation_refs(data, 3)
    trained = {c.name for c in data.categories() if c.split == TRAINED}
    assert len({r.id for r in val}) == 3 * len(trained) and {r.category for r in val} == trained
    for split in (TRAIN, TRAINED, NOVEL):
        assert not {r.id for r in val} & {r.id for r in data.objects(split)}, split
    # a held-out object is another object than the training object of the same index
    for ref in val[::3][:4]:
        held_out = data.mesh(ref).vertices
        twin = data.mesh(type(ref)(ref.id.replace("/val-", "/train-"), ref.category)).vertices
        assert held_out.shape != twin.shape or not np.allclose(held_out, twin), ref.id


def test_saved_rows_are_paired_only_with_the_same_objects_and_contexts(tmp_path, capsys):
    probe = load_benchmark("latent_probe")
    label, ids = "search, validation 50 steps", [f"chair/val-{i:03d}" for i in range(6)]
    meta = {"seed": 0, "data": "abc"}
    saved = tmp_path / "before.json"
    before = [(label, 50, [3.0, 4.0, 5.0, 6.0, 7.0, float("nan")]), (label, 100, [1.0] * 6)]
    probe.save_rows(saved, before, {(label, 50): ids, (label, 100): ids}, meta)
    back = json.loads(saved.read_text())  # strict JSON: a failed object is null
    assert back["rows"][0]["scores"][-1] is None and back["seed"] == 0
    now = [(label, 50, [1.0, 2.0, 3.0, 4.0, 9.0, 2.0]), (label, 100, [1.0] * 6)]
    probe.compare_saved(now, {(label, 50): ids, (label, 100): ids[::-1]}, meta, back, "b.json")
    out = capsys.readouterr().out
    assert "wins 4/5" in out and "5.00 ->     3.80" in out and "failed 1 -> 0" in out
    assert "100  not in b.json (or other objects)" in out  # same label, other objects
    with pytest.raises(SystemExit, match="other seed"):
        probe.compare_saved(now, {(label, 50): ids}, {**meta, "seed": 1}, back, "b.json")


def test_objective_line_counts_the_objects_the_objective_ranks_wrongly():
    probe = load_benchmark("latent_probe")
    target = torch.tensor([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])

    def loss(z: torch.Tensor) -> torch.Tensor:  # one value per object, plus a seeded draw
        return ((z - target) ** 2).sum(1) + torch.rand(1)

    own = target + torch.tensor([[0.5, 0.0], [0.0, 0.0], [0.5, 0.5]])
    found = target + torch.tensor([[0.1, 0.0], [0.3, 0.0], [0.0, 0.0]])
    # found is lower on objects 0 and 2; object 0's completion is worse, 2's is better
    line = probe.objective_line(loss, own, found, [1.0, 1.0, 5.0], [3.0, 0.5, 2.0])
    assert "found lower on 2/3 objects, 1 of them completed worse" in line
    # both codes see the same draws, so the draw cancels in the comparison
    at_own, at_found = probe.objective_at(loss, own), probe.objective_at(loss, found)
    assert np.allclose(at_own - at_found, [0.24, -0.09, 0.5], atol=1e-6)


@pytest.mark.slow  # trains a small IGR, then searches its codes twice
def test_probe_searches_are_repeatable(shapebench, data_cache):
    trained = shapebench("train", "-m", "igr", "-d", "synthetic", *TINY, *SMALL_IGR, "-q")
    assert trained.returncode == 0, trained.stderr
    (ckpt,) = (shapebench.workspace / "checkpoints" / "igr").glob("*/last.ckpt")
    argv = [
        "-m",
        "igr",
        "--checkpoint",
        str(ckpt),
        "--train-only",
        "--objects",
        "3",
        "--contexts",
        "50",
        "--steps",
        "5",
        "--cache-dir",
        str(data_cache),
        *TINY,
        *SMALL_IGR,
    ]
    probe = load_benchmark("latent_probe")
    first = probe.main(argv)
    torch.manual_seed(12345)  # work before the second run leaves the generator elsewhere
    torch.rand(1000)
    second = probe.main(argv)
    assert [label for label, _, _ in first] == ["search, train obj 5 steps"]
    assert first == second
