"""How the store's readers scale with the number of cells (issue 59, "Scale, measured").

For each N of ``--sizes`` the script fills a FRESH workspace (a temporary folder) with N finished
cells of one sweep file and times, in this process, the four commands that read every cell:

* ``shapebench sweep FILE --status`` (one cell-key lookup per planned cell),
* ``shapebench leaderboard -d synthetic`` (reads every cell and its ``per_object.csv``),
* ``shapebench runs --json --limit 10N`` (every cell run, paged; a limit above N, since
  ``--limit 0`` lists no run at all),
* ``shapebench merge WS --into EMPTY`` (copies every run, artifacts included, into another
  empty store).

It prints the seconds of each command at each N and the seconds per 1,000 cells, with the
ratio of that rate to the smallest N's (1.0: linear; above it the command bends), and checks
that no command silently dropped cells: ``--status`` counts N cells, N finished; the
leaderboard's per-object rows are N x objects per cell; ``runs --json`` lists N cells; merge
adds N cell runs. A command that saw fewer exits the script with an error.

How the N cells are written, and why: computing N real cells of even the cheapest method
(``gauss`` on the tiny synthetic benchmark) costs seconds each (contexts, scoring, pictures), an
hours for 10,000. So the script computes REAL cells once: the sweep file's seed 0 (every
split and context size), through ``shapebench sweep``. Every other cell is a SYNTHETIC COPY of
the real cell of its split and context size: its tags are built by the store's own
:func:`shapebench.evaluation.plan.cell_record` from the sweep's own plan (so its cell key is the
one ``sweep --status`` looks up, and its seed is the sweep's), over the real cell's provenance
tags; its params are its own config (``flatten(cfg)``, as the runner logs them); its metrics and
its ``per_object.csv`` are the real cell's, the metrics logged through the runner's
:class:`Tracker` (``log_batch``), the file copied into the run's artifact folder where MLflow's
``log_artifact`` would put it (the benchmark's stores are local); it hangs under the real
cell's parent run. To the four commands a copy reads like a real cell, except that it carries
only ``per_object.csv`` (no contexts or pictures), so merge copies fewer files than it would for
real cells. The write rate is printed too, for the record.

Run it from the repository root (60,000 cells take long; it is opt-in):

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_scale.py [--sizes 1000,10000] [--page N]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

SPLITS = ("trained", "novel")
CONTEXTS = (50, 100)
#: Cells per seed of the sweep file: a size N must be a multiple of it.
PER_SEED = len(SPLITS) * len(CONTEXTS)
DATASET_OPTIONS = {
    "test_per_category": 1,
    "train_per_category": 1,
    "surface_candidates": 3000,
    "gt_points": 2000,
}
#: MLflow's tag of a run's name (the template's would name every copy "seed=0").
RUN_NAME_TAG = "mlflow.runName"
COMMANDS = ("sweep --status", "leaderboard", "runs --json", "merge")


class ScaleError(Exception):
    """A bad argument or a command that did not see every cell: one line, exit status 1."""


@dataclass
class Measure:
    """One N: seconds to write its cells and of each command, and what each command counted."""

    cells: int
    write_seconds: float = 0.0
    seconds: dict[str, float] = field(default_factory=dict)
    counted: dict[str, str] = field(default_factory=dict)


def sweep_text(seeds: int) -> str:
    options = ", ".join(f"{k}: {v}" for k, v in DATASET_OPTIONS.items())
    return (
        "name: scale\nmethods: [gauss]\n"
        f"datasets: [{{name: synthetic, options: {{{options}}}}}]\n"
        f"splits: [{', '.join(SPLITS)}]\ncontexts: [{', '.join(map(str, CONTEXTS))}]\n"
        f"seeds: [{', '.join(map(str, range(seeds)))}]\n"
    )


def invoke(args: list[str]) -> str:
    """Run one ``shapebench`` command in this process (so a patched page size applies) and
    return its output; a failing command is raised."""
    from click.testing import CliRunner

    from shapebench.cli.app import cli

    result = CliRunner().invoke(cli, args, catch_exceptions=False)
    if result.exit_code != 0:
        raise ScaleError(f"shapebench {' '.join(args)} exited {result.exit_code}: {result.output}")
    return result.output


def planned(sweep: Path, settings: Any) -> Iterator[tuple[Any, str, int, int, dict, str]]:
    """``(plan, split, seed, size, cfg, key)`` of every cell of ``sweep``, planned as
    :func:`shapebench.sweeps.plan.plan_sweep` plans them (the same keys ``--status`` reads)."""
    from shapebench.evaluation.orchestrate import resolve_request, seed_plans
    from shapebench.evaluation.plan import planned_cells
    from shapebench.sweeps.spec import load_sweep, pairs, request, sweep_methods
    from shapebench.train.training import trainer_options

    spec = load_sweep(sweep)
    for _, ds, _, m in pairs(spec, sweep_methods(spec)):
        req = request(spec, m, ds, quiet=True)
        resolved = resolve_request(req, settings)
        for sp in seed_plans(req, resolved, settings, lambda s: trainer_options(settings, s)):
            for split in sp.plan.splits:
                for seed, size, cfg, key in planned_cells(sp.plan, split):
                    yield sp.plan, split, seed, size, cfg, key


def write_cells(ws: Path, cache: Path, cells: int, echo: Callable[[str], None]) -> Path:
    """A workspace ``ws`` holding the ``cells`` finished cells of a sweep file (returned): seed
    0's computed, the others synthetic copies of them (see the module's docstring)."""
    from shapebench.config import make_settings
    from shapebench.evaluation.plan import cell_record
    from shapebench.store import records as rec
    from shapebench.store.tracking import Tracker, experiment_name, flatten, local_artifact_path

    store = ["--workspace", str(ws), "--cache-dir", str(cache)]
    seed0 = ws.parent / f"{ws.name}-seed0.yaml"
    seed0.write_text(sweep_text(1))
    invoke(["sweep", str(seed0), "-q", *store])
    sweep = ws.parent / f"{ws.name}.yaml"
    sweep.write_text(sweep_text(cells // PER_SEED))
    tracker = Tracker(make_settings(f"sqlite:///{ws / 'mlflow.db'}", cache, None, ws))
    templates: dict[tuple[str, int], tuple[Any, Path]] = {}
    spare = Path(tempfile.mkdtemp(dir=ws.parent))
    for run_id, _, record in [
        c for split in SPLITS for c in tracker.finished_cells(tracker.experiment_id(
            experiment_name("synthetic", split), create=False) or "")
    ]:  # fmt: skip
        dst = spare / run_id
        dst.mkdir()
        csv = tracker.download_artifact(run_id, "per_object.csv", dst)
        templates[(record.split, record.context_size)] = (tracker.client.get_run(run_id), csv)
    if len(templates) != PER_SEED:
        raise ScaleError(f"seed 0's sweep left {len(templates)} cells, not {PER_SEED}")
    written, start = 0, time.perf_counter()
    for plan, split, seed, size, cfg, key in planned(sweep, tracker.settings):
        if seed == 0:
            continue  # computed
        run, csv = templates[(split, size)]
        tags = {**run.data.tags, **cell_record(plan, split, size, seed, key, cfg).to_tags()}
        tags[rec.KIND_TAG] = rec.CELL_KIND
        tags[RUN_NAME_TAG] = re.sub(r"seed=\d+", f"seed={seed}", run.info.run_name or "")
        info = tracker.client.create_run(run.info.experiment_id, tags=tags).info
        tracker.log_params(info.run_id, flatten("", cfg))
        tracker.log_metrics(info.run_id, dict(run.data.metrics), step=size)
        # Into the run's artifact folder on this disk, as MLflow's log_artifact would put it,
        # without its run lookups (a third of a copy's time).
        folder = local_artifact_path(info.artifact_uri)
        assert folder is not None, info.artifact_uri  # a workspace's store keeps them on disk
        folder.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(csv, folder / csv.name)
        tracker.end(info.run_id)
        written += 1
        if written % 1000 == 0:
            spent = time.perf_counter() - start
            echo(f"  {written + PER_SEED} of {cells} cells written ({spent:.0f} s of copying)")
    shutil.rmtree(spare)
    echo(f"  N={cells}: {written} copies written in {time.perf_counter() - start:.1f} s")
    return sweep


def measure(cells: int, cache: Path, root: Path, echo: Callable[[str], None]) -> Measure:
    """Write ``cells`` cells into a fresh workspace under ``root``, then time and check the four
    commands on it."""
    ws, into, boards = root / f"ws-{cells}", root / f"into-{cells}", root / f"boards-{cells}"
    store = ["--workspace", str(ws), "--cache-dir", str(cache)]
    where = store[:2]  # the commands that only read the store take no --cache-dir
    out = Measure(cells)
    start = time.perf_counter()
    sweep = write_cells(ws, cache, cells, echo)
    out.write_seconds = time.perf_counter() - start

    def timed(name: str, args: list[str]) -> str:
        start = time.perf_counter()
        text = invoke(args)
        out.seconds[name] = time.perf_counter() - start
        echo(f"  N={cells}: {name}: {out.seconds[name]:.1f} s")
        return text

    text = timed("sweep --status", ["sweep", str(sweep), "--status", *store])
    found = re.search(r"(\d+) cells: (\d+) finished", text)
    total, finished = (int(found[1]), int(found[2])) if found else (0, 0)
    out.counted["sweep --status"] = f"{total} cells, {finished} finished"
    expect(total == finished == cells, "sweep --status", text.splitlines()[0], cells)

    timed("leaderboard", ["leaderboard", "-d", "synthetic", "--reference", "gauss",
                          "--out", str(boards), *where])  # fmt: skip
    objects = objects_per_cell(ws, cache)
    rows, seen = leaderboard_cells(boards, objects)
    want = cells // len(SPLITS) * sum(objects.values())
    out.counted["leaderboard"] = f"{rows} (object, seed) rows = {seen} cells"
    expect(rows == want and seen == cells, "leaderboard", f"{rows} per-object rows", want)

    text = timed("runs --json", ["runs", "--json", "--limit", str(10 * cells), *where])
    listed = len(json.loads(text))
    out.counted["runs --json"] = f"{listed} runs"
    expect(listed == cells, "runs --json", f"{listed} runs", cells)

    into.mkdir()
    text = timed("merge", ["merge", str(ws), "--into", f"sqlite:///{into / 'mlflow.db'}",
                           "--workspace", str(into)])  # fmt: skip
    found = re.search(r"(\d+) cell runs added", text)
    added = int(found[1]) if found else 0
    out.counted["merge"] = f"{added} cell runs added"
    expect(added == cells, "merge", text.strip().splitlines()[-1], cells)
    return out


def leaderboard_cells(boards: Path, objects: dict[str, int]) -> tuple[int, int]:
    """The per-object rows behind the raw leaderboards in ``boards`` (the sum of column ``n``,
    the (object, seed) pairs of a row at a context size, over every split's table) and the cells
    they make (each split's rows over its ``objects`` per cell)."""
    import pandas as pd

    rows = cells = 0
    for split in SPLITS:
        board = pd.read_csv(boards / f"synthetic-{split}.csv")
        n = int(board.loc[board["kind"] == "raw", "n"].sum())
        rows += n
        cells += n // objects[split]
    return rows, cells


def objects_per_cell(ws: Path, cache: Path) -> dict[str, int]:
    """How many objects one cell of each split scores (every cell of a split scores the same
    ones): the rows of one of its cells' ``per_object.csv``."""
    from shapebench.config import make_settings
    from shapebench.store import records as rec
    from shapebench.store.tracking import Tracker, experiment_name

    tracker = Tracker(make_settings(f"sqlite:///{ws / 'mlflow.db'}", cache, None, ws))
    out = {}
    for split in SPLITS:
        exp = tracker.experiment_id(experiment_name("synthetic", split), create=False) or ""
        cell = f"tags.`{rec.KIND_TAG}` = '{rec.CELL_KIND}'"
        (run,) = tracker.client.search_runs([exp], cell, max_results=1)
        with tempfile.TemporaryDirectory() as tmp:
            path = tracker.download_artifact(run.info.run_id, "per_object.csv", Path(tmp))
            out[split] = len(path.read_text().splitlines()) - 1
    return out


def expect(ok: bool, command: str, saw: str, want: int) -> None:
    if not ok:
        raise ScaleError(f"{command} did not see every cell: it says {saw!r}, expected {want}")


def table(measures: list[Measure]) -> list[str]:
    """Seconds per command at each N, seconds per 1,000 cells, and that rate over the first
    N's (1.0: linear in N)."""
    lines = [f"{'command':<16}" + "".join(f"{'N=' + str(m.cells):>12}" for m in measures)]
    rows = [("write cells", [m.write_seconds for m in measures])]
    rows += [(c, [m.seconds[c] for m in measures]) for c in COMMANDS]
    for name, values in rows:
        lines.append(f"{name:<16}" + "".join(f"{v:>11.1f}s" for v in values))
    lines.append("seconds per 1,000 cells (in brackets: over the first N's; 1.0 is linear)")
    for name, values in rows:
        rates = [v / m.cells * 1000 for v, m in zip(values, measures, strict=True)]
        cells = [f"{r:.2f} ({r / rates[0]:.1f}x)" for r in rates]
        lines.append(f"{name:<16}" + "".join(f"{c:>16}" for c in cells))
    lines.append("counted: " + "; ".join(
        f"N={m.cells}: " + ", ".join(f"{c}: {m.counted[c]}" for c in COMMANDS) for m in measures
    ))  # fmt: skip
    return lines


def parse_sizes(text: str) -> list[int]:
    try:
        sizes = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise ScaleError(f"--sizes must be comma-separated integers, got {text!r}") from None
    bad = [n for n in sizes if n < PER_SEED or n % PER_SEED]
    if not sizes or bad:
        raise ScaleError(
            f"--sizes {text!r}: each size must be a positive multiple of {PER_SEED} "
            f"({len(SPLITS)} splits x {len(CONTEXTS)} context sizes per seed)"
        )
    return sizes


def run(sizes: list[int], page: int | None, cache: Path | None, keep: Path | None) -> list[str]:
    """Measure every size; the printed table's lines. ``page``: MLflow's page size for the
    store's searches (:data:`shapebench.store.paging.PAGE`), lowered to exercise the paging."""
    from shapebench.store import paging

    default_page = paging.PAGE
    if page is not None:
        paging.PAGE = page
    root = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="bench-scale-"))
    root.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    try:
        cache = cache or root / "cache"
        measures = [measure(n, cache, root, print) for n in sizes]
    finally:
        paging.PAGE = default_page  # a caller in the same process (a test) reads the default
        if not keep:
            shutil.rmtree(root, ignore_errors=True)
    return table(measures)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1000,10000", help="cells per store (60000: long)")
    parser.add_argument("--page", type=int, default=None, help="MLflow search page size")
    parser.add_argument("--cache-dir", type=Path, default=None, help="shapebench data cache")
    parser.add_argument("--keep", type=Path, default=None, help="keep the stores in this folder")
    args = parser.parse_args(argv)
    try:
        sizes = parse_sizes(args.sizes)
        if args.page is not None and args.page < 1:
            raise ScaleError(f"--page must be at least 1, got {args.page}")
        lines = run(sizes, args.page, args.cache_dir, args.keep)
    except ScaleError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
