"""The checks of a method: its interface and options; a trainable method trains for a few steps
and a fresh instance reloads its checkpoint; it completes 50-point contexts into finite ``(n, 3)``
arrays of a sensible size, also when the points are duplicated or all the same (or raises, a
failed object); it gives identical points for the same seed; it uses one Lightning namespace."""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from shapebench.conformance.framework import (
    CONTEXT_SIZE,
    SKIP,
    CheckEnv,
    CheckFailed,
    CheckResult,
    CheckSkipped,
    Component,
    class_path,
    describe,
    run_check,
    skip_rest,
    tiny_values,
)
from shapebench.conformance.options import (
    check_options_class,
    options_message,
    options_roundtrip,
)

#: Points further than this from the origin are not a completion of a unit-sphere shape.
MAX_RADIUS = 10.0
#: A completion has at least the context's size and at most this many times ``n_points``.
MAX_POINTS_FACTOR = 10

#: Method options applied where the options have that field, for methods that declare no
#: ``check_options``: one epoch of small batches, coarse meshes.
TINY_METHOD_OPTIONS: dict[str, Any] = {"epochs": 1, "batch_shapes": 4, "mesh_resolution": 32}


def method_check_options(cls: type) -> dict[str, Any]:
    """The tiny options a method is checked with: its ``check_options``, else
    :data:`TINY_METHOD_OPTIONS` where it has those fields."""
    declared = getattr(cls, "check_options", None)
    if declared:
        return dict(declared)
    options_cls = getattr(cls, "Options", None)
    if options_cls is None or not dataclasses.is_dataclass(options_cls):
        return {}
    return tiny_values(options_cls, TINY_METHOD_OPTIONS)


_METHOD_CHECKS = (
    "interface",
    "options",
    "train",
    "checkpoint",
    "complete",
    "degenerate",
    "deterministic",
    "lightning",
)


def method_checks(
    comp: Component, env: CheckEnv, overrides: dict[str, Any], data_root: Any
) -> Iterator[CheckResult]:
    """The checks of a method after ``imports``, one result at a time (``data_root`` is for
    datasets only)."""
    before = {m for m in ("lightning", "pytorch_lightning") if m in sys.modules}
    yield from _method_steps(comp, env, overrides)
    yield run_check("lightning", lambda: _lightning(before))[0]


def _method_steps(
    comp: Component, env: CheckEnv, overrides: dict[str, Any]
) -> Iterator[CheckResult]:
    """Every check of a method but ``lightning``, which looks at what these imported."""
    res, cls = run_check("interface", lambda: _method_interface(comp))
    yield res
    if cls is None:
        yield from skip_rest(_METHOD_CHECKS[1:-1], "the class did not load")
        return
    owner = f"method {comp.name!r}"
    res, options = run_check("options", lambda: _method_options(cls, owner, overrides))
    yield res
    if options is None:
        yield from skip_rest(_METHOD_CHECKS[2:-1], "no usable options")
        return
    if getattr(cls, "check_needs", ""):
        yield from skip_rest(_METHOD_CHECKS[2:-1], f"needs {cls.check_needs}")
        return
    path = trained = None
    if cls.trains:
        res, path = run_check("train", lambda: _train(cls, options, env, comp.name))
        yield res
        res, trained = run_check("checkpoint", lambda: _reload(cls, options, path))
        yield res
        if trained is None:
            yield from skip_rest(("complete", "degenerate", "deterministic"), "no trained instance")
            return
    else:
        yield from skip_rest(("train", "checkpoint"), "does not train")
    res, outputs = run_check(
        "complete", lambda: _complete(trained if trained is not None else cls(options), env)
    )
    yield res
    if outputs is None:
        yield CheckResult("degenerate", SKIP, "nothing completed")
    else:
        method = trained if trained is not None else cls(options)
        yield run_check("degenerate", lambda: _degenerate(method, env))[0]
    if outputs is None:
        yield CheckResult("deterministic", SKIP, "nothing completed")
    else:
        res, _ = run_check(
            "deterministic", lambda: _deterministic(cls, options, path, env, outputs)
        )
        yield res


def _method_interface(comp: Component) -> tuple[str, type]:
    from shapebench.api.method import Method
    from shapebench.api.types import Supervision

    cls = comp.load()
    if not (isinstance(cls, type) and issubclass(cls, Method)):
        raise CheckFailed(f"{cls!r} is not a subclass of shapebench.Method")
    abstract = sorted(getattr(cls, "__abstractmethods__", ()))
    if abstract:
        raise CheckFailed(f"{cls.__name__} does not implement {', '.join(abstract)}")
    if cls.trains:
        for hook in ("fit", "load_checkpoint"):
            if getattr(cls, hook) is getattr(Method, hook):
                raise CheckFailed(f"{cls.__name__} declares trains=True but has no {hook}()")
    bad = [s for s in cls.supervision if not isinstance(s, Supervision)]
    if bad:
        raise CheckFailed(f"supervision holds {bad!r}: use shapebench.Supervision members")
    size = cls.batch_size
    if not isinstance(size, int) or isinstance(size, bool) or size < 1:
        raise CheckFailed(f"batch_size={size!r} must be a positive integer")
    check_options_class(cls, f"method {comp.name!r}")
    kind = "trainable " if cls.trains else ""
    return f"{kind}{class_path(cls)}", cls


