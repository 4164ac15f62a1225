"""Does each of PoinTr's proxies fold a local patch, or a sheet across the whole object?

    .venv/bin/python benchmarks/pointr_patch_spread.py (--reference KEY | --checkpoint PATH |
        --untrained SEED) [--profile quick] [--contexts 50,1000] [--split validation]
        [--objects 0] [--per-object] [--batch-stats] [-O key=value ...] [-D key=value ...]

PoinTr's dense output is ``num_query`` patches of ``fold_step**2`` points, each the folding head's
offsets added to one predicted proxy centre, then the context itself. The network comes from a
shipped reference (by its key; installed into a temporary folder and checked as ``run`` installs
it), a training's ``last.ckpt``, or ``--untrained``: the profile's network as initialised. On the
synthetic benchmark's objects (validation by default: tuning reads no test object), with the
run's own nested contexts (seed 0), it prints for each context size the median over objects of
each object's median over its proxies of

* ``rms``: the patch's RMS distance from its own centroid (unit-radius frame);
* ``flat``: the smallest over the largest eigenvalue of the patch's covariance (0: a flat sheet or
  a line; 1: a round blob);
* ``thin``: the middle over the largest eigenvalue (near 0: a line; a square sheet: 1);
* ``rms/gap``: ``rms`` over the distance from the proxy's centre to the nearest other centre (about
  0.5 or less: patches tile the surface between the centres; well above 1: they overlap);
* ``rms/R``: ``rms`` over the object's radius (the ground truth's largest distance from its mean);
* ``shift/gap``: the distance from the proxy's centre to its patch's centroid, over the gap (how
  far the offsets carry the patch from the centre they are added to);
* ``ctr``: the centres' RMS distance from their mean over the ground truth's (1: spread as the
  object is; near 0: collapsed);

and means over the objects, x1000 in the benchmark's convention: the ``chamfer-l2`` of the whole
output (``CD all``, the benchmark's score) and of the context alone (``CD ctx``); the folded
points' mean squared distance to the ground truth (``fold>gt``: are they on the surface?) and the
ground truth's to them (``gt>fold``: do they cover it?); the ``chamfer-l2`` of the centres alone
(``CD ctr``). ``--per-object`` adds a line per object and size. Each object is completed alone
with the stored BatchNorm statistics, as a run completes it; ``--batch-stats`` (and
``--untrained``, whose running averages describe no input) runs the objects of a size as one
batch with BatchNorm on its own statistics, as a training step sees them.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from ladder import resolve  # noqa: E402

COLUMNS = ("rms", "flat", "thin", "rms/gap", "rms/R", "shift/gap")


def patch_statistics(centres: np.ndarray, patches: np.ndarray, radius: float) -> np.ndarray:
    """(M, 6) rows of ``COLUMNS`` for M proxy ``centres`` (M, 3) and their ``patches`` (M, S, 3)."""
    centroid = patches.mean(axis=1)
    spread = patches - centroid[:, None]
    rms = np.sqrt((spread**2).sum(axis=-1).mean(axis=1))
    cov = np.einsum("msi,msj->mij", spread, spread) / patches.shape[1]
    eig = np.linalg.eigvalsh(cov)  # ascending
    top = np.maximum(eig[:, -1], 1e-30)
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    gap = np.maximum(dist.min(axis=1), 1e-12)
    shift = np.linalg.norm(centroid - centres, axis=-1)
    columns = [rms, eig[:, 0] / top, eig[:, 1] / top, rms / gap, rms / radius, shift / gap]
    return np.stack(columns, axis=1)


def squared_distances(points: np.ndarray, reference: np.ndarray) -> float:
    """x1000 the mean over ``points`` of the squared distance to ``reference``: one direction of
    the benchmark's chamfer-l2."""
    from shapebench.geometry.nearest import nearest_distances

    return 1000 * float(np.mean(np.asarray(nearest_distances(points, reference)) ** 2))


def chamfer_l2(points: np.ndarray, gt: np.ndarray) -> float:
    """The benchmark's chamfer-l2 x1000: mean squared distance each way, summed."""
    return squared_distances(gt, points) + squared_distances(points, gt)


def load_network(args, resolved, workdir: Path):
    """The PoinTr network to measure, in eval mode (train mode for ``--untrained``)."""
    import torch

    from shapebench.train import references

    if args.untrained is not None:
        from shapebench_pointr.module import PoinTrModule

        torch.manual_seed(args.untrained)
        # Batch statistics, as the first training step sees them: the running averages of an
        # untrained network (mean 0, variance 1) describe no input.
        return PoinTrModule(resolved.options).network.train()
    path = args.checkpoint
    if args.reference:
        ref = references.find("pointr", args.reference)
        if ref is None:
            raise SystemExit(f"no shipped pointr reference {args.reference}")
        path = references.install(ref, workdir)
    method = resolved.cls(resolved.options)
    method.load_checkpoint(path)
    return method.module.network.eval()


