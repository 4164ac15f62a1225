"""Time the training Chamfer of PCN and PoinTr, forward and backward, two ways in one run.

    python benchmarks/bench_chamfer_loss.py [--rounds 5] [--threads N]

``shapebench.train.losses.chamfer_l1_halved`` finds each point's nearest neighbour without
gradient (an exact KD-tree per set on the CPU) and differentiates the chosen pairs only. The
baseline is the loss as it was computed until 2026-11-29: the whole (B, N, M) ``torch.cdist``
matrix, differentiated through ``min``. Both run on the same random sets, alternating in rounds,
at the sizes the profiles train with: PCN standard (8 x 4,096 outputs against 4,096 target
points), PCN quick (8 x 1,024 against 1,024), PoinTr quick's dense output (8 x 2,048 against
2,048). It prints the medians of forward + backward, the ratio baseline / shapebench, and the
largest difference of the losses and of the gradients (they must agree: a fast wrong loss is no
use).
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import torch

from shapebench.train.losses import chamfer_l1_halved

SIZES = {
    "PCN standard (8 x 4096 / 4096)": (8, 4096, 4096),
    "PCN quick (8 x 1024 / 1024)": (8, 1024, 1024),
    "PoinTr quick (8 x 2048 / 2048)": (8, 2048, 2048),
}


def through_cdist(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The baseline: the whole distance matrix, differentiated through ``min``."""
    d = torch.cdist(a, b)
    return 0.5 * (d.min(dim=2).values.mean(dim=1) + d.min(dim=1).values.mean(dim=1))


def step(
    loss: Callable, a0: torch.Tensor, b: torch.Tensor
) -> tuple[float, torch.Tensor, torch.Tensor]:
    a = a0.clone().requires_grad_()
    start = time.perf_counter()
    value = loss(a, b).mean()
    value.backward()
    return time.perf_counter() - start, value.detach(), a.grad


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=5, help="timed rounds (after one untimed)")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: all)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, {args.rounds} rounds")
    print(
        f"{'sizes':34} {'cdist s':>9} {'shapebench s':>13} {'ratio':>7}"
        f" {'loss diff':>10} {'grad diff':>10}"
    )
    for name, (batch, n, m) in SIZES.items():
        g = torch.Generator().manual_seed(0)
        a0, b = torch.rand(batch, n, 3, generator=g), torch.rand(batch, m, 3, generator=g)
        times: dict[str, list[float]] = {"cdist": [], "shapebench": []}
        for r in range(args.rounds + 1):
            t_old, v_old, g_old = step(through_cdist, a0, b)
            t_new, v_new, g_new = step(chamfer_l1_halved, a0, b)
            if r:  # the first round warms both up
                times["cdist"].append(t_old)
                times["shapebench"].append(t_new)
        old, new = statistics.median(times["cdist"]), statistics.median(times["shapebench"])
        loss_diff = (v_old - v_new).abs().item()
        grad_diff = (g_old - g_new).abs().max().item()
        print(
            f"{name:34} {old:9.4f} {new:13.4f} {old / new:6.1f}x"
            f" {loss_diff:10.1e} {grad_diff:10.1e}"
        )


if __name__ == "__main__":
    main()
