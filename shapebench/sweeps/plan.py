"""What a sweep still has to do, without doing it: its cells, which are finished, and the
trainings the missing ones need.

A cluster launcher submits only this (:mod:`shapebench.sweeps.cluster`): cells are identified by the
same keys the runner skips finished cells by (:func:`shapebench.evaluation.plan.planned_cells`),
and a
training by its checkpoint key, so resubmitting an interrupted sweep submits exactly what is
missing. ``shapebench sweep FILE --status`` prints the same plan.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from shapebench.api.errors import ShapebenchError
from shapebench.api.method import TrainerOptions
from shapebench.config import Settings
from shapebench.evaluation.orchestrate import resolve_request, seed_plans
from shapebench.evaluation.plan import planned_cells
from shapebench.evaluation.runner import Runner
from shapebench.store.tracking import Tracker, experiment_name
from shapebench.sweeps.spec import SweepSpec, pairs, request, sweep_methods
from shapebench.train.training import read_done


@dataclass(frozen=True)
class CellTask:
    """One cell of the sweep: method entry ``method_index`` of the sweep on dataset entry
    ``dataset_index``, at one split, seed and context size."""

    method_index: int
    dataset_index: int
    split: str
    seed: int
    size: int
    key: str
    label: str
    dataset: str
    #: The checkpoint key of the training this cell evaluates (None: the method does not train).
    training: str | None = None

    @property
    def name(self) -> str:
        return f"{self.label} on {self.dataset}/{self.split} k={self.size} seed={self.seed}"


@dataclass(frozen=True)
class TrainingTask:
    """A training some missing cell needs and nobody finished yet."""

    method_index: int
    dataset_index: int
    seed: int
    key: str
    label: str
    dataset: str
    #: Reference weights for ``key`` ship with shapebench: the task installs them in seconds
    #: (unless the sweep runs with ``--retrain``) instead of training.
    shipped: bool = False

    @property
    def name(self) -> str:
        return f"train {self.label} on {self.dataset} seed={self.seed}"


@dataclass
class SweepPlan:
    cells: list[CellTask] = field(default_factory=list)
    finished: dict[str, str] = field(default_factory=dict)  # cell key -> run id
    trainings: list[TrainingTask] = field(default_factory=list)  # missing ones only
    trained: set[str] = field(default_factory=set)  # checkpoint keys already trained
    errors: list[str] = field(default_factory=list)  # method x dataset pairs that cannot run

    @property
    def missing(self) -> list[CellTask]:
        return [c for c in self.cells if c.key not in self.finished]


def plan_sweep(
    spec: SweepSpec,
    settings: Settings,
    trainer_for_seed: Callable[[int], TrainerOptions],
    tracker: Tracker | None = None,
    force: bool = False,
) -> SweepPlan:
    """The cells of ``spec``, which of them have a finished run in the store, and the trainings
    that the missing ones need (``force``: every cell counts as missing)."""
    methods = sweep_methods(spec)
    tracker = tracker or Tracker(settings)
    runner = Runner(tracker)
    out = SweepPlan()
    trainings: dict[str, TrainingTask] = {}
    # Each experiment's finished cells, read once: a search per cell scans the store each time,
    # which made `sweep --status` quadratic in the store's size (benchmarks/bench_scale.py).
    indexes: dict[str, dict] = {}

    def finished_index(exp_id: str) -> dict:
        if exp_id not in indexes:
            indexes[exp_id] = tracker.finished_cell_index(exp_id)
        return indexes[exp_id]

    for di, ds, mi, m in pairs(spec, methods):
        req = request(spec, m, ds, force=force, quiet=True)
        try:
            resolved = resolve_request(req, settings)
        except ShapebenchError as exc:  # reported, and the rest of the sweep goes on
            out.errors.append(f"{m.name} on {ds.name}: {exc.message}")
            continue
        for sp in seed_plans(req, resolved, settings, trainer_for_seed):
            ticket = sp.ticket  # the seed's training, planned once by seed_plans
            training = ticket.key if ticket is not None else None
            needed = False  # some cell of this seed is missing
            for split in sp.plan.splits:
                exp_id = tracker.experiment_id(experiment_name(ds.name, split), create=False)
                for seed, size, _cfg, key in planned_cells(sp.plan, split):
                    cell = CellTask(
                        mi, di, split, seed, size, key, sp.variant.label, ds.name, training
                    )
                    out.cells.append(cell)
                    done = (
                        runner.finished(sp.plan, exp_id, key, finished_index(exp_id))
                        if exp_id
                        else None
                    )
                    if done is not None:
                        out.finished[key] = done.run_id
                    else:
                        needed = True
            if ticket is None:
                continue
            if read_done(ticket.workdir) is not None:
                out.trained.add(training)
            elif needed:
                trainings.setdefault(
                    training,
                    TrainingTask(
                        mi,
                        di,
                        sp.seed,
                        training,
                        sp.variant.label,
                        ds.name,
                        shipped=ticket.reference is not None,
                    ),
                )
    out.trainings = list(trainings.values())
    return out
