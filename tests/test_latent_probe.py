"""benchmarks/latent_probe.py gives the same numbers on every run: its searches are seeded as
the runner seeds a completion, whatever torch's generator holds before."""

from __future__ import annotations

import pytest
import torch
from conftest import SMALL_IGR, TINY, load_benchmark

pytestmark = pytest.mark.slow  # trains a small IGR, then searches its codes twice


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
