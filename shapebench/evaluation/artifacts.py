"""The files a cell leaves on its run: the per-object table (``per_object.csv``), the contexts
(``contexts.npz``), and for the pictured objects their completed clouds and pictures."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from shapebench.api.types import Completion, Context
from shapebench.store.tracking import Tracker

#: Completed clouds kept as ``.ply`` files per cell: the pictured objects', filled up with other
#: successes where pictured ones failed (``shapebench.evaluation.pictures.PICTURES_PER_CELL``).
EXAMPLE_PLYS = 3


def log_cell_artifacts(
    tracker: Tracker,
    run_id: str,
    table: pd.DataFrame,
    contexts: list[Context],
    examples: list[tuple[Context, Completion]],
    truths: dict[str, np.ndarray] | None = None,
    title: str = "",
    spare: Sequence[tuple[Context, Completion]] = (),
    echo: Callable[[str], None] = print,
) -> None:
    """The per-object table, the contexts, and for the pictured objects their completed
    clouds (``completions/*.ply``) and pictures (``pictures/<object>.png``, drawn from the
    arrays kept beside it as ``.npz``: context, completion, ground truth, spread, and the
    picture's caption as ``title``); when pictured objects failed, ``spare`` successes fill
    the ``.ply`` examples up."""
    import trimesh

    from shapebench.evaluation.pictures import file_stem, picture_arrays, picture_png

    with tempfile.TemporaryDirectory() as tmp:
        tmpdir = Path(tmp)
        table.to_csv(tmpdir / "per_object.csv", index=False)
        if contexts:
            arrays = {
                "objects": np.array([c.ref.id for c in contexts]),
                "points": np.stack([c.points for c in contexts]),
            }
            if all(c.normals is not None for c in contexts):  # given to the method
                arrays["normals"] = np.stack([c.normals for c in contexts])
            np.savez_compressed(tmpdir / "contexts.npz", **arrays)
        tracker.log_artifacts(run_id, tmpdir)
        if examples:
            pic_dir = tmpdir / "pictures"
            pic_dir.mkdir()
            start = time.perf_counter()
            try:
                for ctx, completion in examples:
                    obj = ctx.ref.id
                    arrays = picture_arrays(
                        ctx.points,
                        completion.points,
                        (truths or {}).get(obj),
                        completion.cache.get("spread"),
                    )
                    caption = f"{title}: {obj}" if title else obj
                    # The caption beside the arrays: the report embeds this PNG as it is when
                    # it would draw the same caption, instead of drawing it again.
                    np.savez_compressed(
                        pic_dir / f"{file_stem(obj)}.npz", **arrays, title=np.array(caption)
                    )
                    png = picture_png(arrays, caption)
                    (pic_dir / f"{file_stem(obj)}.png").write_bytes(png)
            except Exception as exc:  # a picture is a view of the results, not one of them
                echo(
                    f"  warning: could not draw the pictures of this cell "
                    f"({type(exc).__name__}: {exc})"
                )
            tracker.log_artifacts(run_id, pic_dir, "pictures")
            seconds = time.perf_counter() - start
            tracker.log_metrics(run_id, {"pictures_seconds": seconds})
        if examples or spare:
            ex_dir = tmpdir / "completions"
            ex_dir.mkdir()
            for ctx, completion in [*examples, *spare]:
                obj = ctx.ref.id
                stem = obj.replace("/", "__")
                trimesh.PointCloud(completion.points).export(ex_dir / f"{stem}.ply")
                for j, sample in enumerate(completion.samples or []):
                    trimesh.PointCloud(sample).export(ex_dir / f"{stem}.sample{j}.ply")
                if "spread" in completion.cache:
                    np.savez_compressed(
                        ex_dir / f"{stem}.spread.npz",
                        points=completion.points,
                        spread=completion.cache["spread"],
                    )
            tracker.log_artifacts(run_id, ex_dir, "completions")
