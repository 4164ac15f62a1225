"""Sanity ladder: can a trainable method fit what it was trained on?

    .venv/bin/python benchmarks/ladder.py --method igr [--rungs a,b,c] [--profile quick]
        [--steps 1000] [--category bottle] [--context 1000] [--eval-objects 3]
        [--eval-split train|trained|novel] [--largest] [-O key=value ...] [-D key=value ...]
        [--seed 0] [--cache-dir DIR] [--verbose]

Each rung trains the method from scratch on part of the synthetic benchmark's training split and
then completes training objects from ``--context`` of their own visible surface points:

* (a) one training shape (the first of ``--category``);
* (b) every training shape of that category;
* (c) the whole training split.

A method that works should, on rung (a), approach Gauss densification on the same points (the
shape was seen in training, so nothing is left to guess but the resolution of the mesh); a
method far from it on (a) has a bug or too few steps, whatever it does on the benchmark. Per
rung it prints the optimiser steps, the training wall time, the final training loss, and
chamfer-l2 x 1000 (mean over up to ``--eval-objects`` objects of the rung) of the untrained
network, of the trained one, and of Gauss densification on the same points. ``--steps`` is the
number of optimiser steps per rung (epochs are derived from it), so rung (a) is not starved by a
profile sized for the whole split. Trainings run in this process on the CPU (or the GPU torch
sees), in a temporary folder, with nothing logged to MLflow.

``--eval-split trained`` (or ``novel``) scores the first ``--eval-objects`` test objects of that
split instead of the rung's own training objects (rung (c) then is the benchmark's training with
``--steps`` steps). ``--largest`` adds a column: the same completions scored after keeping only
the mesh's largest connected component (``largest_component``), whatever the option says.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from shapebench.api.dataset import Dataset
from shapebench.api.types import (
    NOVEL,
    TRAIN,
    TRAINED,
    Completion,
    Context,
    ObjectData,
    ObjectRef,
    Supervision,
)
from shapebench.hashing import stable_seed

if TYPE_CHECKING:
    import torch

RUNGS = {"a": "one shape", "b": "one category", "c": "training split"}


class Subset(Dataset):
    """``base`` with its training split cut down to ``refs``."""

    def __init__(self, base: Dataset, refs: list[ObjectRef]) -> None:
        super().__init__(base.options, base.cache_dir, base.data_root)
        self.base = base
        self.refs = refs
        self.name = base.name

    def categories(self):
        return self.base.categories()

    def objects(self, split: str) -> list[ObjectRef]:
        return list(self.refs) if split == TRAIN else []

    def load(self, ref: ObjectRef, need: frozenset[Supervision] = frozenset()) -> ObjectData:
        return self.base.load(ref, need)


@dataclass
class RungResult:
    rung: str
    objects: int
    steps: int
    seconds: float
    final_loss: float
    initial: float  # chamfer-l2 x 1000 of the untrained network (nan if it failed to mesh)
    trained: float
    gauss: float
    failures: int
    largest: float = math.nan  # trained, largest mesh component only (--largest)
    # auto-decoders, objects of the rung: decoded from the codes training learned for them
    trained_code: float = math.nan


def rung_refs(dataset: Dataset, rung: str, category: str) -> list[ObjectRef]:
    train = dataset.objects(TRAIN)
    same = [r for r in train if r.category == category]
    if not same:
        cats = sorted({r.category for r in train})
        raise SystemExit(f"no training object in category {category!r}; use one of {cats}")
    return {"a": same[:1], "b": same, "c": train}[rung]


def context_of(data: ObjectData, size: int, seed: int) -> Context:
    """``size`` of the object's visible surface points (all of them if it has fewer); points
    only, as the benchmark's protocol."""
    rng = np.random.default_rng(stable_seed("ladder", data.ref.id, size, seed))
    pts = data.surface_points
    pick = rng.choice(len(pts), size=min(size, len(pts)), replace=False)
    return Context(
        data.ref,
        np.ascontiguousarray(pts[pick], dtype=np.float32),
        None,
        seed=stable_seed("ladder-ctx", data.ref.id, seed),
    )


def chamfer_x1000(completion: Completion | Exception, data: ObjectData, ctx: Context) -> float:
    from shapebench.metrics.chamfer import ChamferL2

    if isinstance(completion, Exception) or len(completion.points) == 0:
        return math.nan
    return 1000.0 * ChamferL2().compute(completion, data, ctx)


