"""Leaderboards built from the runs in MLflow, laid out like the paper's Tables 1-3.

For each finished cell run of a dataset/split experiment the per-object table (the run's
``per_object.csv`` artifact) is read back from MLflow. The *raw* table is the mean ± std over
objects of the metric (x1000 for Chamfer); the *normalised* table divides each object's value by
the reference method's value on the same object and context size, then takes mean ± std (the
paper's equation 8). Objects where either side failed are left out of the ratio and counted.
std is the sample standard deviation (ddof=1). When several seeds were run, every
(object, seed) pair counts as one sample. Values with different metric cards are never mixed.
"""

from __future__ import annotations

import shlex
import sys
import tempfile
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd

from shapebench.config import Settings
from shapebench.errors import ShapebenchError
from shapebench.metric import MetricCard
from shapebench.paper import PAPER_METHOD_ORDER, paper_table
from shapebench.tracking import CELL_KIND, Tracker, experiment_name


@dataclass
class Board:
    dataset: str
    split: str
    metric: str
    card: str
    reference: str
    contexts: list[int]
    raw: pd.DataFrame  # method, display, context, mean, std, n, failures
    normalized: pd.DataFrame | None
    note: str
    paper: pd.DataFrame
    experiment_id: str
    fingerprint: str
    left_out: int


def _card_text(tag: str) -> str:
    fields = dict(item.split("=", 1) for item in tag.split(";"))
    try:
        card = MetricCard(
            metric=fields["metric"],
            power=int(fields["power"]),
            reduction=fields["reduction"],
            direction=fields["direction"],
            halved=fields["halved"] == "True",
            scale=float(fields["scale"]),
            frame=fields["frame"],
            eval_points=int(fields["eval_points"]),
        )
    except (KeyError, ValueError):
        return tag
    return card.describe()


def _load_runs(tracker: Tracker, exp_id: str) -> pd.DataFrame:
    runs = tracker.client.search_runs(
        [exp_id],
        filter_string=f"tags.`shapebench.kind` = '{CELL_KIND}' and attributes.status = 'FINISHED'",
        order_by=["attributes.start_time DESC"],
        max_results=50000,
    )
    rows = [{"run_id": r.info.run_id, "start": r.info.start_time, **r.data.tags} for r in runs]
    return pd.DataFrame(rows)


def _per_object(tracker: Tracker, runs: pd.DataFrame, metric: str) -> pd.DataFrame:
    frames = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, run in enumerate(runs.to_dict("records")):
            dst = Path(tmp) / str(i)
            dst.mkdir()
            path = tracker.client.download_artifacts(run["run_id"], "per_object.csv", str(dst))
            table = pd.read_csv(path, keep_default_na=False, na_values=[""])
            table["value"] = table.get(metric, np.nan)
            table["method"] = run["method"]
            table["display"] = run["_display"]
            table["context"] = int(run["context_size"])
            table["seed"] = int(run["seed"])
            frames.append(
                table[["method", "display", "context", "seed", "object", "status", "value"]]
            )
    return pd.concat(frames, ignore_index=True)


def _aggregate(values: pd.Series) -> tuple[float, float]:
    v = values.to_numpy(dtype=float)
    if len(v) == 0:
        return (np.nan, np.nan)
    return (float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0)


