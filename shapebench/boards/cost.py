"""What a leaderboard row costs: training (wall time, device, device-hours, epochs, optimiser
steps, training shapes, final loss) and evaluation (seconds per object at test time).

Training costs are read from the MLflow training run each cell names (tag ``training_run_id``),
where :func:`shapebench.train.summary.report_summary` logged them (``summary/*`` metrics, tag
``training_device``); evaluation seconds from the per-object tables (column ``seconds``: the
wall time of the method's ``complete_batch`` call divided by the objects in it).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pandas as pd

from shapebench.store.records import REFERENCE_TAG, TRAINING_DEVICE_TAG
from shapebench.store.tracking import Tracker
from shapebench.train.summary import device_count, device_hours

#: Columns :func:`row_costs` returns, besides ``variant``.
COST_COLUMNS = [
    "seconds_per_object",
    "train_device_hours",
    "train_wall_seconds",
    "train_device",
    "train_epochs",
    "train_steps",
    "train_shapes",
    "train_final_loss",
    "train_weights",
    "trainings",
]


@dataclass
class TrainingCost:
    """One training run's cost, as logged at its end."""

    run_id: str
    wall_seconds: float = math.nan
    device: str = ""
    device_hours: float = math.nan
    epochs: float = math.nan
    steps: float = math.nan
    #: Training objects (logged since trainings record it; NaN before).
    shapes: float = math.nan
    final_loss: float = math.nan
    #: "reference" (shipped weights, see shapebench.train.references) or "local".
    weights: str = "local"

    @classmethod
    def from_run(cls, run_id: str, metrics: dict[str, float], tags: dict[str, str]) -> TrainingCost:
        """The cost a training run logged (its ``summary/*`` metrics and device tag)."""
        device = tags.get(TRAINING_DEVICE_TAG, "")
        wall = float(metrics.get("summary/wall_seconds", math.nan))
        # Trainings logged before device-hours were recorded: derive them from the device tag.
        hours = metrics.get("summary/device_hours", device_hours(wall, device_count(device)))
        return cls(
            run_id,
            wall,
            device,
            float(hours),
            float(metrics.get("summary/epochs", math.nan)),
            float(metrics.get("summary/optimizer_steps", math.nan)),
            float(metrics.get("summary/training_shapes", math.nan)),
            float(metrics.get("summary/final_loss", math.nan)),
            "reference" if tags.get(REFERENCE_TAG) else "local",
        )


def training_costs(tracker: Tracker, run_ids: list[str]) -> dict[str, TrainingCost]:
    """The cost of each training run that still exists (a deleted one, or one in another store
    after a merge, has no cost to show and is left out)."""
    out: dict[str, TrainingCost] = {}
    for run_id in sorted({r for r in run_ids if r}):
        found = tracker.run_summary(run_id)
        if found is not None:
            out[run_id] = TrainingCost.from_run(run_id, *found)
    return out


def row_costs(tracker: Tracker, runs: pd.DataFrame, per_object: pd.DataFrame) -> pd.DataFrame:
    """Per variant: test-time seconds per successfully completed object (over all its cells),
    and the mean cost of its trainings (one per seed; NaN for methods that do not train)."""
    ok = per_object[per_object["status"] == "ok"]
    seconds = ok.groupby("variant")["seconds"].mean() if "seconds" in ok else pd.Series(dtype=float)
    ids = runs.get("training_run_id", pd.Series("", index=runs.index)).fillna("")
    costs = training_costs(tracker, ids.tolist())
    rows = []
    for variant, g in runs.assign(_tr=ids).groupby("variant_key"):
        trained = [costs[r] for r in sorted(set(g["_tr"])) if r in costs]
        row: dict[str, Any] = {
            "variant": variant,
            "seconds_per_object": float(seconds.get(variant, math.nan)),
            "trainings": len(trained),
        }
        if trained:
            table = pd.DataFrame([asdict(c) for c in trained])
            row.update(
                train_device_hours=float(table["device_hours"].mean()),
                train_wall_seconds=float(table["wall_seconds"].mean()),
                train_device=", ".join(sorted(set(table["device"]) - {""})),
                train_epochs=float(table["epochs"].mean()),
                train_steps=float(table["steps"].mean()),
                train_shapes=float(table["shapes"].mean()),
                train_final_loss=float(table["final_loss"].mean()),
                train_weights=", ".join(sorted(set(table["weights"]))),
            )
        rows.append(row)
    out = pd.DataFrame(rows, columns=["variant", *COST_COLUMNS])
    for column in ("train_device", "train_weights"):
        out[column] = out[column].astype(object).fillna("")
    return out


def describe_training(cost: pd.Series | dict, hours: bool = True) -> str:
    """``0.05 device-h (181 s on cpu x1), 900 steps (100 epochs), loss 0.0216`` (without the
    device-hours when ``hours`` is false; ``, reference weights`` when the weights were shipped),
    or ``–`` when it did not train (or its training run is gone)."""
    dh = cost.get("train_device_hours", math.nan)
    if dh is None or not np.isfinite(dh):
        return "–"
    where = f"{cost['train_wall_seconds']:.0f} s on {cost['train_device']}"
    text = f"{dh:.3g} device-h ({where})" if hours else where
    steps, epochs = cost.get("train_steps", math.nan), cost.get("train_epochs", math.nan)
    if steps is not None and np.isfinite(steps):  # the budget, since budgets are in steps
        text += f", {steps:.0f} steps"
        if np.isfinite(epochs):
            text += f" ({epochs:.0f} epochs)"
    elif np.isfinite(epochs):
        text += f", {epochs:.0f} epochs"
    if np.isfinite(cost.get("train_final_loss", math.nan)):
        text += f", loss {cost['train_final_loss']:.3g}"
    if "reference" in str(cost.get("train_weights") or ""):
        text += f", {cost['train_weights']} weights"
    return text


def describe_seconds(seconds: float) -> str:
    """Seconds per object, readable from milliseconds to minutes."""
    if seconds is None or not np.isfinite(seconds):
        return "–"
    return f"{seconds * 1000:.1f} ms" if seconds < 1 else f"{seconds:.2f} s"