def evaluate(
    method, objects: list[ObjectData], contexts: list[Context], largest: bool = False
) -> list[float] | tuple[list[float], list[float]]:
    """chamfer-l2 x 1000 of the method's completion of each context (nan where it failed); with
    ``largest``, also that of the same completions cut to their largest mesh component."""
    out, cut = [], []
    for data, ctx in zip(objects, contexts, strict=True):
        result = method.complete_batch([ctx], len(data.gt_points))[0]
        out.append(chamfer_x1000(result, data, ctx))
        if largest:
            cut.append(chamfer_x1000(largest_only(result, len(data.gt_points), ctx), data, ctx))
    return (out, cut) if largest else out


def largest_only(result: Completion | Exception, n_points: int, ctx: Context):
    """The completion resampled from its mesh's largest component (unchanged without a mesh)."""
    if isinstance(result, Exception) or result.mesh is None:
        return result
    from shapebench.geometry.meshing import sample_mesh_points
    from shapebench.implicit.completion import largest_component

    mesh = largest_component(result.mesh)
    return Completion(points=sample_mesh_points(mesh, n_points, seed=ctx.seed), mesh=mesh)


def trained_codes(module: torch.nn.Module) -> torch.Tensor | None:
    """The per-training-object codes of an auto-decoder module (IGR: a Parameter, DeepSDF: an
    Embedding); None for a method that encodes (MSC). An Embedding with ``max_norm`` (DeepSDF's
    bound 1) renormalises a row when it is looked up, so a stored row can exceed the bound by
    the last optimiser step: it is returned as stored."""
    import torch

    latents = getattr(module, "latents", None)
    if latents is None:
        return None
    return (latents.weight if isinstance(latents, torch.nn.Embedding) else latents).detach()


def nanmean(values: list[float]) -> float:
    finite = [v for v in values if not math.isnan(v)]
    return float(np.mean(finite)) if finite else math.nan


def gauss_scores(objects: list[ObjectData], contexts: list[Context]) -> list[float]:
    from shapebench_gauss.method import GaussDensification

    gauss = GaussDensification()
    return [
        chamfer_x1000(gauss.complete(c, len(d.gt_points)), d, c)
        for d, c in zip(objects, contexts, strict=True)
    ]


def untrained(method, n_shapes: int, seed: int):
    """``method`` holding a freshly initialised module, as ``load_checkpoint`` would leave it."""
    from shapebench.train.lightning_method import completion_device
    from shapebench.train.seeding import seed_training

    seed_training(seed)
    method.device = completion_device()
    method.module = method.build_module(n_shapes).to(method.device).eval()
    for p in method.module.parameters():
        p.requires_grad_(False)
    return method


def epochs_for(steps: int, n_objects: int, batch_shapes: int) -> int:
    return max(1, math.ceil(steps / math.ceil(n_objects / min(batch_shapes, n_objects))))


def run_rung(resolved, dataset: Dataset, rung: str, args, workdir: Path) -> RungResult:
    """Train ``resolved`` (a ResolvedMethod) on the rung's objects and score it."""
    from shapebench.api.method import TrainerOptions, TrainingContext

    refs = rung_refs(dataset, rung, args.category)
    subset = Subset(dataset, refs)
    epochs = epochs_for(args.steps, len(refs), resolved.options.batch_shapes)
    options = replace(resolved.options, epochs=epochs)
    if hasattr(options, "steps"):  # a step budget (the quick profile's) is replaced by --steps
        options = replace(options, steps=args.steps)
    pool = refs if args.eval_split == TRAIN else dataset.objects(args.eval_split)
    objects = [dataset.load(r) for r in pool[: args.eval_objects]]
    contexts = [context_of(d, args.context, args.seed) for d in objects]

    initial = evaluate(untrained(resolved.cls(options), len(refs), args.seed), objects, contexts)
    method = resolved.cls(options)
    trainer = TrainerOptions(accelerator=args.accelerator, devices=1, seed=args.seed)
    ctx = TrainingContext(subset, trainer, workdir / rung, "", None, quiet=not args.verbose)
    start = time.perf_counter()
    path = method.fit(ctx)
    seconds = time.perf_counter() - start
    summary = json.loads((workdir / rung / "summary.json").read_text())
    method.load_checkpoint(path)
    trained, cut = evaluate(method, objects, contexts, largest=True)
    return RungResult(
        rung,
        len(refs),
        summary["optimizer_steps"],
        seconds,
        summary["final"].get("train/loss", math.nan),
        nanmean(initial),
        nanmean(trained),
        nanmean(gauss_scores(objects, contexts)),
        sum(map(math.isnan, trained)),
        nanmean(cut),
        nanmean(decode_trained_codes(method, refs, objects, contexts)),
    )


