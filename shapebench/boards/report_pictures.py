"""The pictures of ``shapebench report``: the qualitative grids and posterior-spread pictures
of a board, read back from the PNG/PLY artifacts its cell runs logged (drawn by
:mod:`shapebench.evaluation.pictures`) and returned as PNG data URIs for the self-contained page.
"""

from __future__ import annotations

import base64
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from shapebench.boards.board import Board
from shapebench.store.tracking import Tracker

#: Pictured objects drawn as qualitative grids per table, at most.
GRIDS = 3


def data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def picture_runs(board: Board) -> pd.DataFrame:
    """The cell runs the grids are drawn from: per (row, context size), the lowest seed."""
    runs = board.runs
    if runs is None or runs.empty:
        return pd.DataFrame(columns=["run_id", "variant_key", "context_size", "seed"])
    return runs.sort_values("seed").drop_duplicates(["variant_key", "context_size"])


class Artifacts:
    """Reads a run's artifacts: straight from the folder when the store is local (the embedded
    workspace), else downloaded; MLflow's download costs ~80 ms a file even for local files."""

    def __init__(self, tracker: Tracker, run_id: str, dst: Path) -> None:
        from urllib.parse import urlparse
        from urllib.request import url2pathname

        self.tracker, self.run_id, self.dst = tracker, run_id, dst
        uri = tracker.artifact_uri(run_id)
        parsed = urlparse(uri)
        self.local = Path(url2pathname(parsed.path)) if parsed.scheme in ("", "file") else None

    def path(self, name: str) -> Path:
        if self.local is not None and (self.local / name).exists():
            return self.local / name
        return self.tracker.download_artifact(self.run_id, name, self.dst)

    def names(self, folder: str) -> list[str]:
        if self.local is not None and (self.local / folder).is_dir():
            return sorted(f"{folder}/{p.name}" for p in (self.local / folder).iterdir())
        return self.tracker.list_artifacts(self.run_id, folder)


def cell_pictures(tracker: Tracker, run_id: str, dst: Path) -> dict[str, dict[str, np.ndarray]]:
    """Object id stem -> arrays of the pictures a cell logged (``pictures/*.npz``, with the
    cell's PNG of it as ``png`` bytes where the arrays name its caption); for cells logged
    before pictures existed, the completed ``.ply`` clouds and their contexts."""
    out: dict[str, dict[str, np.ndarray]] = {}
    store = Artifacts(tracker, run_id, dst)
    if store.names("pictures"):
        folder = store.path("pictures")
        for npz in sorted(folder.glob("*.npz")):
            with np.load(npz) as arrays:
                out[npz.stem] = {k: arrays[k] for k in arrays.files}
            png = npz.with_suffix(".png")
            if "title" in out[npz.stem] and png.exists():
                out[npz.stem]["png"] = np.frombuffer(png.read_bytes(), dtype=np.uint8)
        return out
    plys = [p for p in store.names("completions") if p.endswith(".ply") and ".sample" not in p]
    if not plys:
        return out
    import trimesh

    contexts: dict[str, np.ndarray] = {}
    try:
        with np.load(store.path("contexts.npz")) as c:
            contexts = {
                str(o).replace("/", "__"): p for o, p in zip(c["objects"], c["points"], strict=True)
            }
    except Exception:  # no contexts logged: the grid shows completions only
        pass
    for path in plys:
        stem = Path(path).stem
        cloud = trimesh.load(store.path(path))
        out[stem] = {
            "completion": np.asarray(cloud.vertices, np.float32),
            "context": contexts.get(stem, np.zeros((0, 3), np.float32)),
        }
    return out


def fixed_stems(board: Board) -> set[str] | None:
    """The picture stems of the objects every cell pictures (picked from each cell's object list
    by :func:`shapebench.evaluation.pictures.picture_objects`), or None when the board has no
    per-object tables to pick from."""
    from shapebench.evaluation.pictures import file_stem, picture_objects

    scored = board.scored
    if scored is None or scored.empty:
        return None
    stems: set[str] = set()
    for _, cell in scored.groupby(["variant", "context", "seed"], sort=False):
        stems |= {file_stem(o) for o in picture_objects(cell["object"].tolist())}
    return stems


