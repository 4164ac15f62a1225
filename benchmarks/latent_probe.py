"""Where does an auto-decoder lose: its shape space, or the test-time search in it?

    .venv/bin/python benchmarks/latent_probe.py -m igr --checkpoint PATH [--objects 6]
        [--contexts 50,1000] [--steps 50,400] [--split trained] [-O key=value ...]
        [-D key=value ...] [--profile quick] [--cache-dir DIR]

For a trained auto-decoder (IGR, DeepSDF) and the synthetic benchmark it was trained on, it
prints chamfer-l2 x 1000 (mean and median over ``--objects`` objects) of:

* ``trained code``: training objects decoded from the code training learned for them: what the
  shape space holds at best (no search);
* ``search, train obj``: the same objects completed from ``k`` of their own surface points by the
  test-time optimiser with ``opt_steps`` = each of ``--steps``, and how far the found codes are
  from the trained ones (mean L2): a search that cannot find a code the decoder already knows;
* ``search, <split>``: test objects of ``--split`` completed the same way, next to Gauss
  densification on the same points;

so a completion that barely depends on the context can be told apart as a shape space that holds
one blob (``trained code`` already bad), a search that stays near its start (``search`` far
worse than ``trained code``, codes far from the trained ones), or both. Under each search of the
training objects an ``objective`` line tells those two last cases apart: the test-time objective
(the loss the codes are optimised with, averaged over four seeded draws of what it samples) at
the trained codes and at the codes found. Where the found code scores *lower* than the trained
one while its completion is worse, the objective itself prefers the wrong shape: no optimiser,
step count or start fixes that; only what the objective sees (the context, the prior) can.
Nothing is logged; the checkpoint is only read. Objects are spread over the categories (the
first of each, then the second...).

``--split validation`` completes *held-out objects of the training categories* instead of test
objects: generated like training objects but under ids (``<category>/val-NNN``) that neither the
training split (whatever ``train_per_category``) nor the test splits ever use. That is the split
to choose training settings on; test objects are not for tuning. ``--save FILE`` writes every
row's per-object scores as JSON, and ``--against FILE`` pairs each row with the same row of an
earlier ``--save`` (same objects and context points: two-sided Wilcoxon signed-rank test), e.g.
two checkpoints on the same validation objects.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from shapebench.api.types import TRAIN, TRAINED, Completion, Context, ObjectData, ObjectRef

VALIDATION = "validation"
#: A test-time objective: one loss per object (B,) for codes (B, d).
Objective = Callable[[torch.Tensor], torch.Tensor]

sys.path.insert(0, str(Path(__file__).parent))
from ladder import chamfer_x1000, context_of, gauss_scores, trained_codes  # noqa: E402


def spread(refs: list[ObjectRef], n: int) -> list[ObjectRef]:
    """``n`` refs taking the categories in turn (first of each, then second of each...)."""
    by_cat: dict[str, list[ObjectRef]] = {}
    for r in refs:
        by_cat.setdefault(r.category, []).append(r)
    out: list[ObjectRef] = []
    depth = 0
    while len(out) < n and any(len(v) > depth for v in by_cat.values()):
        out += [v[depth] for v in by_cat.values() if len(v) > depth]
        depth += 1
    return out[:n]


def validation_refs(dataset, per_category: int) -> list[ObjectRef]:
    """Held-out objects of the training categories: ids no split of the synthetic benchmark
    uses (its objects are generated from their ids), so they were never trained on and are not
    test objects."""
    return [
        ObjectRef(f"{cat.name}/val-{i:03d}", cat.name)
        for cat in dataset.categories()
        if cat.split == TRAINED
        for i in range(per_category)
    ]


def save_rows(
    path: Path,
    rows: list[tuple[str, int, list[float]]],
    objects: dict[tuple[str, int], list[str]],
    meta: dict,
) -> None:
    """Write the rows as JSON (a failed object as null), with the object ids of each row and
    what else fixes its context points (``meta``: seed, data fingerprint)."""
    out = [
        {
            "label": label,
            "k": k,
            "objects": objects[(label, k)],
            "scores": [None if math.isnan(v) else v for v in scores],
        }
        for label, k, scores in rows
    ]
    path.write_text(json.dumps({**meta, "rows": out}, indent=1, allow_nan=False))


def compare_saved(
    rows: list[tuple[str, int, list[float]]],
    objects: dict[tuple[str, int], list[str]],
    meta: dict,
    saved: dict,
    name: str,
) -> None:
    """Pair each row with the row of the same label and size in ``saved`` (a :func:`save_rows`
    file, read before anything was written), if both scored the same objects from the same
    context points; failed objects (NaN) are left out of the pair and counted."""
    from shapebench.boards.stats import paired_p

    differs = [key for key, value in meta.items() if saved.get(key) != value]
    if differs:
        raise SystemExit(
            f"{name} was made with other {', '.join(differs)} "
            f"({', '.join(f'{k}={saved.get(k)}' for k in differs)}): "
            "its context points are not these"
        )
    before = {(r["label"], r["k"]): r for r in saved["rows"]}
    print(f"\nagainst {name} (same objects and context points; wins = lower now)")
    for label, k, scores in rows:
        row = before.get((label, k))
        if row is None or row["objects"] != objects[(label, k)]:
            print(f"{label:<28} {k:>5}  not in {name} (or other objects)")
            continue
        old = np.asarray([np.nan if v is None else v for v in row["scores"]], dtype=float)
        now = np.asarray(scores, dtype=float)
        ok = ~(np.isnan(old) | np.isnan(now))
        failed = f"  failed {int(np.isnan(old).sum())} -> {int(np.isnan(now).sum())}"
        if not ok.any():
            print(f"{label:<28} {k:>5}  no object succeeded in both{failed}")
            continue
        wins = int((now[ok] < old[ok]).sum())
        print(
            f"{label:<28} {k:>5}  {np.mean(old[ok]):8.2f} -> {np.mean(now[ok]):8.2f}  "
            f"median {np.median(old[ok]):7.2f} -> {np.median(now[ok]):7.2f}  "
            f"wins {wins}/{int(ok.sum())}  p = {paired_p(now[ok], old[ok]):.2g}"
            + (failed if not ok.all() else "")
        )


def stats(values: list[float]) -> str:
    finite = [v for v in values if not math.isnan(v)]
    failed = len(values) - len(finite)
    if not finite:
        return f"{'all failed':>21}"
    text = f"{np.mean(finite):>9.2f} {np.median(finite):>8.2f}"
    return text + (f" ({failed} failed)" if failed else "   ")


def search(method, objects: list[ObjectData], contexts: list[Context]):
    """Completions of the contexts made as the runner makes them (one batch through
    ``complete_batch``, which seeds the test-time draws from the contexts), the codes found, and
    the test-time objective they were found with (None for a method without a search).

    The codes are recorded on their way from ``encode`` to ``decode``: completing by hand instead
    would leave torch's generator where earlier work put it, and the 50-point searches then
    differ from run to run by more than the settings compared.
    """
    sizes = {len(d.gt_points) for d in objects}
    if len(sizes) != 1:
        raise SystemExit(f"objects with different gt_points counts {sorted(sizes)}")
    codes: list = []
    objective: list[Objective] = []
    encode, optimise = method.encode, getattr(method, "optimise_codes", None)

    def recorded(ctxs: list[Context]):
        found = encode(ctxs)
        codes.extend(found)
        return found

    def recorded_objective(loss, init):
        objective.append(loss)
        return optimise(loss, init)

    method.encode = recorded
    if optimise is not None:
        method.optimise_codes = recorded_objective
    try:
        results: list[Completion | Exception] = method.complete_batch(contexts, sizes.pop())
    finally:
        del method.encode  # back to the class's methods
        if optimise is not None:
            del method.optimise_codes
    scores = [chamfer_x1000(r, d, c) for r, d, c in zip(results, objects, contexts, strict=True)]
    # MSC's codes are (posterior mean, variance) pairs: the mean is the code
    codes = [c[0] if isinstance(c, tuple) else c for c in codes]
    return scores, torch.stack([torch.as_tensor(c) for c in codes]), (objective or [None])[0]


def objective_at(loss: Objective, codes: torch.Tensor, draws: int = 4) -> np.ndarray:
    """The per-object test-time objective ``loss`` at ``codes``, averaged over ``draws`` seeded
    draws of whatever it samples (IGR's Eikonal points), the same draws for any ``codes``."""
    values = []
    for i in range(draws):
        torch.manual_seed(i)
        values.append(loss(codes.detach()).detach())
    return torch.stack(values).mean(0).cpu().numpy()


def objective_line(
    loss: Objective,
    own: torch.Tensor,
    found: torch.Tensor,
    own_scores: list[float],
    scores: list[float],
) -> str:
    """Is the search's answer a worse minimum of the objective than the trained code, or a
    better one? "found lower" objects whose completion is also worse are objects the objective
    ranks wrongly: no search of it can recover them."""
    at_own, at_found = objective_at(loss, own), objective_at(loss, found)
    lower = at_found < at_own
    worse = np.asarray(scores) > np.asarray(own_scores)
    both = int((lower & worse).sum())
    return (
        f"  objective at trained / found code: {at_own.mean():.4g} / {at_found.mean():.4g}; "
        f"found lower on {int(lower.sum())}/{len(lower)} objects, "
        f"{both} of them completed worse than by the trained code"
    )


def main(argv: list[str] | None = None) -> list[tuple[str, int, list[float]]]:
    """Print the table; return its rows (searches, and Gauss densification beside the searches
    of ``--split``) as (label, k, per-object scores)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", "-m", required=True)
    parser.add_argument("--checkpoint", required=True, type=Path)
    parser.add_argument("--objects", type=int, default=6)
    parser.add_argument("--contexts", default="50,1000")
    parser.add_argument("--steps", default="50,400", help="opt_steps values to try")
    parser.add_argument(
        "--split",
        default=TRAINED,
        help="trained, novel or validation "
        "(held-out objects of the training categories; tune on these)",
    )
    parser.add_argument(
        "--train-only",
        action="store_true",
        help="training objects only: what to look at while choosing training "
        "settings (never choose them by test objects)",
    )
    parser.add_argument("--profile", default="quick")
    parser.add_argument("--cache-dir", default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("-O", action="append", default=[], help="method option KEY=VALUE")
    parser.add_argument("-D", action="append", default=[], help="dataset option KEY=VALUE")
    parser.add_argument("--save", type=Path, help="write the rows' per-object scores (JSON)")
    parser.add_argument("--against", type=Path, help="pair the rows with an earlier --save")
    args = parser.parse_args(argv)
    # read before anything is written: --save and --against may name the same file
    saved = json.loads(args.against.read_text()) if args.against else None

    from shapebench.api.options import parse_assignments
    from shapebench.config import make_settings
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method

    settings = make_settings(None, args.cache_dir, args.profile, tempfile.gettempdir())
    reg = get_registry()
    resolved = resolve_method(reg, args.method, settings, parse_assignments(args.O, "-O"))
    dataset = resolve_dataset(reg, "synthetic", settings, None, parse_assignments(args.D, "-D"))
    sizes = [int(s) for s in args.contexts.split(",")]
    steps = [int(s) for s in args.steps.split(",")]

    train_refs = dataset.objects(TRAIN)
    train_pick = spread(train_refs, args.objects)
    train_objs = [dataset.load(r) for r in train_pick]
    if args.split == VALIDATION:
        categories = sum(cat.split == TRAINED for cat in dataset.categories())
        per_category = -(-args.objects // categories)
        test_refs = spread(validation_refs(dataset, per_category), args.objects)
    else:
        test_refs = spread(dataset.objects(args.split), args.objects)
    test_objs = [] if args.train_only else [dataset.load(r) for r in test_refs]

    method = resolved.cls(resolved.options)
    method.load_checkpoint(args.checkpoint)
    base = method.options  # the recipe applied
    table = trained_codes(method.module)
    own = None
    rows: list[tuple[str, int, list[float]]] = []
    objects: dict[tuple[str, int], list[str]] = {}  # the object ids of each row
    print(f"{'row':<28} {'k':>5} {'mean':>9} {'median':>8}    code dist  seconds")
    if table is not None:
        if len(table) != len(train_refs):
            raise SystemExit(
                f"the checkpoint has {len(table)} codes, the training split "
                f"{len(train_refs)} objects: not this dataset's training"
            )
        own = table[[train_refs.index(r) for r in train_pick]].to(method.device)
        print(
            f"{len(table)} trained codes, mean norm {table.norm(dim=1).mean():.3f}, mean "
            f"pairwise distance {torch.cdist(table, table).mean():.3f}"
        )
        ctx0 = [context_of(d, sizes[-1], args.seed) for d in train_objs]
        oracle = [
            chamfer_x1000(method.decode(z, c, len(d.gt_points)), d, c)
            for z, d, c in zip(own, train_objs, ctx0, strict=True)
        ]
        print(f"{'trained code, train obj':<28} {'-':>5} {stats(oracle)}")
        print(
            "  per object: "
            + ", ".join(f"{d.ref.id} {v:.1f}" for d, v in zip(train_objs, oracle, strict=True))
        )
    for k in sizes:
        groups = [(f"search, {TRAIN} obj", train_objs)]
        if not args.train_only:
            groups.append((f"search, {args.split}", test_objs))
        for label, objs in groups:
            ctxs = [context_of(d, k, args.seed) for d in objs]
            ids = [d.ref.id for d in objs]
            for s in steps:
                method.options = replace(base, opt_steps=s)
                start = time.perf_counter()
                scores, codes, loss = search(method, objs, ctxs)
                rows.append((f"{label} {s} steps", k, scores))
                objects[(rows[-1][0], k)] = ids
                to_own = objs is train_objs and own is not None
                dist = ((codes - own) if to_own else codes).norm(dim=1).mean().item()
                what = "to trained" if to_own else "norm"
                print(
                    f"{label + f' {s} steps':<28} {k:>5} {stats(scores)} {what} {dist:.3f} "
                    f"{time.perf_counter() - start:>7.1f}",
                    flush=True,
                )
                if to_own and loss is not None and s > 0:
                    # a decoded code's score does not depend on k (the mesh is sampled from
                    # the context's seed, which k does not change): the trained-code row's
                    print(objective_line(loss, own, codes.to(own.device), oracle, scores))
            if objs is not train_objs:
                gauss = gauss_scores(objs, ctxs)
                rows.append((f"gauss, {args.split}", k, gauss))
                objects[(rows[-1][0], k)] = ids
                print(f"{'gauss, ' + args.split:<28} {k:>5} {stats(gauss)}")
    meta = {"seed": args.seed, "data": dataset.data_fingerprint()}
    if saved is not None:
        compare_saved(rows, objects, meta, saved, args.against.name)
    if args.save:
        save_rows(args.save, rows, objects, meta)
    return rows


if __name__ == "__main__":
    main()