def _method_options(cls: type, owner: str, overrides: dict[str, Any]) -> tuple[str, Any]:
    from shapebench.api import options as opts

    options_roundtrip(cls.Options, {}, owner)
    tiny = {**method_check_options(cls), **overrides}
    options = options_roundtrip(cls.Options, tiny, owner)
    if getattr(cls, "check_needs", ""):
        # It cannot be built without the user's input it needs (its own tests build it).
        return options_message(cls.Options, tiny), options
    # The config a run logs holds the options as the instance resolved them (recipe defaults
    # filled in); built again from that config, the method must resolve the same options.
    effective = cls(options).options
    logged = json.loads(json.dumps(opts.as_dict(effective)))
    again = cls(opts.build(cls.Options, logged, owner)).options
    if again != effective:
        raise CheckFailed(
            "the options a run logs do not build the same method again: "
            f"{opts.as_dict(effective)} -> {opts.as_dict(again)}"
        )
    return options_message(cls.Options, tiny), options


def _trainer(options: Any) -> Any:
    from shapebench.api.method import TrainerOptions

    epochs = getattr(options, "epochs", None)
    return TrainerOptions(
        accelerator="cpu", devices=1, max_epochs=epochs or 1, seed=0, checkpoint_minutes=0.0
    )


def _train(cls: type, options: Any, env: CheckEnv, name: str) -> tuple[str, Path]:
    from shapebench.api.method import TrainingContext

    dataset = env.tiny_dataset()
    workdir = env.workdir / "train" / name
    workdir.mkdir(parents=True, exist_ok=True)
    trainer = _trainer(options)
    path = cls(options).fit(TrainingContext(dataset, trainer, workdir, "", None, quiet=True))
    if path is None or not Path(path).exists():
        raise CheckFailed(f"fit() returned {path!r}, which does not exist: return the checkpoint")
    n = len(dataset.objects("train"))
    return (
        f"{trainer.max_epochs} epoch(s) on {n} objects of the tiny synthetic dataset -> "
        f"{Path(path).name}",
        Path(path),
    )


def _reload(cls: type, options: Any, path: Path | None) -> tuple[str, Any]:
    if path is None:
        raise CheckSkipped("training failed")
    instance = cls(options)
    instance.load_checkpoint(Path(path))
    return f"a fresh instance loads {Path(path).name}", instance


def _complete_all(method: Any, contexts: list, n_points: int) -> list[Any]:
    """Outputs per context, in chunks of the method's ``batch_size`` like a run."""
    chunk = max(1, int(getattr(method, "batch_size", 1)))
    out: list[Any] = []
    for i in range(0, len(contexts), chunk):
        part = contexts[i : i + chunk]
        got = method.complete_batch(part, n_points)
        if not isinstance(got, list) or len(got) != len(part):
            raise CheckFailed(
                f"complete_batch returned {_size(got)} results for {len(part)} "
                "contexts: return one per context, in order"
            )
        out += got
    return out


def _size(value: Any) -> str:
    return str(len(value)) if hasattr(value, "__len__") else repr(value)


def _complete(method: Any, env: CheckEnv) -> tuple[str, list[Any]]:
    import numpy as np

    contexts, n_points = env.contexts()
    before = [c.points.copy() for c in contexts]
    outputs = _complete_all(method, contexts, n_points)
    for ctx, points in zip(contexts, before, strict=True):
        if not np.array_equal(ctx.points, points):
            raise CheckFailed(
                f"complete() changed the context points of {ctx.ref.id} in place: "
                "every method is given the same arrays"
            )
    raised = []
    sizes = []
    for ctx, out in zip(contexts, outputs, strict=True):
        if isinstance(out, Exception):
            raised.append(f"{ctx.ref.id}: {describe(out)}")
            continue
        problem = completion_problem(out, n_points)
        if problem:
            raise CheckFailed(f"{ctx.ref.id}: {problem}")
        sizes.append(len(out.points))
    if not sizes:
        raise CheckFailed(f"every context failed: {'; '.join(raised)}")
    message = (
        f"{len(sizes)} context(s) of {CONTEXT_SIZE} points -> finite (n, 3) points, "
        f"n = {', '.join(map(str, sorted(set(sizes))))} (asked for {n_points})"
    )
    if raised:  # a tiny trained network may find no surface on some object: reported, allowed
        message += f"; {len(raised)} failed: {'; '.join(raised)}"
    return message, outputs


