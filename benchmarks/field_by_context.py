"""Does an implicit method's field get better or only bigger as the context grows?

    .venv/bin/python benchmarks/field_by_context.py -m occnet --checkpoint PATH
        [--profile standard] [--contexts 50,100,300,1000] [--levels 0.2,0.5]
        [--split validation] [--objects 22] [-O key=value ...] [-D key=value ...]

For a trained implicit method (OccNet, ConvONet, IGR, DeepSDF, MSC) and the synthetic benchmark,
it reads the field itself, before any meshing: for each context size (the nested first ``k``
points of the stored order, as runs draw them) and each surface level it prints

* the **volume** the field puts inside the surface, as a fraction of the ground truth's (both
  counted on the ground truth's uniform occupancy points of the ``iou`` metric);
* the **IoU** of the two insides on those points (mean and median over the objects).

A field that grows with the context (volume ratio rising past 1 while IoU falls) inflates the
completion: its Chamfer distance grows in both directions even though the network sees more of
the object. Comparing levels tells a field that has the right shape at another level (a
calibration matter) from one that does not. Levels are probabilities for occupancy fields
(``inside_is_negative`` False; the method's ``threshold`` is one of them) and field values for
signed distance fields (0 is the surface). Nothing is meshed or logged; the checkpoint is only
read. Use validation objects (the default) for choices; test objects are not for tuning.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from ladder import resolve  # noqa: E402


def level_value(level: float, logits: bool) -> float:
    """The field value of a surface level: a probability's logit, or an SDF value as given."""
    if not logits:
        return level
    if not 0.0 < level < 1.0:
        raise SystemExit(f"--levels: {level} is not a probability in (0, 1) (an occupancy field)")
    return math.log(level / (1.0 - level))


def against_truth(
    values: np.ndarray, truth: np.ndarray, value: float, logits: bool
) -> tuple[float, float]:
    """(inside volume / the truth's, IoU) of the field ``values`` at surface value ``value``, on
    points where ``truth`` says inside; an empty truth counts as one point."""
    inside = values > value if logits else values < value
    union = int((inside | truth).sum())
    iou = float((inside & truth).sum() / union) if union else 1.0
    return float(inside.sum()) / max(int(truth.sum()), 1), iou


def main(argv: list[str] | None = None) -> dict[tuple[int, float], np.ndarray]:
    """Print the table; return {(k, level): (objects, 2) array of (volume ratio, IoU)}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", "-m", required=True)
    parser.add_argument("--checkpoint", required=True, type=Path)
    parser.add_argument("--profile", default="quick")
    parser.add_argument("--contexts", default="50,100,300,1000")
    parser.add_argument(
        "--levels",
        default=None,
        help="surface levels, comma-separated: probabilities for occupancy fields, field "
        "values for SDFs (default: the method's own level)",
    )
    parser.add_argument("--split", default="validation", help="validation, trained or novel")
    parser.add_argument("--objects", type=int, default=0, help="the first N objects (0: all)")
    parser.add_argument("--cache-dir", default=None)
    parser.add_argument("--seed", type=int, default=0, help="the run seed of the contexts")
    parser.add_argument("-O", action="append", default=[], help="method option KEY=VALUE")
    parser.add_argument("-D", action="append", default=[], help="dataset option KEY=VALUE")
    args = parser.parse_args(argv)

    from shapebench.api.contexts import ContextStore
    from shapebench.api.types import GroundTruthArray

    resolved, dataset = resolve(args)
    method = resolved.cls(resolved.options)
    if not hasattr(method, "field"):
        raise SystemExit(f"{args.method} has no implicit field (not an ImplicitMethod)")
    method.load_checkpoint(args.checkpoint)
    logits = not method.inside_is_negative
    if args.levels:
        levels = [float(v) for v in args.levels.split(",")]
    else:
        levels = [getattr(method.options, "threshold", 0.0) if logits else 0.0]
    sizes = [int(s) for s in args.contexts.split(",")]

    refs = dataset.objects(args.split)
    refs = refs[: args.objects] if args.objects else refs
    store = ContextStore(dataset.cache_root, dataset.data_fingerprint())
    need = frozenset({GroundTruthArray.OCCUPANCY})
    rows: dict[tuple[int, float], list[tuple[float, float]]] = {
        (k, lv): [] for k in sizes for lv in levels
    }
    for ref in refs:
        data = dataset.load(ref, need)
        occupancy = data.extra[GroundTruthArray.OCCUPANCY.value]
        queries, truth = occupancy[:, :3], occupancy[:, 3] > 0.5
        for k in sizes:
            ctx = store.context(data, k, args.seed)  # the run's own context of k points
            code = next(iter(method.encode([ctx])))
            values = method.field(code)(queries)
            for lv in levels:
                rows[(k, lv)].append(against_truth(values, truth, level_value(lv, logits), logits))

    print(
        f"{args.method} on synthetic/{args.split}, {len(refs)} objects: the field's inside "
        "against the ground truth's (uniform occupancy points)"
    )
    print(f"{'level':>7} {'k':>5}  {'volume ratio':>12} {'IoU mean':>9} {'IoU median':>10}")
    out = {key: np.array(v) for key, v in rows.items()}
    for lv in levels:
        for k in sizes:
            a = out[(k, lv)]
            print(
                f"{lv:>7g} {k:>5}  {np.mean(a[:, 0]):>12.2f} {np.mean(a[:, 1]):>9.3f} "
                f"{np.median(a[:, 1]):>10.3f}"
            )
    return out


if __name__ == "__main__":
    main()
