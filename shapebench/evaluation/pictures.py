"""Pictures of completions: point clouds drawn headless with matplotlib (Agg), from fixed views.

Every cell draws the same few objects (:func:`picture_objects`, chosen from the split's object
list, not from which objects succeeded), so two methods' pictures of one object sit side by side.
A picture shows, per view, the context points, the completion and the ground truth (and, for a
method that returns posterior samples, the completion coloured by the per-point spread of
:func:`shapebench.evaluation.scoring.posterior_spread`). The arrays a picture was drawn from are
kept too (:func:`picture_arrays`, ``pictures/<object>.npz``), so the qualitative grid
(:func:`qualitative_grid`: rows = methods, columns = context sizes, like the paper's Figures 2-20)
is drawn from the runs in MLflow without loading the dataset again.

Drawing is an orthographic projection done in numpy and a 2D scatter (far points first, shaded
darker), not matplotlib's 3D axes: a picture costs tens of milliseconds, not seconds.
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

#: Fixed views (elevation, azimuth) in degrees, for y-up objects (ShapeNet's and the synthetic
#: benchmark's convention, front towards +z): a three-quarter view from the front right, and
#: one from the side, slightly above.
VIEWS: tuple[tuple[float, float], ...] = ((20.0, 35.0), (15.0, 110.0))
#: At most this many points of a completion or ground truth are drawn (and kept in the npz).
MAX_POINTS = 4096
#: Points per panel of the qualitative grid (small panels: more would only blur).
GRID_POINTS = 2500
#: How many objects per cell are pictured.
PICTURES_PER_CELL = 3

COLOURS = {"context": "#d62728", "completion": "#1f77b4", "ground truth": "#555555"}


def picture_objects(ids: Sequence[str], n: int = PICTURES_PER_CELL) -> list[str]:
    """``n`` object ids spread evenly over the split's (ordered) object list: the same for every
    method, whichever objects fail."""
    if not ids:
        return []
    picks = np.unique(np.linspace(0, len(ids) - 1, min(n, len(ids))).round().astype(int))
    return [ids[i] for i in picks]


def subsample(points: np.ndarray, n: int = MAX_POINTS) -> np.ndarray:
    """Indices of at most ``n`` points, evenly spaced (deterministic, no generator needed)."""
    if len(points) <= n:
        return np.arange(len(points))
    return np.linspace(0, len(points) - 1, n).round().astype(int)


def project(points: np.ndarray, elev: float, azim: float) -> tuple[np.ndarray, np.ndarray]:
    """Screen coordinates (n, 2) and depth (n,; larger is nearer) of y-up ``points`` seen from
    elevation ``elev`` and azimuth ``azim`` (degrees), orthographically."""
    a, e = np.deg2rad(azim), np.deg2rad(elev)
    # Turn about the vertical (y) axis, then tilt about the screen's x axis.
    turn = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    tilt = np.array([[1, 0, 0], [0, np.cos(e), -np.sin(e)], [0, np.sin(e), np.cos(e)]])
    p = np.asarray(points, dtype=np.float64) @ (tilt @ turn).T
    return p[:, :2], p[:, 2]


@dataclass
class Panel:
    """One cloud to draw: its points, its title, and either a colour or per-point values."""

    points: np.ndarray
    title: str
    colour: str = COLOURS["completion"]
    values: np.ndarray | None = None  # per-point values (coloured with ``cmap``, colour bar)
    size: float = 1.5
    max_points: int = MAX_POINTS


def _shade(colour: str, depth: np.ndarray) -> np.ndarray:
    """RGBA per point: the colour, darker with distance, so the shape reads without lighting."""
    from matplotlib.colors import to_rgba

    rgba = np.tile(np.array(to_rgba(colour)), (len(depth), 1))
    if len(depth) > 1 and np.ptp(depth) > 0:
        near = (depth - depth.min()) / np.ptp(depth)
        rgba[:, :3] *= (0.35 + 0.65 * near)[:, None]
    return rgba


def _draw(ax, panel: Panel, view: tuple[float, float], bounds: tuple[np.ndarray, float]):
    """Scatter one panel on ``ax`` (square limits from ``bounds``); the mappable when coloured
    by values."""
    centre, half = bounds
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_visible(False)
    pts = np.asarray(panel.points, dtype=np.float64).reshape(-1, 3)
    if not len(pts):
        ax.text(
            0.5,
            0.5,
            panel.title or "no points",
            ha="center",
            va="center",
            fontsize=8,
            color="#888888",
            transform=ax.transAxes,
        )
        return None
    keep = subsample(pts, panel.max_points)
    pts = pts[keep]
    xy, depth = project(pts, *view)
    order = np.argsort(depth)  # far first: near points are drawn over them
    if panel.values is not None:
        vals = np.asarray(panel.values, dtype=float)[keep][order]
        return ax.scatter(
            xy[order, 0],
            xy[order, 1],
            c=vals,
            s=panel.size,
            cmap="magma",
            linewidths=0,
            rasterized=True,
        )
    ax.scatter(
        xy[order, 0],
        xy[order, 1],
        c=_shade(panel.colour, depth[order]),
        s=panel.size,
        linewidths=0,
        rasterized=True,
    )
    return None


def _bounds(clouds: Sequence[np.ndarray], view: tuple[float, float]) -> tuple[np.ndarray, float]:
    """One square window for every panel of a view: the panels compare at the same scale."""
    pts = [np.asarray(c, dtype=np.float64).reshape(-1, 3) for c in clouds]
    pts = [p for p in pts if len(p)]
    if not pts:
        return np.zeros(2), 1.0
    xy, _ = project(np.concatenate(pts), *view)
    lo, hi = np.percentile(xy, 0.5, axis=0), np.percentile(xy, 99.5, axis=0)
    return (lo + hi) / 2, float(max(hi - lo) / 2 * 1.08 + 1e-6)


def object_figure(
    context: np.ndarray,
    completion: np.ndarray | None,
    ground_truth: np.ndarray | None,
    spread: np.ndarray | None = None,
    title: str = "",
    views: Sequence[tuple[float, float]] = VIEWS,
):
    """A figure with one row per view: context, completion, ground truth, and (``spread``
    given, one value per completion point) the completion coloured by posterior spread."""
    from matplotlib.figure import Figure

    panels = [Panel(context, f"context ({len(context)} pts)", COLOURS["context"], size=5)]
    if completion is not None:
        panels.append(Panel(completion, "completion"))
    if ground_truth is not None:
        panels.append(Panel(ground_truth, "ground truth", COLOURS["ground truth"]))
    if spread is not None and completion is not None:
        panels.append(Panel(completion, "posterior spread", values=spread))
    fig = Figure(
        figsize=(2.2 * len(panels) + (0.5 if spread is not None else 0), 2.2 * len(views) + 0.4),
        dpi=80,
    )
    axes = fig.subplots(len(views), len(panels), squeeze=False)
    for r, view in enumerate(views):
        bounds = _bounds([p.points for p in panels], view)
        for c, panel in enumerate(panels):
            mappable = _draw(axes[r, c], panel, view, bounds)
            if r == 0:
                axes[r, c].set_title(panel.title, fontsize=9)
            if mappable is not None:
                fig.colorbar(mappable, ax=axes[r, c], fraction=0.046, pad=0.02)
    top = 0.92
    if title:  # long variant labels wrap instead of running off the picture
        text = textwrap.fill(title, int(fig.get_figwidth() * 13))
        fig.suptitle(text, fontsize=9)
        top -= 0.16 * text.count("\n") / fig.get_figheight() + 0.06
    fig.subplots_adjust(left=0.02, right=0.95, bottom=0.02, top=top, wspace=0.08, hspace=0.05)
    return fig


def qualitative_grid(
    rows: Sequence[str],
    contexts: Sequence[int],
    completions: Mapping[tuple[str, int], np.ndarray],
    context_points: Mapping[int, np.ndarray],
    ground_truth: np.ndarray | None = None,
    title: str = "",
    view: tuple[float, float] = VIEWS[0],
):
    """The paper's figure layout: a first row of context points per context size (and the
    ground truth in a last column), then one row per method (``rows``, labels), one column per
    context size; a missing completion is an empty, labelled panel."""
    from matplotlib.figure import Figure

    n_cols = len(contexts) + (1 if ground_truth is not None else 0)
    n_rows = len(rows) + 1
    # Long variant labels wrap beside their row, in a margin as wide as their longest line.
    names = [textwrap.fill(r.replace(",", ", "), 22, break_long_words=True) for r in rows]
    longest = max([len(line) for n in names for line in n.split("\n")] + [7])
    margin = 0.25 + 0.075 * longest  # inches, at 8 pt
    fig = Figure(figsize=(1.8 * n_cols + margin, 1.8 * n_rows + 0.5), dpi=80)
    axes = fig.subplots(n_rows, n_cols, squeeze=False)
    clouds = [*context_points.values(), *completions.values()]
    if ground_truth is not None:
        clouds.append(ground_truth)
    # Completions that explode (a failed implicit surface) must not shrink everything else.
    anchor = [ground_truth] if ground_truth is not None else list(context_points.values())
    bounds = _bounds(anchor or clouds, view)
    bounds = (bounds[0], bounds[1] * 1.15)
    for c, k in enumerate(contexts):
        pts = context_points.get(k, np.zeros((0, 3)))
        _draw(axes[0, c], Panel(pts, "", COLOURS["context"], size=4), view, bounds)
        axes[0, c].set_title(f"{k} points", fontsize=9)
        for r, row in enumerate(rows, start=1):
            cloud = completions.get((row, k))
            if cloud is None:  # not run, or this object failed
                _draw(axes[r, c], Panel(np.zeros((0, 3)), "no completion"), view, bounds)
            else:
                _draw(axes[r, c], Panel(cloud, "", max_points=GRID_POINTS), view, bounds)
    if ground_truth is not None:
        gt = Panel(ground_truth, "", COLOURS["ground truth"], max_points=GRID_POINTS)
        _draw(axes[0, -1], gt, view, bounds)
        axes[0, -1].set_title("ground truth", fontsize=9)
        for r in range(1, n_rows):
            axes[r, -1].set_axis_off()
    axes[0, 0].set_ylabel("context", fontsize=9, rotation=0, ha="right", va="center")
    for r, name in enumerate(names, start=1):
        axes[r, 0].set_ylabel(name, fontsize=8, rotation=0, ha="right", va="center")
    height = fig.get_figheight()
    if title:  # in the top 0.5 inch the figure keeps free, above the column titles
        fig.suptitle(title, fontsize=10, y=1 - 0.08 / height)
    fig.subplots_adjust(
        left=margin / fig.get_figwidth(),
        right=0.99,
        bottom=0.01,
        top=1 - 0.5 / height,
        wspace=0.04,
        hspace=0.06,
    )
    return fig


def png_bytes(fig, dpi: int | None = None) -> bytes:
    """The figure as PNG, drawn by Agg (no display, no pyplot state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def picture_arrays(
    context: np.ndarray,
    completion: np.ndarray,
    ground_truth: np.ndarray | None,
    spread: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """What a picture is drawn from, subsampled (``MAX_POINTS``), for ``pictures/<obj>.npz``."""
    keep = subsample(completion)
    arrays = {
        "context": np.asarray(context, np.float32),
        "completion": np.asarray(completion, np.float32)[keep],
    }
    if ground_truth is not None:
        arrays["ground_truth"] = np.asarray(ground_truth, np.float32)[subsample(ground_truth)]
    if spread is not None:
        arrays["spread"] = np.asarray(spread, np.float32)[keep]
    return arrays


def picture_png(arrays: Mapping[str, np.ndarray], title: str = "") -> bytes:
    """The PNG of one object's picture from its :func:`picture_arrays`."""
    fig = object_figure(
        arrays["context"],
        arrays.get("completion"),
        arrays.get("ground_truth"),
        arrays.get("spread"),
        title,
    )
    return png_bytes(fig)


def is_blank(png: bytes) -> bool:
    """True when every pixel of the PNG has one colour (nothing was drawn)."""
    from matplotlib.image import imread

    pixels = imread(io.BytesIO(png), format="png")
    return bool(np.all(pixels == pixels.reshape(-1, pixels.shape[-1])[0]))


def file_stem(object_id: str) -> str:
    """An object id as a file name (ids may hold slashes: category/name)."""
    return object_id.replace("/", "__")