def _degenerate(method: Any, env: CheckEnv) -> str:
    """Contexts real data produces that a method may not expect: half the points duplicates of
    the other half (a scan fused twice), and every point the same (a scanner's dead pixel). A
    method may complete them or raise (the run records that object as failed, with the reason);
    it may not return NaN or points far outside the unit sphere."""
    import numpy as np

    contexts, n_points = env.contexts()
    ctx = contexts[0]
    half = ctx.points[: (len(ctx.points) + 1) // 2]
    cases = {
        "duplicated": np.concatenate([half, half])[: len(ctx.points)],
        "identical": np.repeat(ctx.points[:1], len(ctx.points), axis=0),
    }
    said = []
    for name, points in cases.items():
        normals = None
        if ctx.normals is not None:  # the normals of the points the rows were copied from
            rows = (
                np.arange(len(points)) % len(half)
                if name == "duplicated"
                else np.zeros(len(points), dtype=int)
            )
            normals = ctx.normals[rows]
        case = dataclasses.replace(ctx, points=points.astype(np.float32), normals=normals)
        (out,) = _complete_all(method, [case], n_points)
        if isinstance(out, Exception):
            said.append(f"{name}: raised ({describe(out)}), recorded as a failed object")
            continue
        problem = completion_problem(out, n_points)
        if problem:
            raise CheckFailed(f"a context of {len(points)} {name} points: {problem}")
        said.append(f"{name}: {len(out.points)} finite points")
    return f"contexts of {len(ctx.points)} points, " + "; ".join(said)


def completion_problem(completion: Any, n_points: int) -> str | None:
    """Why ``completion`` is not a usable completion for ``n_points`` ground-truth points."""
    import numpy as np

    from shapebench.api.types import Completion

    if not isinstance(completion, Completion):
        return f"returned {type(completion).__name__}, not a Completion"
    clouds = [("points", completion.points)]
    clouds += [(f"samples[{i}]", s) for i, s in enumerate(completion.samples or [])]
    for what, cloud in clouds:
        pts = np.asarray(cloud)
        if pts.ndim != 2 or pts.shape[1] != 3:
            return f"{what} has shape {pts.shape}, expected (n, 3)"
        if not np.issubdtype(pts.dtype, np.floating):
            return f"{what} has dtype {pts.dtype}, expected float32"
        bad = int((~np.isfinite(pts)).any(axis=1).sum())
        if bad:
            where = "" if what == "points" else f" of {what}"
            return f"{bad} of {len(pts)} points{where} are NaN/inf"
        if len(pts) < CONTEXT_SIZE or len(pts) > MAX_POINTS_FACTOR * n_points:
            return (
                f"{what} has {len(pts)} points for n_points={n_points}: expected between "
                f"{CONTEXT_SIZE} and {MAX_POINTS_FACTOR * n_points}"
            )
        far = float(np.linalg.norm(pts, axis=1).max())
        if far > MAX_RADIUS:
            return (
                f"{what} has a point {far:.3g} from the origin: shapes are in the unit sphere, "
                "completions should be too"
            )
    return None


def _deterministic(
    cls: type, options: Any, path: Path | None, env: CheckEnv, first: list[Any]
) -> str:
    import numpy as np

    contexts, n_points = env.contexts()
    method = cls(options)
    if path is not None:
        method.load_checkpoint(Path(path))
    second = _complete_all(method, contexts, n_points)
    for ctx, a, b in zip(contexts, first, second, strict=True):
        if isinstance(a, Exception) or isinstance(b, Exception):
            if type(a) is not type(b) or str(a) != str(b):
                raise CheckFailed(
                    f"{ctx.ref.id}: the same seed gave {_outcome(a)}, then {_outcome(b)}"
                )
            continue
        pa, pb = np.asarray(a.points), np.asarray(b.points)
        if pa.shape != pb.shape:
            raise CheckFailed(f"{ctx.ref.id}: the same seed gave {pa.shape} then {pb.shape} points")
        if not np.array_equal(pa, pb):
            differ = int((pa != pb).any(axis=1).sum())
            raise CheckFailed(
                f"{ctx.ref.id}: the same seed gave different points ({differ} of {len(pa)} "
                f"differ, by up to {float(np.abs(pa - pb).max()):.3g}): draw random numbers from "
                "a generator seeded with context.seed"
            )
    return f"a fresh instance gives identical points for the same {len(contexts)} contexts"


def _outcome(value: Any) -> str:
    return describe(value) if isinstance(value, Exception) else f"{len(value.points)} points"


def _lightning(before: set[str]) -> str:
    """Whether the method's checks (training included) imported the ``lightning`` package.

    ``before`` is what of it this process had imported before them: in ``shapebench check``
    nothing, so a method importing it is caught; in a test process that imported it already, the
    check cannot tell and skips."""
    if "lightning" in before:
        raise CheckSkipped("this process had imported the lightning package before the check")
    if "lightning" in sys.modules:
        raise CheckFailed(
            "imported the lightning package (lightning.pytorch): shapebench uses "
            "pytorch_lightning, and objects of the two namespaces cannot be mixed"
        )
    if "pytorch_lightning" in sys.modules and "pytorch_lightning" not in before:
        return "uses pytorch_lightning, not lightning.pytorch"
    return "does not import lightning.pytorch"
