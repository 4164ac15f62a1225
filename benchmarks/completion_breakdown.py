"""Where a completion's time goes, per row: encoder, latent optimisation, meshing, scoring.

    .venv/bin/python benchmarks/completion_breakdown.py [--rows igr,msc,...] [--objects 3]
        [--contexts 50,1000] [--profile standard] [--threads 1] [--device auto|cpu|cuda]
        [--seed 0] [--cache-dir DIR] [-O KEY=VALUE ...] [--untrained]

Each row (default: the eight implicit rows; ``pcn``, ``pointr`` and ``gauss`` may be added) is
resolved at ``--profile`` as ``shapebench train -m ROW -d synthetic --seed S`` resolves it, and
its SHIPPED reference checkpoint for that key is loaded (copied to a temporary folder first, as
a workspace installs it): nothing is trained, and a row whose key has no reference is refused.
``--untrained`` instead times a freshly initialised network (a smoke test of the timing, not of a
trained field). The first ``--objects`` validation objects of the synthetic benchmark (held out
of every split) are completed from their contexts of each ``--contexts`` size as a sweep cell
completes them (all objects of one size in one ``complete_batch``, subnormals flushed, the
dataset's number of points) and scored with the default metrics, after one untimed warm-up
completion.

The stages are timed by wrapping the functions that do them for the span of the run: a context
manager replaces every reference to them in the loaded ``shapebench*`` modules with a timing
wrapper and puts the originals back after, so no method code (and no cell key) changes. Stage
times are exclusive (a stage called inside another is subtracted from it, the encoder holding
the latent optimisation of the auto-decoders); whatever no stage covers is ``other``. On CUDA
the device is synchronised before every clock reading. Nothing is logged.

* ``encoder/posterior``: the method's ``encode`` (the encoder, the posterior, the initial codes);
* ``latent optimisation``: ``optimise_latents`` (all its Adam steps);
* ``field evaluations``: the field calls of ``extract_mesh`` (the decoder on grid points);
* ``meshing bookkeeping``: the rest of ``extract_mesh`` (refinement, filling the volume);
* ``marching cubes``: ``_marching_cubes`` (scikit-image, and trimesh's vertex merge);
* ``mesh components``: the connected components (``largest_component`` and the count);
* ``surface sampling``: ``sample_mesh_points``;
* ``scoring``: ``score`` with the default metrics, as the runner scores an object;
* ``other``: the rest of ``complete_batch`` (the decode loop, posterior samples, copies).

Seconds are per completion (one object at one context size), averaged over objects and sizes;
the ``k=...`` columns split them by context size.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).parent))

IMPLICIT = (
    "igr",
    "deepsdf",
    "msc",
    "msc-noopt",
    "msc-hier",
    "msc-hier-noopt",
    "occnet",
    "convonet",
)
#: Rows timed "total only": no latent optimisation or mesh; their stages are encode and scoring.
OTHERS = ("pcn", "pointr", "gauss")
ENCODE = "encoder/posterior"
OPTIMISE = "latent optimisation"
FIELD = "field evaluations"
BOOKKEEPING = "meshing bookkeeping"
CUBES = "marching cubes"
COMPONENTS = "mesh components"
SAMPLING = "surface sampling"
SCORING = "scoring"
OTHER = "other"
STAGES = (ENCODE, OPTIMISE, FIELD, BOOKKEEPING, CUBES, COMPONENTS, SAMPLING, SCORING, OTHER)


class StageTimer:
    """Exclusive wall time per stage: a stage's time less that of the stages called inside it.

    Why exclusive: the stages nest (``encode`` holds the latent optimisation, ``extract_mesh``
    holds the field calls and marching cubes), and inclusive times would count the inner work
    twice, so the shares would not sum to one.
    """

    def __init__(self, sync: Callable[[], None] | None = None) -> None:
        self.seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self._children: list[float] = []  # per open stage, the time of the stages inside it
        self._sync = sync or (lambda: None)

    def clock(self) -> float:
        """``perf_counter`` after the device's queued work is done (CUDA runs asynchronously)."""
        self._sync()
        return time.perf_counter()

    def wrap(self, stage: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(fn)
        def timed(*args: Any, **kwargs: Any) -> Any:
            start = self.clock()
            self._children.append(0.0)
            try:
                return fn(*args, **kwargs)
            finally:
                elapsed = self.clock() - start
                inner = self._children.pop()
                self.seconds[stage] = self.seconds.get(stage, 0.0) + elapsed - inner
                self.calls[stage] = self.calls.get(stage, 0) + 1
                if self._children:
                    self._children[-1] += elapsed

        return timed

    def reset(self) -> None:
        self.seconds.clear()
        self.calls.clear()


def _replace_everywhere(original: Callable[..., Any], replacement: Callable[..., Any]) -> list:
    """Point every attribute of a loaded ``shapebench*`` module (plugins included) that is
    ``original`` at ``replacement``; return (module, name) of each, to put back.

    Why every module: a plugin or a sibling module that did ``from ... import f`` holds its own
    reference, which patching the defining module alone would miss."""
    patched = []
    for name, module in list(sys.modules.items()):
        if module is None or not name.startswith("shapebench"):
            continue
        for attr, value in list(vars(module).items()):
            if value is original:
                setattr(module, attr, replacement)
                patched.append((module, attr))
    return patched


@contextlib.contextmanager
def stages_timed(timer: StageTimer, method: Any) -> Iterator[None]:
    """The stage functions wrapped by ``timer`` for the span of the block (``method``'s
    ``encode`` on the instance); everything is restored after, also on an error."""
    import shapebench.geometry.meshing as meshing
    import shapebench.implicit.completion as completion

    original_extract = meshing.extract_mesh

    def extract_mesh(field_fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        return original_extract(timer.wrap(FIELD, field_fn), *args, **kwargs)

    wrapped = [
        (
            original_extract,
            timer.wrap(BOOKKEEPING, functools.wraps(original_extract)(extract_mesh)),
        ),
        (meshing._marching_cubes, timer.wrap(CUBES, meshing._marching_cubes)),
        (meshing.sample_mesh_points, timer.wrap(SAMPLING, meshing.sample_mesh_points)),
        (completion.optimise_latents, timer.wrap(OPTIMISE, completion.optimise_latents)),
        (completion.component_labels, timer.wrap(COMPONENTS, completion.component_labels)),
        (completion.largest_component, timer.wrap(COMPONENTS, completion.largest_component)),
    ]
    patched = []
    had_encode = "encode" in vars(method)
    try:
        for original, replacement in wrapped:
            patched += [(m, a, original) for m, a in _replace_everywhere(original, replacement)]
        if hasattr(method, "encode"):
            method.encode = timer.wrap(ENCODE, method.encode)
        yield
    finally:
        for module, attr, original in patched:
            setattr(module, attr, original)
        if not had_encode and "encode" in vars(method):
            del method.encode


@dataclass
class RowBreakdown:
    """One row's exclusive seconds per stage, per context size, summed over its objects."""

    row: str
    origin: str
    objects: int
    sizes: list[int]
    seconds: dict[int, dict[str, float]] = field(default_factory=dict)
    totals: dict[int, float] = field(default_factory=dict)
    failures: int = 0
    notes: str = ""

    def per_object(self, stage: str | None, size: int | None = None) -> float:
        """Seconds per completion of ``stage`` (None: every stage) at ``size`` (None: all)."""
        sizes = self.sizes if size is None else [size]
        if stage is None:
            total = sum(self.totals[s] for s in sizes)
        else:
            total = sum(self.seconds[s].get(stage, 0.0) for s in sizes)
        return total / (self.objects * len(sizes))

    def shares(self) -> dict[str, float]:
        total = self.per_object(None)
        return {s: self.per_object(s) / total if total > 0 else 0.0 for s in STAGES}


def load_row(row: str, args: argparse.Namespace, workdir: Path) -> tuple[Any, Any, str]:
    """The method of ``row`` ready to complete, the dataset, and where its weights come from.

    Resolved as ``shapebench train`` resolves the reference training of that row (the profile,
    the seed, the ``-O`` options, one device), so the key is the one a sweep looks up."""
    from shapebench.api.options import parse_assignments
    from shapebench.train.references import install
    from shapebench.train.ticket import find_reference
    from shapebench.train.training import reference_training

    cache = Path(args.cache_dir) if args.cache_dir else None
    options = parse_assignments(args.O, "-O")
    training = reference_training(
        row, "synthetic", args.profile, args.seed, workdir, cache, options
    )
    resolved, dataset = training.method, training.dataset
    method = resolved.cls(resolved.options)
    if not resolved.cls.trains:
        return method, dataset, "no training"
    if args.untrained:
        from ladder import untrained

        return untrained(method, 1, args.seed), dataset, "untrained"
    if resolved.cls.fit_ignores_trainer:
        raise SystemExit(
            f"completion_breakdown: {row} builds an index from the training split on "
            "its first run; it is not timed here"
        )
    ref = find_reference(resolved, training.key)
    if ref is None:
        raise SystemExit(
            f"completion_breakdown: {row} has no shipped reference checkpoint for key "
            f"{training.key} (profile {args.profile}, seed {args.seed}, -O {options or 'none'}); "
            "this benchmark never trains: use a shipped key (uncommitted edits to the method's "
            "code move it), or --untrained"
        )
    family = resolved.cls.checkpoint_family or resolved.name
    method.load_checkpoint(install(ref, workdir / family / training.key))
    return method, dataset, ref.origin


def place(method: Any, device: str) -> None:
    """Move ``method``'s network to ``device`` (``auto``: where ``load_checkpoint`` put it, the
    GPU when there is one)."""
    import torch

    if device == "auto" or getattr(method, "module", None) is None:
        return
    method.device = torch.device(device)
    method.module.to(method.device)


def time_row(row: str, args: argparse.Namespace, sizes: list[int], workdir: Path) -> RowBreakdown:
    """Complete and score the validation objects' contexts of every size; the stage times."""
    import torch

    from shapebench.api.contexts import ContextStore
    from shapebench.api.protocol import Protocol
    from shapebench.evaluation.completion import keep_freed_memory, subnormals_flushed
    from shapebench.evaluation.scoring import score
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_metrics

    method, dataset, origin = load_row(row, args, workdir / row)
    place(method, args.device)
    cuda = getattr(method, "device", None) is not None and method.device.type == "cuda"
    timer = StageTimer(torch.cuda.synchronize if cuda else None)
    protocol = Protocol()
    metrics = resolve_metrics(get_registry(), None, dataset)
    refs = dataset.objects("validation")[: args.objects]
    objects = [dataset.load(ref) for ref in refs]
    store = ContextStore(dataset.cache_root, dataset.data_fingerprint())
    contexts = {
        k: [store.context(d, k, args.seed, protocol=protocol) for d in objects] for k in sizes
    }
    n_points = dataset.points_to_complete(objects[0])
    out = RowBreakdown(row, origin, len(objects), sizes)
    opt_steps = getattr(method.options, "opt_steps", None) if method.options else None
    resolution = getattr(method.options, "mesh_resolution", None) if method.options else None
    if getattr(method, "optimise", True) and opt_steps is not None:
        out.notes += f"opt_steps {opt_steps}  "
    if resolution is not None:
        out.notes += f"mesh_resolution {resolution}  "
    field_points = 0.0
    keep_freed_memory()  # as the runner completes (complete_chunk)
    with subnormals_flushed():  # as the runner completes (complete_chunk); it scores unflushed
        method.complete_batch(contexts[sizes[0]][:1], n_points)  # warm-up: imports, allocations
    with stages_timed(timer, method):
        scorer = timer.wrap(SCORING, score)
        for k in sizes:
            timer.reset()
            start = timer.clock()
            with subnormals_flushed():
                outputs = method.complete_batch(contexts[k], n_points)
            for output, data, ctx in zip(outputs, objects, contexts[k], strict=True):
                result, _ = scorer(output, data, ctx, metrics, protocol.scale)
                out.failures += result["status"] != "ok"
                field_points += float(result.get("info.mesh_evaluations", 0.0))
            out.totals[k] = timer.clock() - start
            out.seconds[k] = dict(timer.seconds)
            out.seconds[k][OTHER] = out.totals[k] - sum(timer.seconds.values())
    if field_points:
        out.notes += f"field points/object {field_points / (len(objects) * len(sizes)):,.0f}"
    return out


def print_row(r: RowBreakdown) -> None:
    shares = r.shares()
    head = f"{'stage':<22} {'s/object':>9} {'share':>7}"
    head += "".join(f" {'k=' + str(k) + ' s':>10}" for k in r.sizes)
    failed = f", {r.failures} failed" if r.failures else ""
    print(f"\n{r.row} ({r.origin}; {r.objects} objects x {len(r.sizes)} sizes{failed}) {r.notes}")
    print(head)
    print("-" * len(head))
    for stage in STAGES:
        if not any(stage in r.seconds[k] for k in r.sizes):
            continue
        cells = "".join(f" {r.per_object(stage, k):>10.4f}" for k in r.sizes)
        print(f"{stage:<22} {r.per_object(stage):>9.4f} {shares[stage]:>6.1%}{cells}")
    cells = "".join(f" {r.per_object(None, k):>10.4f}" for k in r.sizes)
    print(f"{'total':<22} {r.per_object(None):>9.4f} {sum(shares.values()):>6.1%}{cells}")


def main(argv: list[str] | None = None) -> list[RowBreakdown]:
    """Print one table per row; return the breakdowns."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", default=",".join(IMPLICIT), help="comma-separated methods")
    parser.add_argument("--objects", type=int, default=3, help="validation objects per row")
    parser.add_argument("--contexts", default="50,1000", help="comma-separated context sizes")
    parser.add_argument("--profile", default="standard")
    parser.add_argument("--threads", type=int, default=1, help="torch's intra-op threads")
    parser.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    parser.add_argument("--seed", type=int, default=0, help="reference seed and context seed")
    parser.add_argument("--cache-dir", default=None)
    parser.add_argument("-O", action="append", default=[], help="method option KEY=VALUE")
    parser.add_argument("--untrained", action="store_true", help="fresh networks, no checkpoint")
    args = parser.parse_args(argv)

    import torch

    rows = [r.strip() for r in args.rows.split(",") if r.strip()]
    try:
        sizes = [int(k) for k in args.contexts.split(",") if k.strip()]
    except ValueError:
        raise SystemExit(
            "completion_breakdown: --contexts must be comma-separated integers, got "
            f"{args.contexts!r}"
        ) from None
    if not rows or not sizes or min(sizes) < 1 or args.objects < 1 or args.threads < 1:
        raise SystemExit(
            "completion_breakdown: --rows, --contexts (>= 1), --objects and "
            "--threads (>= 1) must be non-empty and positive"
        )
    if args.device == "cuda" and not torch.cuda.is_available():
        raise SystemExit("completion_breakdown: --device cuda, but torch sees no CUDA device")
    before = torch.get_num_threads()
    torch.set_num_threads(args.threads)
    device = (
        args.device if args.device != "auto" else ("cuda" if torch.cuda.is_available() else "cpu")
    )
    print(
        f"completion breakdown: profile {args.profile}, {args.objects} validation objects, "
        f"contexts {','.join(map(str, sizes))}, {args.threads} torch thread(s), {device}, "
        f"torch {torch.__version__}; seconds per completion (object x context size), "
        "exclusive per stage"
    )
    results = []
    try:
        with tempfile.TemporaryDirectory(prefix="breakdown-") as tmp:
            for row in rows:
                results.append(time_row(row, args, sizes, Path(tmp)))
                print_row(results[-1])
                sys.stdout.flush()
    finally:
        torch.set_num_threads(before)
    if len(results) > 1:
        print(f"\n{'row':<16} {'s/object':>9}")
        for r in results:
            print(f"{r.row:<16} {r.per_object(None):>9.4f}")
    return results


if __name__ == "__main__":
    main()