def build_board(
    tracker: Tracker, dataset: str, split: str, reference: str, metric: str | None
) -> Board | None:
    exp_id = tracker.experiment_id(experiment_name(dataset, split), create=False)
    if exp_id is None:
        return None
    runs = _load_runs(tracker, exp_id)
    if runs.empty:
        return None
    # One data version per table: the one of the newest run; older versions are left out.
    fingerprint = runs.iloc[0]["dataset.fingerprint"]
    same = runs[runs["dataset.fingerprint"] == fingerprint]
    left_out = len(runs) - len(same)
    # The newest finished run of each cell wins (a --force rerun replaces the older one).
    latest = same.drop_duplicates(subset=["method", "context_size", "seed"], keep="first").copy()
    if metric is None:
        metric = _default_metric(latest)
    card_col = f"card.{metric}"
    if card_col not in latest:
        raise ShapebenchError(
            f"no run of {dataset}-{split} recorded metric {metric!r}", "pick another with --metric"
        )
    cards = latest.groupby(card_col)["method"].agg(lambda s: sorted(set(s)))
    if len(cards) > 1:
        listing = "; ".join(f"[{_card_text(c)}] used by {', '.join(m)}" for c, m in cards.items())
        raise ShapebenchError(
            f"runs of {dataset}-{split} computed {metric} with different cards, which cannot share "
            f"a table: {listing}",
            "rerun the odd ones with the same dataset options (shapebench run ... --force)",
        )
    card = cards.index[0]
    latest["_display"] = latest["method.display_name"].fillna(latest["method"])
    per_obj = _per_object(tracker, latest, metric)
    scale = float(dict(i.split("=", 1) for i in card.split(";")).get("scale", 1.0))
    contexts = sorted(per_obj["context"].unique().tolist())

    raw_rows = []
    for (method, display, ctx), g in per_obj.groupby(["method", "display", "context"]):
        ok = g[g.status == "ok"]["value"]
        mean, std = _aggregate(ok)
        raw_rows.append(
            {
                "method": method,
                "display": display,
                "context": ctx,
                "mean": mean * scale,
                "std": std * scale,
                "n": len(g),
                "failures": int((g.status != "ok").sum()),
            }
        )
    raw = pd.DataFrame(raw_rows)

    normalized, note = None, ""
    ref = per_obj[(per_obj.method == reference) & (per_obj.status == "ok")]
    if ref.empty:
        note = (
            f"No runs of the reference method {reference!r} in this experiment, so there is no "
            f"normalised table. Run it, or choose another reference with --reference "
            f"(methods with runs: {', '.join(sorted(per_obj.method.unique()))})."
        )
    else:
        ref = ref[["context", "seed", "object", "value"]].rename(columns={"value": "ref"})
        merged = per_obj.merge(ref, on=["context", "seed", "object"], how="left")
        norm_rows = []
        for (method, display, ctx), g in merged.groupby(["method", "display", "context"]):
            usable = g[(g.status == "ok") & g.ref.notna() & (g.ref > 0)]
            mean, std = _aggregate(usable["value"] / usable["ref"])
            norm_rows.append(
                {
                    "method": method,
                    "display": display,
                    "context": ctx,
                    "mean": mean,
                    "std": std,
                    "n": len(usable),
                    "failures": len(g) - len(usable),
                }
            )
        normalized = pd.DataFrame(norm_rows)
    return Board(
        dataset,
        split,
        metric,
        card,
        reference,
        contexts,
        raw,
        normalized,
        note,
        paper_table(dataset, split),
        exp_id,
        fingerprint,
        left_out,
    )


def _default_metric(runs: pd.DataFrame) -> str:
    from shapebench.registry import get_registry

    dataset = runs.iloc[0]["dataset"]
    try:
        return get_registry().load("dataset", dataset).default_metric
    except ShapebenchError:
        return "chamfer-l2"


def _order(methods: pd.DataFrame) -> list[tuple[str, str]]:
    pairs = sorted(set(zip(methods["method"], methods["display"], strict=True)))

    def rank(pair: tuple[str, str]) -> tuple[int, str]:
        display = pair[1]
        return (PAPER_METHOD_ORDER.index(display) if display in PAPER_METHOD_ORDER else 99, display)

    return sorted(pairs, key=rank)


def _cell(df: pd.DataFrame | None, method: str, ctx: int, fmt: str = "{:.2f} ± {:.2f}") -> str:
    if df is None or df.empty:
        return "–"
    row = df[(df.method == method) & (df.context == ctx)]
    if row.empty or np.isnan(row.iloc[0]["mean"]):
        return "–"
    return fmt.format(row.iloc[0]["mean"], row.iloc[0]["std"])