def decode_trained_codes(
    method, refs: list[ObjectRef], objects: list[ObjectData], contexts: list[Context]
) -> list[float]:
    """chamfer-l2 x 1000 of each training object decoded from the code training learned for it
    (nan where it failed; none for a method without per-object codes, or objects that were not
    trained on). A search that starts elsewhere (DeepSDF's codes start far from its z0) can
    miss a shape the network holds: this column says whether the network holds it."""
    table = trained_codes(method.module)
    if table is None or len(table) != len(refs):  # a training object that failed to load
        return []  # shifts the rows: no code can be matched to its object
    out = []
    for data, ctx in zip(objects, contexts, strict=True):
        if data.ref not in refs:
            continue
        try:
            code = table[refs.index(data.ref)].to(method.device)
            out.append(chamfer_x1000(method.decode(code, ctx, len(data.gt_points)), data, ctx))
        except Exception:  # no surface: the code holds no shape
            out.append(math.nan)
    return out


def resolve(args):
    """The method and the synthetic dataset with the profile and the overrides."""
    from shapebench.api.options import parse_assignments
    from shapebench.config import make_settings
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method

    settings = make_settings(None, args.cache_dir, args.profile, tempfile.gettempdir())
    reg = get_registry()
    resolved = resolve_method(reg, args.method, settings, parse_assignments(args.O, "-O"))
    if not resolved.cls.trains:
        raise SystemExit(f"{args.method} does not train: nothing to climb")
    dataset = resolve_dataset(reg, "synthetic", settings, None, parse_assignments(args.D, "-D"))
    return resolved, dataset


def print_table(results: list[RungResult], method: str, largest: bool = False) -> None:
    codes = any(not math.isnan(r.trained_code) for r in results)
    head = f"{'rung':<18} {'objects':>7} {'steps':>6} {'train s':>8} {'final loss':>10} "
    head += f"{'init x1000':>10} {method + ' x1000':>12} {'gauss x1000':>11} {'failed':>6}"
    print(
        head
        + (f" {'largest x1000':>13}" if largest else "")
        + (f" {'code x1000':>10}" if codes else "")
    )
    for r in results:
        row = (
            f"{r.rung + ' ' + RUNGS[r.rung]:<18} {r.objects:>7} {r.steps:>6} {r.seconds:>8.1f} "
            f"{r.final_loss:>10.4g} {r.initial:>10.3f} {r.trained:>12.3f} {r.gauss:>11.3f} "
            f"{r.failures:>6}"
        )
        print(
            row
            + (f" {r.largest:>13.3f}" if largest else "")
            + (f" {r.trained_code:>10.3f}" if codes else "")
        )


def main(argv: list[str] | None = None) -> list[RungResult]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", "-m", required=True)
    parser.add_argument("--rungs", default="a,b,c")
    parser.add_argument("--profile", default="quick")
    parser.add_argument("--steps", type=int, default=1000, help="optimiser steps per rung")
    parser.add_argument("--category", default="bottle")
    parser.add_argument("--context", type=int, default=1000)
    parser.add_argument("--eval-objects", type=int, default=3)
    parser.add_argument("--eval-split", default=TRAIN, choices=[TRAIN, TRAINED, NOVEL])
    parser.add_argument("--largest", action="store_true", help="also score the largest component")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--accelerator", default="auto")
    parser.add_argument("--cache-dir", default=None)
    parser.add_argument("--verbose", action="store_true", help="progress bars and summaries")
    parser.add_argument("-O", action="append", default=[], help="method option KEY=VALUE")
    parser.add_argument("-D", action="append", default=[], help="dataset option KEY=VALUE")
    args = parser.parse_args(argv)
    resolved, dataset = resolve(args)
    rungs = [r.strip() for r in args.rungs.split(",") if r.strip()]
    unknown = [r for r in rungs if r not in RUNGS]
    if unknown:
        raise SystemExit(f"unknown rungs {unknown}; use a, b, c")
    print(
        f"ladder: {args.method}, profile {args.profile}, {args.steps} steps per rung, "
        f"{args.context} context points, seed {args.seed}",
        file=sys.stderr,
    )
    results = []
    with tempfile.TemporaryDirectory(prefix="ladder-") as tmp:
        for rung in rungs:
            results.append(run_rung(resolved, dataset, rung, args, Path(tmp)))
            print(f"rung {rung} done in {results[-1].seconds:.0f} s", file=sys.stderr)
    print_table(results, args.method, args.largest)
    return results


if __name__ == "__main__":
    main()
