"""Steps per second of shapebench's Lightning training against a bare PyTorch loop.

For each trainable built-in method, the same LightningModule (network, loss, optimiser), the same
training objects and the same batches are stepped two ways in one run:

* ``bare``: a plain loop, ``loss = module.training_step(batch, i); loss.backward();
  opt.step(); opt.zero_grad()`` over the method's own DataLoader, timed after ``--warmup``
  steps;
* ``shapebench``: :func:`shapebench.train.lightning_fit.fit_lightning`, the loop ``shapebench
  train`` runs (Lightning, the seeded data draws, epoch checkpoints, signal handling), timed as
  the difference between a long and a short training divided by the difference in steps, so
  the Trainer's start-up is not counted (it is printed on its own).

It prints seconds per step and steps per second of both, and their ratio (shapebench / bare:
the overhead of Lightning, data and logging; the goal is at most 1.25). Rounds alternate the two
loops (bare, shapebench, bare, ...) so that a change of load hits both; the medians are printed.

    .venv/bin/python benchmarks/bench_training.py [--methods igr,msc] [--steps 60] [--rounds 3]

The training objects are the synthetic dataset's (the profile's scale unless
``--train-per-category``), preprocessed into the usual cache on first use.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

METHODS = ("igr", "deepsdf", "msc", "occnet", "pcn", "convonet", "msc-hier", "pointr")


def _batches(data, device):
    """Batches forever, epoch after epoch, as the DataLoader draws them, on ``device``."""
    epoch = 0
    while True:
        data.start_epoch(epoch)
        for batch in data.train_dataloader():
            yield {k: v.to(device) for k, v in batch.items()}
        epoch += 1


def bare_seconds_per_step(method, data, n_shapes: int, steps: int, warmup: int, device) -> float:
    """The plain loop's wall time per optimiser step, after ``warmup`` untimed steps."""
    import torch

    from shapebench.train.seeding import seed_training

    seed_training(0)
    module = method.build_module(n_shapes).to(device)
    module.train()
    # A bare loop logs nothing. Outside a Trainer, LightningModule.log warns on every call (MSC
    # logs six terms a step), and even an ignored warning costs: that made the bare loop slower
    # than Lightning's (ratios of 0.77 for MSC, 0.89 for DeepSDF before this line).
    module.log = lambda *args, **kwargs: None
    conf = module.configure_optimizers()
    opt = conf["optimizer"] if isinstance(conf, dict) else conf
    batches = _batches(data, device)
    start = 0.0
    for i in range(warmup + steps):
        if i == warmup:
            if device.type == "cuda":
                torch.cuda.synchronize()
            start = time.perf_counter()
        loss = module.training_step(next(batches), i)
        loss.backward()
        opt.step()
        opt.zero_grad(set_to_none=True)
    if device.type == "cuda":
        torch.cuda.synchronize()
    return (time.perf_counter() - start) / steps


def lightning_seconds(method, dataset, data, epochs: int, accelerator: str) -> tuple[float, int]:
    """Wall time and optimiser steps of one ``fit_lightning`` of ``epochs`` epochs."""
    from shapebench.api.method import TrainerOptions, TrainingContext
    from shapebench.train.lightning_fit import fit_lightning
    from shapebench.train.seeding import seed_training

    with tempfile.TemporaryDirectory() as tmp:
        trainer = TrainerOptions(accelerator=accelerator, devices=1, seed=0, max_epochs=epochs)
        ctx = TrainingContext(dataset, trainer, Path(tmp) / "run", "", None, True)
        seed_training(0)
        module = method.build_module(len(data.refs))
        start = time.perf_counter()
        fit_lightning(module, data, ctx, epochs)
        seconds = time.perf_counter() - start
        steps = int(module.trainer.global_step)
    return seconds, steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods")
    parser.add_argument("--steps", type=int, default=60, help="timed optimiser steps per loop")
    parser.add_argument("--warmup", type=int, default=10, help="untimed steps of the bare loop")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds per loop")
    parser.add_argument("--profile", default="quick")
    parser.add_argument("--train-per-category", type=int, default=None)
    parser.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: all)")
    args = parser.parse_args()

    import logging
    import warnings

    import torch

    from shapebench.config import make_settings
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method

    if args.threads:
        torch.set_num_threads(args.threads)
    warnings.filterwarnings("ignore")
    logging.getLogger("pytorch_lightning").setLevel(logging.ERROR)
    device = torch.device(args.device)
    settings = make_settings(None, None, args.profile, None)
    reg = get_registry()
    opts = {}
    if args.train_per_category is not None:
        opts["train_per_category"] = args.train_per_category
    dataset = resolve_dataset(reg, "synthetic", settings, None, opts)
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, device {device}"
        + (f" ({torch.cuda.get_device_name(device)})" if device.type == "cuda" else ""),
        file=sys.stderr,
    )
    print(
        f"{'method':8} {'shapes':>6} {'batch':>5} {'bare s/step':>12} {'shapebench s/step':>18} "
        f"{'bare steps/s':>12} {'shapebench steps/s':>18} {'ratio':>6} {'start-up s':>10}"
    )
    for name in args.methods.split(","):
        method = resolve_method(reg, name, settings).instantiate()
        from shapebench.api.method import TrainerOptions, TrainingContext

        ctx = TrainingContext(dataset, TrainerOptions(seed=0), Path("."), "", None, True)
        data = method.data_module(ctx)
        n_shapes = data.load_objects()
        per_epoch = -(-n_shapes // min(method.options.batch_shapes, n_shapes))
        short_epochs = max(1, -(-args.warmup // per_epoch))
        long_epochs = short_epochs + max(1, -(-args.steps // per_epoch))
        bare, light, startup = [], [], []
        for _ in range(args.rounds):
            bare.append(
                bare_seconds_per_step(method, data, n_shapes, args.steps, args.warmup, device)
            )
            t_short, s_short = lightning_seconds(method, dataset, data, short_epochs, args.device)
            t_long, s_long = lightning_seconds(method, dataset, data, long_epochs, args.device)
            per_step = (t_long - t_short) / (s_long - s_short)
            light.append(per_step)
            startup.append(t_short - s_short * per_step)
        b, lt = statistics.median(bare), statistics.median(light)
        print(
            f"{name:8} {n_shapes:>6} {min(method.options.batch_shapes, n_shapes):>5} "
            f"{b:>12.4f} {lt:>18.4f} {1 / b:>12.2f} {1 / lt:>18.2f} {lt / b:>6.2f} "
            f"{statistics.median(startup):>10.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
