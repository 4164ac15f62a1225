"""Where a thread count (or another CPU's SIMD kernels) enters a meshed method's scores.

    .venv/bin/python benchmarks/thread_scores.py [-m igr] [--threads 1,2] [--chunk 0] [-k 50]
        [--seed 0] [--split trained] [--other-isa] [--cache-dir DIR]

Completes one runner chunk of test objects (the runner's ``batch_size`` objects of the split,
``--chunk`` picks which, at the standard profile with the shipped reference weights of
``--seed``) twice, in two child processes: with the first and the second of ``--threads`` torch
threads (set as a local sweep worker sets them), or, with ``--other-isa``, both at the first
count with the second child restricted to SSE4.2 kernels (torch, oneDNN and MKL), which stands
in for another machine. It prints per object the first stage where the two differ: the code
(after a test-time search), the field on a fixed 33^3 grid, the mesh (faces, vertices), the
sampled points and chamfer-l2; and splits the score's difference into what the vertices' motion
does (the first run's face picks and barycentric draws on the second run's vertices) and what
the changed face picks do, beside the score's resampling noise (five other sampling seeds, same
mesh). Nothing is logged and no store is touched. Measured numbers: benchmarks/README.md
("Thread counts and scores").
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

#: Environment that restricts torch, oneDNN and MKL to SSE4.2 kernels: another CPU's rounding.
OTHER_ISA = {
    "ATEN_CPU_CAPABILITY": "default",
    "ONEDNN_MAX_CPU_ISA": "SSE41",
    "MKL_ENABLE_INSTRUCTIONS": "SSE4_2",
}


def shipped_reference(method: str, profile: str, seed: int) -> Path:
    """The shipped reference checkpoint of ``method`` on the synthetic benchmark trained at
    ``profile`` with ``seed`` (found by its reference.json, so a rekey does not break this)."""
    from shapebench.train.references import SHIPPED

    for info in sorted(SHIPPED.glob("*/*/reference.json")):
        d = json.loads(info.read_text())
        wanted = (method, profile, seed, "synthetic")
        if (d.get("method"), d.get("profile"), d.get("seed"), d.get("dataset")) == wanted:
            return info.parent / "model.ckpt"
    raise SystemExit(f"no shipped reference of {method} at profile {profile}, seed {seed}")


def child(args: argparse.Namespace) -> None:
    """Complete the chunk as the runner does and save every stage to ``args.out``."""
    threads = int(args.threads.split(",")[0])
    os.environ["OMP_NUM_THREADS"] = os.environ["MKL_NUM_THREADS"] = str(threads)
    import torch

    torch.set_num_threads(threads)
    from shapebench.api.contexts import ContextStore
    from shapebench.config import make_settings
    from shapebench.evaluation.completion import complete_chunk, subnormals_flushed
    from shapebench.metrics.chamfer import ChamferL2
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method

    settings = make_settings(None, args.cache_dir, "standard", tempfile.gettempdir())
    reg = get_registry()
    method = (resolved := resolve_method(reg, args.method, settings)).cls(resolved.options)
    method.load_checkpoint(shipped_reference(args.method, "standard", args.seed))
    dataset = resolve_dataset(reg, "synthetic", settings, None)
    size = max(1, int(getattr(method, "batch_size", 1)))
    refs = dataset.objects(args.split)[args.chunk * size : (args.chunk + 1) * size]
    store = ContextStore(dataset.cache_root, dataset.data_fingerprint())
    datas = [dataset.load(r) for r in refs]
    ctxs = [store.context(d, args.k, args.seed) for d in datas]
    codes: list = []
    encode = method.encode

    def recorded(contexts):
        found = encode(contexts)
        codes.extend(found)
        return found

    method.encode = recorded
    outputs, _ = complete_chunk(method, ctxs, dataset.points_to_complete(datas[0]))
    axis = np.linspace(-1.05, 1.05, 33, dtype=np.float32)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    save: dict[str, np.ndarray] = {"ids": np.array([r.id for r in refs])}
    for i, (d, c, o) in enumerate(zip(datas, ctxs, outputs, strict=True)):
        if isinstance(o, Exception):
            continue
        code = codes[i][0] if isinstance(codes[i], tuple) else codes[i]
        with subnormals_flushed():
            save[f"{i}_field"] = method.field(codes[i])(grid)
        save[f"{i}_code"] = torch.as_tensor(code).detach().cpu().numpy()
        save[f"{i}_verts"] = np.asarray(o.mesh.vertices)
        save[f"{i}_faces"] = np.asarray(o.mesh.faces)
        save[f"{i}_points"] = np.asarray(o.points)
        save[f"{i}_score"] = np.float64(ChamferL2().compute(o, d, c))
        save[f"{i}_seed"] = np.int64(c.seed)
    np.savez(args.out, **save)


def _draws(verts: np.ndarray, faces: np.ndarray, n: int, seed: int):
    """The face picks and barycentric draws of ``sample_mesh_points`` (same generator, order)."""
    rng = np.random.default_rng(seed)
    tri = verts[faces].astype(np.float64)
    areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    face = rng.choice(len(faces), size=n, p=areas / areas.sum())
    return face, np.sqrt(rng.random(n)), rng.random(n)


def _place(verts, faces, face, r1, r2) -> np.ndarray:
    t = verts[faces[face]]
    pts = (1 - r1)[:, None] * t[:, 0] + (r1 * (1 - r2))[:, None] * t[:, 1]
    return (pts + (r1 * r2)[:, None] * t[:, 2]).astype(np.float32)


def _chamfer(points: np.ndarray, gt: np.ndarray, tree) -> float:
    from scipy.spatial import cKDTree

    p = points.astype(np.float64)
    to_gt, _ = tree.query(p)
    to_pred, _ = cKDTree(p).query(gt)
    return float(np.mean(to_pred**2) + np.mean(to_gt**2))


def compare(a: dict, b: dict, cache_dir: str | None, split: str) -> None:
    """Print the per-stage differences of the two children's outputs, object by object."""
    from scipy.spatial import cKDTree

    from shapebench.config import make_settings
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset

    settings = make_settings(None, cache_dir, "standard", tempfile.gettempdir())
    dataset = resolve_dataset(get_registry(), "synthetic", settings, None)
    refs = {r.id: r for r in dataset.objects(split)}
    worst = 0.0
    for i, oid in enumerate(a["ids"]):
        if f"{i}_score" not in a or f"{i}_score" not in b:
            print(f"{oid:16s} failed in one run")
            continue
        va, fa, vb, fb = a[f"{i}_verts"], a[f"{i}_faces"], b[f"{i}_verts"], b[f"{i}_faces"]
        sa, sb = float(a[f"{i}_score"]), float(b[f"{i}_score"])
        rel = abs(sb - sa) / sa
        worst = max(worst, rel)
        line = (
            f"{oid:16s} code {np.abs(a[f'{i}_code'] - b[f'{i}_code']).max():.1e} "
            f"field {np.abs(a[f'{i}_field'] - b[f'{i}_field']).max():.1e} "
            f"faces {len(fa)}/{len(fb)} "
        )
        same = fa.shape == fb.shape and bool((fa == fb).all())
        if same:
            line += f"verts {np.abs(va - vb).max():.1e} "
        line += f"score {rel:.2e}"
        if rel > 0:
            gt = dataset.load(refs[str(oid)]).gt_points.astype(np.float64)
            tree = cKDTree(gt)
            n, seed = len(a[f"{i}_points"]), int(a[f"{i}_seed"])
            picks = _draws(va, fa, n, seed)
            if same:
                moved = _chamfer(_place(vb, fb, *picks), gt, tree)
                changed = np.mean(picks[0] != _draws(vb, fb, n, seed)[0])
                line += (
                    f" = vertices {abs(moved - sa) / sa:.1e} + face picks "
                    f"{abs(sb - moved) / sa:.1e} ({changed * n:.0f} of {n} picks)"
                )
            else:
                line += " (mesh topology differs: picks reshuffled)"
            noise = [
                _chamfer(_place(va, fa, *_draws(va, fa, n, seed + j)), gt, tree)
                for j in (1, 2, 3, 4, 5)
            ]
            line += f"; resampling noise {np.std(noise) / sa:.1e}"
        print(line, flush=True)
    print(f"largest relative difference of chamfer-l2: {worst:.2e}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", "-m", default="igr")
    parser.add_argument("--threads", default="1,2", help="the two thread counts, e.g. 1,2")
    parser.add_argument("--chunk", type=int, default=0)
    parser.add_argument("-k", type=int, default=50, help="context size")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--split", default="trained")
    parser.add_argument("--other-isa", action="store_true", help="second run on SSE4.2 kernels")
    parser.add_argument("--cache-dir", default=None)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args)
        return
    counts = [int(t) for t in args.threads.split(",")]
    if len(counts) != 2 or min(counts) < 1:
        raise SystemExit(f"--threads takes two counts of at least 1, e.g. 1,2; got {args.threads}")
    if args.other_isa:
        counts[1] = counts[0]
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for j, threads in enumerate(counts):
            env = {**os.environ, **(OTHER_ISA if args.other_isa and j == 1 else {})}
            out = Path(tmp) / f"run{j}.npz"
            cmd = [
                sys.executable,
                __file__,
                "--child",
                "--threads",
                str(threads),
                "--out",
                str(out),
            ]
            cmd += ["-m", args.method, "--chunk", str(args.chunk), "-k", str(args.k)]
            cmd += ["--seed", str(args.seed), "--split", args.split]
            cmd += ["--cache-dir", args.cache_dir] if args.cache_dir else []
            subprocess.run(cmd, env=env, check=True)
            runs.append(dict(np.load(out)))
    second = "SSE4.2 kernels" if args.other_isa else f"{counts[1]} threads"
    print(
        f"{args.method}, {args.split} chunk {args.chunk}, k={args.k}, seed {args.seed}: "
        f"{counts[0]} threads against {second} (largest absolute differences; score relative)"
    )
    compare(runs[0], runs[1], args.cache_dir, args.split)


if __name__ == "__main__":
    main()