def render_markdown(board: Board, command: str, uri: str) -> str:
    ctxs = board.contexts
    scale_txt = "x1000" if "scale=1000" in board.card else ""
    lines = [
        f"# {board.dataset} / {board.split}: {board.metric}",
        "",
        f"Generated {datetime.now(timezone.utc):%Y-%m-%d %H:%M UTC} by `{command}` from the "
        f"MLflow runs of experiment `{experiment_name(board.dataset, board.split)}` "
        f"(id {board.experiment_id}) in `{uri}`; dataset fingerprint `{board.fingerprint}`.",
        "",
        f"**Metric card**: {_card_text(board.card)}.",
        "",
        f"Raw: mean ± std over objects of {board.metric} {scale_txt}. Normalised: per object "
        f"divided by `{board.reference}` on the same object and context size, then mean ± std "
        "(the paper's eq. 8).",
        "",
    ]
    if board.left_out:
        lines += [f"{board.left_out} runs on other versions of the dataset were left out.", ""]
    header = (
        ["Method"]
        + [f"raw {c}" for c in ctxs]
        + [f"norm. {c}" for c in ctxs]
        + ["objects", "failed (per context)"]
    )
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for method, display in _order(board.raw):
        raw = board.raw[board.raw.method == method]
        n = int(raw["n"].max())
        fails = "/".join(str(int(raw[raw.context == c]["failures"].sum())) for c in ctxs)
        cells = [_cell(board.raw, method, c) for c in ctxs] + [
            _cell(board.normalized, method, c) if method != board.reference else "1" for c in ctxs
        ]
        lines.append(f"| {display} (`{method}`) | " + " | ".join(cells) + f" | {n} | {fails} |")
    if not board.paper.empty:
        lines += [
            "",
            "**The paper's figures** (as published; not rerun here):",
            "",
            "| " + " | ".join(header[:-2]) + " |",
            "|" + "---|" * (len(header) - 2),
        ]
        for display in PAPER_METHOD_ORDER:
            rows = board.paper[board.paper.method == display]
            if rows.empty:
                continue
            cells = []
            for kind in ("raw_x1000", "normalized"):
                for c in ctxs:
                    r = rows[(rows.kind == kind) & (rows.context == c)]
                    if r.empty:
                        cells.append("–")
                    elif np.isnan(r.iloc[0]["std"]):
                        cells.append(f"{r.iloc[0]['mean']:.2f}")
                    else:
                        cells.append(f"{r.iloc[0]['mean']:.2f} ± {r.iloc[0]['std']:.2f}")
            lines.append(f"| {display} (paper) | " + " | ".join(cells) + " |")
    if board.note:
        lines += ["", f"> {board.note}"]
    return "\n".join(lines) + "\n"


def tidy_csv(board: Board) -> pd.DataFrame:
    frames = []
    for kind, df in (("raw", board.raw), ("normalized", board.normalized)):
        if df is not None and not df.empty:
            frames.append(df.assign(source="shapebench", kind=kind))
    if not board.paper.empty:
        p = board.paper.rename(columns={"method": "display"})
        p = p.assign(
            source="paper",
            method="",
            n=np.nan,
            failures=np.nan,
            kind=p.kind.map({"raw_x1000": "raw", "normalized": "normalized"}),
        )
        frames.append(
            p[["source", "method", "display", "context", "kind", "mean", "std", "n", "failures"]]
        )
    out = pd.concat(frames, ignore_index=True)
    out = out.assign(
        dataset=board.dataset,
        split=board.split,
        metric=board.metric,
        reference=board.reference,
        card=board.card,
    )
    cols = [
        "source",
        "dataset",
        "split",
        "metric",
        "kind",
        "method",
        "display",
        "context",
        "mean",
        "std",
        "n",
        "failures",
        "reference",
        "card",
    ]
    return out[cols]


def build_leaderboards(
    settings: Settings,
    dataset: str,
    splits: list[str] | None,
    reference: str,
    metric: str | None,
    out_dir: Path,
) -> list[Path]:
    tracker = Tracker(settings)
    if splits is None:
        prefix = f"{dataset}-"
        names = [e.name for e in tracker.client.search_experiments() if e.name.startswith(prefix)]
        splits = sorted(n[len(prefix) :] for n in names if n[len(prefix) :] != "train")
    command = "shapebench " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    written = []
    for split in splits:
        board = build_board(tracker, dataset, split, reference, metric)
        if board is None:
            continue
        out_dir.mkdir(parents=True, exist_ok=True)
        md = out_dir / f"{dataset}-{split}.md"
        md.write_text(render_markdown(board, command, settings.tracking_uri))
        csv = md.with_suffix(".csv")
        tidy_csv(board).to_csv(csv, index=False)
        written += [md, csv]
    if not written:
        raise ShapebenchError(
            f"no finished runs of dataset {dataset!r}"
            + (f" (splits {', '.join(splits)})" if splits else "")
            + f" in {settings.tracking_uri}",
            f"run one first: shapebench run --method gauss --dataset {dataset}",
        )
    return written
