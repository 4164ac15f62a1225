"""benchmarks/latent_probe.py gives the same numbers on every run: its searches are seeded as
the runner seeds a completion, whatever torch's generator holds before."""

from __future__ import annotations

import importlib.util
import sys

import pytest
import torch
from conftest import ROOT, SMALL_IGR, TINY

pytestmark = pytest.mark.slow  # trains a small IGR, then searches its codes twice


def _probe():
    sys.path.insert(0, str(ROOT / "benchmarks"))  # the probe imports ladder.py beside it
    spec = importlib.util.spec_from_file_location("latent_probe", ROOT / "benchmarks" /
                                                  "latent_probe.py")  # fmt: skip
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_probe_searches_are_repeatable(shapebench, data_cache):
    trained = shapebench("train", "-m", "igr", "-d", "synthetic", *TINY, *SMALL_IGR, "-q")
    assert trained.returncode == 0, trained.stderr
    (ckpt,) = (shapebench.workspace / "checkpoints" / "igr").glob("*/last.ckpt")
    argv = ["-m", "igr", "--checkpoint", str(ckpt), "--train-only", "--objects", "3",
            "--contexts", "50", "--steps", "5", "--cache-dir", str(data_cache),
            *TINY, *SMALL_IGR]  # fmt: skip
    probe = _probe()
    first = probe.main(argv)
    torch.manual_seed(12345)  # work before the second run leaves the generator elsewhere
    torch.rand(1000)
    second = probe.main(argv)
    assert [label for label, _, _ in first] == ["search, train obj 5 steps"]
    assert first == second