def grids_and_spreads(tracker: Tracker, board: Board) -> tuple[list, list]:
    """The qualitative grids (one per pictured object, up to ``GRIDS``) and the posterior
    spread pictures of the board's cells."""
    from shapebench.evaluation.pictures import png_bytes, qualitative_grid

    labels = {r.variant: r.label for r in board.rows}
    cells: dict[tuple[str, int], dict[str, dict[str, np.ndarray]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, run in enumerate(picture_runs(board).to_dict("records")):
            dst = Path(tmp) / str(i)
            dst.mkdir()
            key = (labels.get(run["variant_key"], run["_label"]), int(run["context_size"]))
            cells[key] = cell_pictures(tracker, run["run_id"], dst)
    fixed = fixed_stems(board)
    objects: dict[str, int] = {}
    for pictures in cells.values():
        for stem in pictures:
            if fixed is None or stem in fixed:  # a cell's worst object is not a grid's
                objects[stem] = objects.get(stem, 0) + 1
    # The objects most cells pictured (every cell pictures the same ones; older stores differ).
    chosen = sorted(objects, key=lambda s: (-objects[s], s))[:GRIDS]
    grids, spreads = [], []
    for stem in chosen:
        completions = {k: p[stem]["completion"] for k, p in cells.items() if stem in p}
        context_points = {
            k[1]: p[stem]["context"]
            for k, p in cells.items()
            if stem in p and len(p[stem]["context"])
        }
        truth = next(
            (
                p[stem]["ground_truth"]
                for p in cells.values()
                if stem in p and "ground_truth" in p[stem]
            ),
            None,
        )
        obj = stem.replace("__", "/")
        fig = qualitative_grid(
            [r.label for r in board.rows],
            board.contexts,
            completions,
            context_points,
            truth,
            f"{board.dataset}/{board.split}: {obj}",
        )
        grids.append((obj, data_uri(png_bytes(fig))))
        for (label, ctx), p in sorted(cells.items()):
            if stem in p and "spread" in p[stem]:
                spreads.append(
                    (
                        f"{label}, {ctx} points: {obj}",
                        spread_picture(p[stem], f"{label} k={ctx}: {obj}"),
                    )
                )
    return grids, spreads


def worst_pictures(tracker: Tracker, board: Board) -> list[tuple[str, str, int, float, str, str]]:
    """Per row, its worst sample at the table's largest context size (:attr:`Board.worst`):
    (label, object, seed, value in displayed units, status, PNG data URI of the picture its
    cell logged of that object, or "" where there is none: a failed object has no completion,
    and cells of stores made before 2026-12-03 pictured the split's fixed objects only)."""
    from shapebench.evaluation.pictures import file_stem, picture_png

    if board.worst is None or board.worst.empty or not board.contexts:
        return []
    ctx = max(board.contexts)
    runs = board.runs if board.runs is not None else pd.DataFrame()
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, row in enumerate(board.rows):
            hit = board.worst[(board.worst.variant == row.variant) & (board.worst.context == ctx)]
            if hit.empty:
                continue
            obj, seed = str(hit.iloc[0]["object"]), int(hit.iloc[0]["seed"])
            value = float(hit.iloc[0]["scored"])
            uri = ""
            cell = (
                runs[
                    (runs["variant_key"] == row.variant)
                    & (runs["context_size"].astype(int) == ctx)
                    & (runs["seed"].astype(int) == seed)
                ]
                if {"variant_key", "context_size", "seed", "run_id"} <= set(runs.columns)
                else pd.DataFrame()
            )
            if not cell.empty:  # its cell pictured its worst success (the runner does)
                dst = Path(tmp) / str(i)
                dst.mkdir()
                arrays = cell_pictures(tracker, cell.iloc[0]["run_id"], dst).get(file_stem(obj))
                if arrays is not None and "completion" in arrays:
                    title = f"{row.label} k={ctx} seed {seed}: {obj} ({value:.2f}, its worst)"
                    uri = data_uri(picture_png(arrays, title))
            out.append((row.label, obj, seed, value, str(hit.iloc[0]["status"]), uri))
    return out


def spread_picture(arrays: dict[str, np.ndarray], title: str) -> str:
    """The picture of one object's cell as a data URI: the PNG its cell logged when that was
    drawn with this caption (the same arrays, so the same bytes; a relabelled row's was not),
    else drawn now."""
    from shapebench.evaluation.pictures import picture_png

    if "png" in arrays and str(arrays.get("title", "")) == title:
        return data_uri(arrays["png"].tobytes())
    return data_uri(picture_png(arrays, title))


# -- the page ---------------------------------------------------------------------------------
