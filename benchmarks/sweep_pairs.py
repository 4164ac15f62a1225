"""Rewrite a sweep file with one method entry per (method entry, dataset) pair.

    .venv/bin/python benchmarks/sweep_pairs.py SWEEP_FILE --out PAIRS.yaml [--max-steps N]

``shapebench sweep --launcher local -j N`` starts worker ``i`` at the ``i``-th method entry, and a
worker trains the checkpoints of its entry one dataset after the other. With one entry per pair
and one worker per entry, every training of the sweep starts at once (what a GPU machine lent
for minutes needs: benchmarks/gpu_data_scaling.sh). The cells are the same as the original
file's: a cell's key does not depend on the sweep file. ``--max-steps`` leaves out the entries
whose ``steps`` option is larger (and says which).
"""

from __future__ import annotations

import argparse
import sys

import yaml


def pairs(spec: dict, max_steps: int | None) -> tuple[list[dict], list[dict]]:
    """The (kept, left out) method entries, one per (entry, dataset label) pair."""
    labels = [d.get("label", d["name"]) if isinstance(d, dict) else d for d in spec["datasets"]]
    kept: list[dict] = []
    left_out: list[dict] = []
    for entry in spec["methods"]:
        entry = {"name": entry} if isinstance(entry, str) else dict(entry)
        steps = int(entry.get("options", {}).get("steps", 0) or 0)
        over = max_steps is not None and steps > max_steps
        for label in entry.pop("datasets", labels):
            (left_out if over else kept).append({**entry, "datasets": [label]})
    return kept, left_out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sweep_file")
    parser.add_argument("--out", required=True)
    parser.add_argument("--max-steps", type=int, default=None)
    args = parser.parse_args()
    with open(args.sweep_file) as f:
        spec = yaml.safe_load(f)
    kept, left_out = pairs(spec, args.max_steps)
    spec["methods"] = kept
    with open(args.out, "w") as f:
        yaml.safe_dump(spec, f, sort_keys=False)
    print(f"{len(kept)} (method, dataset) entries in {args.out}", file=sys.stderr)
    for entry in left_out:
        print(f"  left out (steps over {args.max_steps}): {entry}", file=sys.stderr)


if __name__ == "__main__":
    main()
