"""One training ticket per seed: planning a run computes each seed's checkpoint key, training
identity and shipped-reference lookup once (:func:`shapebench.train.ticket.training_ticket`), and
the cells' keys, the leaderboard row and ``ensure_checkpoint`` use that ticket rather than
computing them again."""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

import shapebench
from shapebench.train import ticket as ticket_module

#: The functions that compute (part of) a training's key, or look its reference up.
COUNTED = ("checkpoint_key", "training_identity", "find_reference", "apply_trainer")


class Calls:
    """The calls of the :data:`COUNTED` functions, with the seed (or key) each was made for."""

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self.count: Counter[str] = Counter()
        self.seeds: dict[str, Counter] = {name: Counter() for name in COUNTED}


@pytest.fixture
def calls(monkeypatch) -> Calls:
    """Wrap each counted function (the real one still runs) wherever a shapebench module bound
    it, so that a call from any module counts."""
    recorded = Calls()

    def counted(name: str, real: Callable) -> Callable:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            recorded.count[name] += 1
            # checkpoint_key, training_identity, apply_trainer: the trainer (its seed) is an
            # argument; find_reference: the key.
            about = next(
                (a.seed for a in args if isinstance(a, shapebench.TrainerOptions)),
                args[1] if name == "find_reference" else None,
            )
            recorded.seeds[name][about] += 1
            return real(*args, **kwargs)

        return wrapper

    for name in COUNTED:
        real = getattr(ticket_module, name)
        wrapped = counted(name, real)
        for module in list(sys.modules.values()):
            if getattr(module, "__name__", "").startswith("shapebench") and (
                getattr(module, name, None) is real
            ):
                monkeypatch.setattr(module, name, wrapped)
    return recorded


def _evaluate(workspace: Path, cache: Path, seeds: tuple[int, ...]):
    """PCN on one novel object per category, at the standard profile: its seeds' weights ship."""
    return shapebench.evaluate(
        "pcn",
        "synthetic",
        profile="standard",
        seeds=seeds,
        split="novel",
        contexts=(50,),
        metrics=["chamfer-l2"],
        dataset_options={"test_per_category": 1},
        workspace=workspace,
        cache_dir=cache,
        progress=False,
    )


def _require_shipped(workspace: Path, cache: Path, seeds: tuple[int, ...]) -> None:
    """Fail at once, rather than train PCN for an hour, where its seeds' keys moved away from the
    shipped references (test_shipped_sweeps.py says which; rekey or retrain them)."""
    from shapebench.config import make_settings
    from shapebench.evaluation.orchestrate import EvalRequest, resolve_request
    from shapebench.train.training import trainer_options

    settings = make_settings(None, cache, "standard", workspace)
    req = EvalRequest("pcn", "synthetic", dataset_opts={"test_per_category": 1})
    resolved = resolve_request(req, settings)
    for seed in seeds:
        trainer = trainer_options(settings, seed)
        ticket = ticket_module.training_ticket(resolved.method, resolved.dataset, trainer, settings)
        if ticket.reference is None:
            pytest.fail(f"PCN's standard seed-{seed} key {ticket.key} has no shipped reference")


def test_a_run_computes_each_seeds_training_key_once(calls, tmp_path, data_cache, capsys):
    seeds = (0, 1)
    _require_shipped(tmp_path, data_cache, seeds)
    calls.clear()
    scores = _evaluate(tmp_path, data_cache, seeds)
    err = capsys.readouterr().err
    assert err.count("pcn: using the reference checkpoint for key") == len(seeds), err
    assert "no checkpoint for key" not in err  # nothing trained: the shipped weights serve
    assert set(scores["seed"]) == set(seeds) and not scores["failed"].any()
    # Planned once per seed, installed from that plan: no key computed or looked up twice.
    for name in COUNTED:
        assert calls.count[name] == len(seeds), (name, calls.seeds[name])
    assert calls.seeds["checkpoint_key"] == Counter(dict.fromkeys(seeds, 1))
    assert calls.seeds["training_identity"] == Counter(dict.fromkeys(seeds, 1))
    keys = calls.seeds["find_reference"]
    assert len(keys) == len(seeds) and set(keys.values()) == {1}

    calls.clear()  # the same run again: every cell cached, the plan alone
    _evaluate(tmp_path, data_cache, seeds)
    for name in COUNTED:
        assert calls.count[name] == len(seeds), (name, calls.seeds[name])
    assert "using the reference" not in capsys.readouterr().err  # installed already


def test_a_sweep_plan_computes_each_seeds_training_key_once(calls, tmp_path, data_cache):
    """``shapebench sweep --status`` and the cluster launcher plan cells and trainings: one
    ticket per (method, seed), whose reference says whether a training task is shipped."""
    from shapebench.config import make_settings
    from shapebench.sweeps.plan import plan_sweep
    from shapebench.sweeps.spec import load_sweep
    from shapebench.train.training import trainer_options

    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(
        "name: tickets\nmethods: [gauss, pcn]\ndatasets: [synthetic]\nsplits: [novel]\n"
        "contexts: [50]\nseeds: [0, 1, 2]\n"
    )
    settings = make_settings(None, data_cache, "standard", tmp_path)
    plan = plan_sweep(load_sweep(sweep), settings, lambda seed: trainer_options(settings, seed))
    for name in COUNTED:  # gauss does not train: pcn's three seeds only
        assert calls.count[name] == 3, (name, calls.seeds[name])
    assert calls.seeds["checkpoint_key"] == Counter({0: 1, 1: 1, 2: 1})
    # The tickets' lookups say which trainings ship: none is looked up again.
    assert len(plan.trainings) == 3 and all(task.shipped for task in plan.trainings)
