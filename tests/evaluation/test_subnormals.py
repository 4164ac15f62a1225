"""Completions run with subnormal floats flushed to zero, and leave the flag as they found it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from shapebench.api.method import Method
from shapebench.api.types import Completion, Context, ObjectRef
from shapebench.evaluation.completion import complete_chunk, subnormals_flushed

TINY = 1e-39  # a float32 subnormal


def flushing() -> bool:
    return (torch.tensor([TINY]) * 1.0).item() == 0.0


needs_ftz = pytest.mark.skipif(
    not torch.set_flush_denormal(False), reason="this CPU cannot flush subnormals (no SSE3)"
)


class Probe(Method):
    """Records whether subnormals were flushed while it completed."""

    display_name = "probe"
    seen: list[bool] = []

    def complete(self, context: Context, n_points: int) -> Completion:
        Probe.seen.append(flushing())
        return Completion(np.zeros((n_points, 3), dtype=np.float32))


@needs_ftz
@pytest.mark.parametrize("before", [False, True])
def test_a_completion_runs_flushed_and_the_flag_is_restored(before: bool) -> None:
    torch.set_flush_denormal(before)
    try:
        Probe.seen = []
        ctx = Context(ObjectRef("chair/test-000", "chair"), np.zeros((5, 3), np.float32), None, 0)
        outputs, _ = complete_chunk(Probe(), [ctx, ctx], 8)
        assert [o.points.shape for o in outputs] == [(8, 3), (8, 3)]
        assert Probe.seen == [True, True]
        assert flushing() is before
    finally:
        torch.set_flush_denormal(False)


@needs_ftz
def test_the_flag_is_restored_when_the_completion_raises() -> None:
    with pytest.raises(RuntimeError), subnormals_flushed():
        assert flushing()
        raise RuntimeError("a failed batch")
    assert not flushing()


def test_softplus_of_the_implicit_decoders_is_bitwise_the_same_flushed() -> None:
    """The activation the flush is for: outputs below the smallest normal float are zero either
    way after the next layer's sums; the values themselves agree wherever they are normal."""
    x = torch.linspace(-3, 3, 20001)
    softplus = torch.nn.Softplus(beta=100)
    plain = softplus(x)
    with subnormals_flushed():
        flushed = softplus(x)
    normal = plain.abs() >= torch.finfo(torch.float32).tiny
    assert torch.equal(plain[normal], flushed[normal])
    assert (flushed[~normal] == 0).all()
