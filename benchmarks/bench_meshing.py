"""Multiresolution vs dense marching cubes on a realistic neural SDF decoder.

    python benchmarks/bench_meshing.py [--skip-dense-256] [--bf16] [--resolutions 128,256]
        [--coarse 32] [--safety 1.5] [--points 30000] [--batch-size N] [--seed 0]
        [--device cpu|cuda]

IGR, DeepSDF, MSC and OccNet turn a completion into a mesh by evaluating an MLP on a grid, and on
a CPU the decoder, not marching cubes, is the whole cost. This script builds the 8x512 softplus
(beta=100) MLP those methods use, with IGR's geometric initialisation (its output is then close
to ``|x| - 0.6``, a realistic sphere-like level set with a network's small-scale wiggles), and
for each resolution meshes it twice with ``shapebench.geometry.meshing.extract_mesh``:

* ``dense``: every grid point evaluated, the reference;
* ``multires``: coarse grid, then only cells near the surface refined.

It prints the decoder evaluations, wall time and speed-up of each, and how far the multires mesh
is from the dense one: chamfer-l2 (squared distances, mean per set, both directions summed, as
the ``chamfer-l2`` metric) between ``--points`` points sampled on each mesh, next to its noise
floor (the same measure between two independent samplings of the dense mesh) and the squared
voxel size, and the largest distance from a multires vertex to the nearest dense vertex, in
voxels. Dense at 256 takes ~9 minutes on 2 CPU cores: ``--skip-dense-256`` skips it, estimates
its time as its evaluations divided by the throughput measured at the dense 128 run, and checks
the multires 256 mesh against the field itself instead (``max|f(v)|``: the decoder at the mesh
vertices, in voxels; a 1-Lipschitz SDF bounds the distance to the true level set by it). Every
number is marked measured or estimated.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from shapebench.geometry.meshing import (
    ExtractionStats,
    default_batch_size,
    extract_mesh,
    sample_mesh_points,
)
from shapebench.geometry.nearest import nearest_distances

BOUND = 1.05


class GeometricInitMLP(nn.Module):
    """IGR's decoder: ``depth`` softplus layers of ``width`` units, input re-injected at ``skip``.

    The geometric initialisation (Atzmon & Lipman, SAL; used by IGR) makes the untrained network
    approximate the SDF of a sphere of radius ``radius``.
    """

    def __init__(self, width: int = 512, depth: int = 8, skip: int = 4, radius: float = 0.6):
        super().__init__()
        dims = [3] + [width] * depth + [1]
        self.skip = skip
        self.layers = nn.ModuleList()
        for i in range(len(dims) - 1):
            out_dim = dims[i + 1] - 3 if i + 1 == skip else dims[i + 1]
            layer = nn.Linear(dims[i], out_dim)
            if i == len(dims) - 2:
                nn.init.normal_(
                    layer.weight, mean=math.sqrt(math.pi) / math.sqrt(dims[i]), std=1e-4
                )
                nn.init.constant_(layer.bias, -radius)
            else:
                nn.init.normal_(layer.weight, 0.0, math.sqrt(2) / math.sqrt(out_dim))
                nn.init.constant_(layer.bias, 0.0)
            self.layers.append(layer)
        self.activation = nn.Softplus(beta=100)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        x = points
        for i, layer in enumerate(self.layers):
            if i == self.skip:
                x = torch.cat([x, points], dim=-1) / math.sqrt(2)
            x = layer(x)
            if i < len(self.layers) - 1:
                x = self.activation(x)
        return x.squeeze(-1)


def make_field(
    decoder: nn.Module, bf16: bool, device: torch.device
) -> Callable[[np.ndarray], np.ndarray]:
    """The numpy-in, numpy-out callable ``extract_mesh`` wants, as a method plugin would wrap it.

    On a GPU the points travel to the device and the values back on every call, as they do in
    the methods' own meshing (``shapebench.implicit.completion.field_of``), so the copies count.
    """

    def field(points: np.ndarray) -> np.ndarray:
        x = torch.from_numpy(points).to(device)
        with (
            torch.inference_mode(),
            torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16),
        ):
            return decoder(x).float().cpu().numpy()

    return field


@dataclass
class Run:
    resolution: int
    mode: str
    evaluations: int
    seconds: float
    faces: int | None
    measured: bool
    stats: ExtractionStats | None = None


def chamfer_l2(a: np.ndarray, b: np.ndarray) -> float:
    """Squared distances, mean per set, both directions summed (the ``chamfer-l2`` metric)."""
    return float(np.mean(nearest_distances(a, b) ** 2) + np.mean(nearest_distances(b, a) ** 2))


def mesh_once(field, resolution: int, dense: bool, args: argparse.Namespace):
    mesh, stats = extract_mesh(
        field,
        resolution=resolution,
        bound=BOUND,
        coarse=args.coarse,
        batch_size=args.batch_size,
        safety=args.safety,
        dense=dense,
    )
    mode = "dense" if dense else "multires"
    return mesh, Run(
        resolution, mode, stats.evaluations, stats.seconds, len(mesh.faces), True, stats
    )


def agreement(fine, ref, resolution: int, args: argparse.Namespace) -> dict[str, float]:
    """How far the multires mesh is from the dense one, next to the sampling noise floor."""
    voxel = 2 * BOUND / resolution
    ref_a = sample_mesh_points(ref, args.points, seed=args.seed)
    ref_b = sample_mesh_points(ref, args.points, seed=args.seed + 1)
    ours = sample_mesh_points(fine, args.points, seed=args.seed + 1)
    offset = nearest_distances(np.asarray(fine.vertices), np.asarray(ref.vertices)).max()
    return {
        "chamfer": chamfer_l2(ours, ref_a),
        "floor": chamfer_l2(ref_b, ref_a),
        "voxel2": voxel**2,
        "vertex_offset": offset / voxel,
    }


def field_at_vertices(field, mesh, resolution: int, batch: int) -> float:
    """max |f| over the mesh vertices, in voxels: distance to the level set for an SDF."""
    verts = np.asarray(mesh.vertices, dtype=np.float32)
    values = np.concatenate([field(verts[s : s + batch]) for s in range(0, len(verts), batch)])
    return float(np.abs(values).max() / (2 * BOUND / resolution))


def print_runs(runs: list[Run], dense_throughput: float) -> None:
    dense = {r.resolution: r for r in runs if r.mode == "dense"}
    head = (
        f"{'res':>4} {'mode':<9}{'evaluations':>12} {'share':>7} {'seconds':>9} "
        f"{'speed-up':>9} {'faces':>8}  source"
    )
    print(head)
    print("-" * len(head))
    for r in runs:
        d = dense[r.resolution]
        share = 100 * r.evaluations / d.evaluations
        faces = f"{r.faces:>8,}" if r.faces is not None else f"{'-':>8}"
        source = (
            "measured"
            if r.measured
            else (
                f"estimated: evaluations / {dense_throughput:,.0f} points/s measured at dense "
                f"{min(dense)}"
            )
        )
        if r.mode == "multires" and not d.measured:
            source = "measured (speed-up against the estimated dense time)"
        print(
            f"{r.resolution:>4} {r.mode:<9}{r.evaluations:>12,} {share:>6.1f}% "
            f"{r.seconds:>9.1f} {d.seconds / r.seconds:>8.1f}x {faces}  {source}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolutions", default="128,256", help="cells per axis, comma-separated")
    parser.add_argument(
        "--skip-dense-256",
        action="store_true",
        help="estimate dense 256 from the dense throughput (it takes ~9 min)",
    )
    parser.add_argument("--bf16", action="store_true", help="decoder under bf16 autocast")
    parser.add_argument("--coarse", type=int, default=32)
    parser.add_argument("--safety", type=float, default=1.5)
    parser.add_argument("--points", type=int, default=30_000, help="points per mesh for Chamfer")
    parser.add_argument(
        "--batch-size",
        type=int,
        default=None,
        help="points per decoder call [the extractor's: 4,096 on a CPU, 65,536 with CUDA]",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu", help="where the decoder runs: cpu or cuda")
    args = parser.parse_args()
    resolutions = sorted(int(r) for r in args.resolutions.split(","))

    torch.manual_seed(args.seed)
    device = torch.device(args.device)
    decoder = GeometricInitMLP().eval().to(device)
    field = make_field(decoder, args.bf16, device)
    if args.batch_size is None:  # after the decoder's move: CUDA is initialised on a GPU run
        args.batch_size = default_batch_size()
    # Warm-up: first-call allocations, and on a GPU the kernels' first launch at full batch size.
    field(np.zeros((args.batch_size, 3), dtype=np.float32))
    precision = "bf16 autocast" if args.bf16 else "float32"
    where = f"{torch.cuda.get_device_name(device)}, " if device.type == "cuda" else ""
    print(
        f"8x512 softplus MLP (IGR geometric init, r=0.6), {precision}; {where}"
        f"{os.cpu_count()} CPU cores ({platform.machine()}), torch {torch.__version__} "
        f"({torch.get_num_threads()} threads); bound {BOUND}, coarse {args.coarse}, "
        f"safety {args.safety}"
    )

    runs: list[Run] = []
    checks: list[str] = []
    dense_meshes: dict[int, object] = {}
    throughput = float("nan")
    for res in resolutions:
        fine, fine_run = mesh_once(field, res, dense=False, args=args)
        if res == 256 and args.skip_dense_256:
            if not dense_meshes:
                raise SystemExit("--skip-dense-256 needs a smaller dense run for its throughput")
            evals = (res + 1) ** 3
            runs += [Run(res, "dense", evals, evals / throughput, None, False), fine_run]
            lower = max(dense_meshes)
            a = agreement(fine, dense_meshes[lower], res, args)
            err = field_at_vertices(field, fine, res, args.batch_size)
            checks.append(
                f"{res:>4} {a['chamfer']:>12.3e} {a['floor']:>12.3e} {a['voxel2']:>10.3e} "
                f"{'-':>12}   vs dense {lower} (dense {res} skipped); max|f(v)| = {err:.3f} voxel"
            )
            continue
        ref, ref_run = mesh_once(field, res, dense=True, args=args)
        dense_meshes[res] = ref
        throughput = ref_run.evaluations / ref_run.seconds
        runs += [ref_run, fine_run]
        a = agreement(fine, ref, res, args)
        checks.append(
            f"{res:>4} {a['chamfer']:>12.3e} {a['floor']:>12.3e} {a['voxel2']:>10.3e} "
            f"{a['vertex_offset']:>12.3f}"
        )
    print()
    print_runs(runs, throughput)
    print()
    print(
        f"{'res':>4} {'chamfer-l2':>12} {'noise floor':>12} {'voxel^2':>10} {'max v. off.':>12}"
        "   multires vs dense, measured; vertex offset in voxels"
    )
    for line in checks:
        print(line)
    for r in runs:
        if r.stats is not None and r.mode == "multires":
            print(
                f"multires {r.resolution}: levels {r.stats.levels}, evaluations per level "
                f"{r.stats.evaluations_per_level}, cells refined {r.stats.active_cells}"
            )
    print(f"load average after the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
