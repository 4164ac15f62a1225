"""Training is reproducible: the same seed gives bitwise-identical weights, another seed does not;
and every training ends with a summary on stderr and in its MLflow run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from shapebench_msc.method import MSC
from tiny_datasets import TINY_MSC, Shapes, meshes

from shapebench.api.method import TrainerOptions, TrainingContext

pytestmark = pytest.mark.slow  # every test trains with Lightning


def _train(
    tmp_path: Path,
    seed: int,
    name: str,
    tracking_uri: str = "",
    run_id: str | None = None,
    quiet: bool = True,
    **options: object,
) -> dict[str, torch.Tensor]:
    """Two epochs of the tiny MSC in this process (unless ``options`` say otherwise); the
    weights it saved."""
    trainer = TrainerOptions(accelerator="cpu", devices=1, seed=seed)
    ctx = TrainingContext(Shapes(meshes()), trainer, tmp_path / name, tracking_uri, run_id, quiet)
    path = MSC(MSC.Options(**{**TINY_MSC, **options})).fit(ctx)
    state = torch.load(path, map_location="cpu", weights_only=False)
    return {"global_step": state["global_step"], **state["state_dict"]}


def _same(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(
        torch.equal(torch.as_tensor(a[k]), torch.as_tensor(b[k])) for k in a
    )


def test_same_seed_same_weights_other_seed_other_weights(tmp_path):
    first = _train(tmp_path, seed=3, name="a")
    # Draw from the global generators in between: the second training must not depend on it.
    torch.rand(100)
    np.random.rand(100)
    again = _train(tmp_path, seed=3, name="b")
    other = _train(tmp_path, seed=4, name="c")
    assert _same(first, again)
    assert not _same(first, other)


def test_training_ends_with_a_summary_on_stderr_and_in_mlflow(tmp_path, capsys):
    from mlflow.tracking import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    client = MlflowClient(uri)
    run_id = client.create_run(client.create_experiment("train")).info.run_id
    _train(tmp_path, seed=0, name="s", tracking_uri=uri, run_id=run_id, quiet=False)
    err = capsys.readouterr().err
    assert "training plan: 4 shapes, 4 optimiser steps (2 epochs x 2 batches of 2 shapes" in err
    assert "s per optimiser step over 2 steps; about" in err and "for the 1 step left" in err
    assert "training done" in err and "4 shapes, 2 epochs, 4 optimiser steps" in err
    assert "elbo" in err and "eikonal" in err
    metrics = client.get_run(run_id).data.metrics
    assert metrics["summary/epochs"] == 2 and metrics["summary/optimizer_steps"] == 4
    assert metrics["summary/training_shapes"] == 4
    assert metrics["summary/wall_seconds"] > 0 and "summary/final_loss" in metrics
    assert client.get_run(run_id).data.tags["training_device"].startswith("cpu")


def test_a_step_budget_trains_that_many_steps_and_the_same_weights_as_its_epochs(tmp_path, capsys):
    # 4 shapes in batches of 2: 2 epochs are 4 steps. A budget of 4 steps trains exactly what
    # 2 epochs train (the constant learning rate of lr_halve_steps=0 equals a halving every 500
    # epochs that never comes); 3 steps end mid-epoch, and that checkpoint is saved.
    epochs = _train(tmp_path, seed=1, name="epochs")
    steps = _train(tmp_path, seed=1, name="steps", quiet=False, steps=4, lr_halve_steps=0)
    assert "4 shapes, 4 optimiser steps (about 2 epochs of 2 batches" in capsys.readouterr().err
    assert _same(epochs, steps)
    three = _train(tmp_path, seed=1, name="three", steps=3, lr_halve_steps=0)
    assert int(three["global_step"]) == 3 and not _same(three, steps)


def test_a_step_schedule_halves_the_learning_rate_every_n_steps():
    from shapebench.train.lightning_fit import adam_halving

    params = [torch.nn.Parameter(torch.zeros(2))]
    config = adam_halving(params, 1.0, every=500, every_steps=3)
    opt, sched = config["optimizer"], config["lr_scheduler"]
    assert sched["interval"] == "step"
    rates = []
    for _ in range(7):
        rates.append(opt.param_groups[0]["lr"])
        opt.step()
        sched["scheduler"].step()
    assert rates == [1.0, 1.0, 1.0, 0.5, 0.5, 0.5, 0.25]
    assert "lr_scheduler" not in adam_halving(params, 1.0, every=500, every_steps=0)
