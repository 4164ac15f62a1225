"""What a very large mesh costs to read and preprocess: time and peak memory against a typical one.

    python benchmarks/bench_large_mesh.py [--subdivisions 7,9] [--keep DIR]

docs/bad-input.md promises that a mesh of millions of faces in a ``meshes`` folder costs bounded
time and memory rather than a refusal. This script measures it: for each icosphere subdivision
level (7: 328k faces, a detailed ShapeNet model; 9: 5.2M faces) it writes a binary PLY, then, in
a fresh process per mesh (so that each peak resident memory is its own), reads it with the
``meshes`` dataset's loader (``shapebench_meshes.loading.load_mesh_file``, with its second,
unprocessed parse that looks for NaN vertices) and preprocesses it with the default
``PreprocessParams`` (20,000 surface candidates, 100 viewpoints, 30,000 ground-truth points).
It prints faces, file size, seconds to read, seconds to preprocess and peak memory of each,
and the ratios of the largest against the first.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

_CHILD = r"""
import json, resource, sys, time
import numpy as np
from shapebench.preprocess.pipeline import PreprocessParams, prepare_mesh
from shapebench_meshes.loading import load_mesh_file
path = sys.argv[1]
t0 = time.perf_counter()
mesh = load_mesh_file(path)
t1 = time.perf_counter()
prepare_mesh(mesh, PreprocessParams(), np.random.default_rng(0))
t2 = time.perf_counter()
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"faces": len(mesh.faces), "read": t1 - t0, "prepare": t2 - t1, "peak_mb": peak}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--subdivisions", default="7,9", help="icosphere levels, comma-separated")
    ap.add_argument("--keep", type=Path, default=None, help="write the meshes here (reused)")
    args = ap.parse_args()

    import trimesh

    folder = args.keep or Path(tempfile.mkdtemp(prefix="shapebench-large-mesh-"))
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for level in [int(v) for v in args.subdivisions.split(",")]:
        path = folder / f"icosphere-{level}.ply"
        if not path.exists():
            trimesh.creation.icosphere(subdivisions=level).export(path)
        out = subprocess.run(
            [sys.executable, "-c", _CHILD, str(path)], capture_output=True, text=True, check=True
        )
        row = json.loads(out.stdout.strip().splitlines()[-1])
        row["mb"] = path.stat().st_size / 2**20
        rows.append(row)
        print(
            f"{row['faces']:>9,} faces  {row['mb']:7.1f} MB file  read {row['read']:6.1f} s  "
            f"preprocess {row['prepare']:6.1f} s  peak {row['peak_mb']:7.0f} MB",
            flush=True,
        )
    if len(rows) > 1:
        a, b = rows[0], rows[-1]
        print(
            f"ratio {b['faces'] / a['faces']:.1f}x faces: read {b['read'] / a['read']:.1f}x, "
            f"preprocess {b['prepare'] / a['prepare']:.1f}x, peak memory "
            f"{b['peak_mb'] / a['peak_mb']:.1f}x"
        )


if __name__ == "__main__":
    main()
