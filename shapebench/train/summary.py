"""What a finished training cost and where it ended: the summary that
:func:`~shapebench.train.lightning_fit.fit_lightning` reports.

:func:`training_summary` reads it off the Trainer (wall time, device, device-hours, training
shapes, epochs, optimiser steps, the last value of every logged term); :func:`report_summary`
prints it and logs it to the training's MLflow run; :func:`device_count` and
:func:`device_hours` are the arithmetic the leaderboard's cost columns share
(:mod:`shapebench.boards.cost`). Bookkeeping only: nothing here changes what a training computes.

torch and Lightning are imported inside the functions, so that the boards read costs without
them.
"""

from __future__ import annotations

import re
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import pytorch_lightning as pl


def device_count(device: str) -> int:
    """Devices of a ``training_device`` tag (``cpu x1``, ``cuda x4 (NVIDIA H100)``); 1 if none."""
    match = re.search(r"\bx(\d+)", device or "")
    return int(match.group(1)) if match else 1


def device_hours(wall_seconds: float, devices: int) -> float:
    """Devices held times wall time, in hours: what a cluster bills."""
    return float(wall_seconds) * max(int(devices), 1) / 3600.0


#: The last training summary, next to the checkpoint (benchmarks/ladder.py reads it).
SUMMARY_FILE = "summary.json"


def training_summary(trainer: pl.Trainer, seconds: float) -> dict[str, Any]:
    """Wall time, device, epochs, optimiser steps and the last value of every logged term."""
    import torch

    from shapebench.train.data import ShapeDataModule

    device = trainer.strategy.root_device
    kind = f"{device.type} x{trainer.num_devices * trainer.num_nodes}"
    if device.type == "cuda":
        kind += f" ({torch.cuda.get_device_name(device)})"
    terms = {
        k: float(v) for k, v in sorted(trainer.callback_metrics.items()) if k.startswith("train/")
    }

    # Device-hours: every device is held for the whole wall time (what a cluster bills).
    devices = int(trainer.num_devices * trainer.num_nodes)
    data = trainer.datamodule
    return {
        "wall_seconds": seconds,
        "device": kind,
        "devices": devices,
        "device_hours": device_hours(seconds, devices),
        # The training-set size: the x axis of a data-scaling figure.
        "training_shapes": len(data.refs) if isinstance(data, ShapeDataModule) else None,
        "epochs": int(trainer.current_epoch),
        "optimizer_steps": int(trainer.global_step),
        "final": terms,
    }


def report_summary(summary: dict[str, Any], logger: Any | None, quiet: bool = False) -> None:
    """Print the summary to stderr (unless ``quiet``) and log it to the MLflow training run."""
    if not quiet:
        terms = summary["final"].items()
        final = ", ".join(f"{k.removeprefix('train/')} {v:.4g}" for k, v in terms)
        hours = summary.get("device_hours")
        spent = f" ({hours:.3g} device-hours)" if hours is not None else ""
        shapes = summary.get("training_shapes")
        print(
            f"training done in {summary['wall_seconds']:.1f} s on {summary['device']}{spent}: "
            + (f"{shapes} shapes, " if shapes else "")
            + f"{summary['epochs']} epochs, {summary['optimizer_steps']} optimiser steps; "
            f"final {final or 'no logged terms'}",
            file=sys.stderr,
        )
    if logger is None:
        return
    metrics = {
        "summary/wall_seconds": summary["wall_seconds"],
        **({"summary/device_hours": summary["device_hours"]} if "device_hours" in summary else {}),
        "summary/epochs": float(summary["epochs"]),
        "summary/optimizer_steps": float(summary["optimizer_steps"]),
    }
    if summary.get("training_shapes"):
        metrics["summary/training_shapes"] = float(summary["training_shapes"])
    metrics.update(
        {f"summary/final_{k.removeprefix('train/')}": v for k, v in summary["final"].items()}
    )
    from shapebench.store.tracking import log_training_summary

    log_training_summary(logger, metrics, summary["optimizer_steps"], summary["device"])