def main(argv: list[str] | None = None) -> dict[int, np.ndarray]:
    """Print the table; return {k: (objects, 6) per-object medians of ``COLUMNS``}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--reference", help="a shipped pointr reference key")
    source.add_argument("--checkpoint", type=Path, help="a training's last.ckpt")
    source.add_argument("--untrained", type=int, metavar="SEED", help="the initialised network")
    parser.add_argument("--profile", default="quick")
    parser.add_argument("--contexts", default="50,1000")
    parser.add_argument("--split", default="validation", help="validation, trained or novel")
    parser.add_argument("--objects", type=int, default=0, help="the first N objects (0: all)")
    parser.add_argument("--per-object", action="store_true")
    parser.add_argument(
        "--batch-stats",
        action="store_true",
        help="BatchNorm on the statistics of one batch of every object (training mode)",
    )
    parser.add_argument("--cache-dir", default=None)
    parser.add_argument("--seed", type=int, default=0, help="the run seed of the contexts")
    parser.add_argument("-O", action="append", default=[], help="method option KEY=VALUE")
    parser.add_argument("-D", action="append", default=[], help="dataset option KEY=VALUE")
    args = parser.parse_args(argv)
    args.method = "pointr"

    import torch

    from shapebench.api.contexts import ContextStore

    resolved, dataset = resolve(args)
    with tempfile.TemporaryDirectory() as tmp:
        net = load_network(args, resolved, Path(tmp))
    if args.batch_stats:
        net.train()  # BatchNorm on the batch's own statistics, as in a training step
    m, s = net.num_query, net.folding.grid.shape[1]
    sizes = [int(v) for v in args.contexts.split(",")]
    refs = dataset.objects(args.split)
    refs = refs[: args.objects] if args.objects else refs
    store = ContextStore(dataset.cache_root, dataset.data_fingerprint())
    objects = [dataset.load(ref) for ref in refs]
    rows: dict[int, list[np.ndarray]] = {k: [] for k in sizes}
    spreads: dict[int, list[float]] = {k: [] for k in sizes}
    scores: dict[int, list[tuple[float, ...]]] = {k: [] for k in sizes}
    for k in sizes:
        contexts = [np.asarray(store.context(d, k, args.seed).points, np.float32) for d in objects]
        with torch.no_grad():
            if net.training:  # one batch of every object: the statistics of a training batch
                coarse, fine = net(torch.as_tensor(np.stack(contexts)))
            else:  # each object alone, as a run completes it
                outs = [net(torch.as_tensor(c)[None]) for c in contexts]
                coarse, fine = (torch.cat(parts) for parts in zip(*outs, strict=True))
        for i, (ref, data, given) in enumerate(zip(refs, objects, contexts, strict=True)):
            gt = np.asarray(data.gt_points, dtype=np.float64)
            middle = gt.mean(axis=0)
            radius = float(np.linalg.norm(gt - middle, axis=1).max())
            gt_rms = float(np.sqrt(((gt - middle) ** 2).sum(axis=1).mean()))
            # The network's layout: coarse = centres then an FPS of the input; fine = the M
            # patches of S points (centre + offsets), then the input.
            centres = coarse[i, :m].double().numpy()
            patches = fine[i, : m * s].double().numpy().reshape(m, s, 3)
            stats = np.median(patch_statistics(centres, patches, radius), axis=0)
            rows[k].append(stats)
            ctr = np.sqrt(((centres - centres.mean(axis=0)) ** 2).sum(axis=1).mean()) / gt_rms
            spreads[k].append(float(ctr))
            folded, given = patches.reshape(-1, 3), given.astype(np.float64)
            score = (
                chamfer_l2(np.concatenate([folded, given]), gt),
                chamfer_l2(given, gt),
                squared_distances(folded, gt),
                squared_distances(gt, folded),
                chamfer_l2(centres, gt),
            )
            scores[k].append(score)
            if args.per_object:
                cells = " ".join(f"{v:>9.3f}" for v in stats)
                cds = " ".join(f"{v:>8.2f}" for v in score)
                print(f"{ref.id:<20} {k:>5} {cells} {ctr:>6.3f} {cds}")

    what = args.reference or args.checkpoint or f"untrained (seed {args.untrained})"
    mode = "batch statistics" if net.training else "eval"
    print(
        f"pointr {what} ({mode}) on synthetic/{args.split}, {len(refs)} objects, {m} proxies x "
        f"{s} points: medians over objects of each object's median over its proxies; "
        "chamfer-l2 x1000 means"
    )
    head = " ".join(f"{c:>9}" for c in COLUMNS)
    cd_head = " ".join(f"{c:>8}" for c in ("CD all", "CD ctx", "fold>gt", "gt>fold", "CD ctr"))
    print(f"{'k':>5} {head} {'ctr':>6} {cd_head}")
    out = {k: np.array(v) for k, v in rows.items()}
    for k in sizes:
        cells = " ".join(f"{v:>9.3f}" for v in np.median(out[k], axis=0))
        cds = " ".join(f"{v:>8.2f}" for v in np.mean(np.array(scores[k]), axis=0))
        print(f"{k:>5} {cells} {np.median(spreads[k]):>6.3f} {cds}")
    return out


if __name__ == "__main__":
    main()
