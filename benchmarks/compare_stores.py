"""Do two workspaces' stores hold the same per-object scores?

    .venv/bin/python benchmarks/compare_stores.py --a WORKSPACE --b WORKSPACE \
        [--rtol 1e-5] [--metric chamfer-l2] [--failing]

A fresh clone's quickstart should reproduce the committed tables within the cell contract's
tolerance (:data:`shapebench.api.protocol.SCORE_RTOL`: other thread counts and machines sum
floats in another order). Comparing the tables' means hides which objects moved; comparing cells
by key fails as soon as the code digests in the keys move (a store's cells stay under the keys of
the code that computed them). So this pairs per-object scores by what a score means: dataset,
split, frame, context protocol, row label (the variant's label, or the method's name), context
size, seed, object id and metric.

Each store is read the way ``shapebench leaderboard`` reads it
(:func:`~shapebench.boards.selection.load_runs` and
:func:`~shapebench.boards.selection.select_runs`: per split, frame and context protocol, the
newest data version, the newest run per variant, context size and seed, the newest variant per
label) and each selected cell's per-object table through
:func:`~shapebench.boards.frames.results_of_runs`; a cell contributes only the metrics it scored
(those with a card). Failed objects have no score (NaN): NaN against NaN agrees, NaN against a
value counts as a difference.

It prints one line per (dataset/split, label, context size, seed, metric) present in both
stores: the objects paired, the largest absolute and relative difference (relative to the larger
magnitude, as :func:`~shapebench.api.protocol.scores_agree`), how many objects differ by more
than ``--rtol``, how many objects of the row only one store has, and how far the row's mean
over the paired objects moved (``mean rel``: what a table shows); then the rows only one store
has, per label, and each label's largest relative difference. The data versions (fingerprints)
each store's selection used head each section: a quickstart (``-D test_per_category=4``)
evaluates another data version than the full sweep, whose first objects are the same objects.

Exit status 1 when a row has an object over ``--rtol`` (default ``SCORE_RTOL``) or when no object
pairs at all (nothing was compared), 2 on bad input. Opening a store as shapebench does writes
to it (a lock file beside ``mlflow.db``; MLflow may upgrade an older schema): copy an archived
store before comparing it.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from shapebench.api.protocol import DEFAULT_CONTEXT, DEFAULT_FRAME, SCORE_RTOL
from shapebench.boards.frames import results_of_runs
from shapebench.boards.selection import load_runs, run_column, select_runs
from shapebench.config import make_settings
from shapebench.store.records import CARD_PREFIX
from shapebench.store.tracking import LEGACY_TRAINING_SUFFIX, Tracker, training_experiment_name

#: What a score means, the columns it is paired on (``object`` and ``metric`` last).
ROW = ["dataset", "split", "frame", "context_protocol", "label", "context", "seed", "metric"]
PAIR = [*ROW[:-1], "object", "metric"]
#: A section of the printout: one table of the leaderboard.
SECTION = ROW[:4]


def store_scores(workspace: Path) -> tuple[pd.DataFrame, dict[tuple, str]]:
    """Every per-object score the leaderboard of ``workspace`` would read, one row per (cell,
    object, metric it scored) with the :data:`PAIR` columns and ``value``; and the data version
    (fingerprint) selected per section, with what the selection left out."""
    tracker = Tracker(make_settings(workspace=workspace))
    training = training_experiment_name("")
    frames: list[pd.DataFrame] = []
    notes: dict[tuple, str] = {}
    for name in tracker.experiment_names():
        if name.startswith(training) or name.endswith(LEGACY_TRAINING_SUFFIX):
            continue
        exp_id = tracker.experiment_id(name, create=False)
        runs = load_runs(tracker, exp_id) if exp_id is not None else pd.DataFrame()
        if runs.empty:
            continue
        dataset, split = runs["dataset"].iloc[0], runs["split"].iloc[0]
        frame_names = sorted(set(run_column(runs, "frame", DEFAULT_FRAME)))
        protocols = sorted(set(run_column(runs, "context_protocol", DEFAULT_CONTEXT)))
        for frame in frame_names:
            for protocol in protocols:
                chosen, fingerprint, left_out = select_runs(runs, frame, None, False, protocol)
                if chosen.empty:
                    continue
                section = (dataset, split, frame, protocol)
                notes[section] = fingerprint + "".join(f"; left out: {t}" for t in left_out)
                table = results_of_runs(tracker, dataset, {split: list(chosen["run_id"])})
                frames.append(scored_long(table, chosen, frame, protocol))
    if not frames:
        return pd.DataFrame(columns=[*PAIR, "value"]), notes
    return pd.concat(frames, ignore_index=True), notes


def scored_long(
    table: pd.DataFrame, chosen: pd.DataFrame, frame: str, protocol: str
) -> pd.DataFrame:
    """``results_of_runs``' wide table as one row per (object, metric its cell scored)."""
    cards = [c for c in chosen.columns if c.startswith(CARD_PREFIX)]
    scored = {
        (run_id, column[len(CARD_PREFIX) :])
        for run_id, row in chosen.set_index("run_id")[cards].iterrows()
        for column, card in row.items()
        if isinstance(card, str) and card
    }
    metrics = sorted({m for _, m in scored} & set(table.columns))
    long = table.melt(
        id_vars=["dataset", "split", "label", "context", "seed", "object", "run_id"],
        value_vars=metrics,
        var_name="metric",
        value_name="value",
    )
    keep = [(r, m) in scored for r, m in zip(long["run_id"], long["metric"], strict=True)]
    long = long[keep].assign(frame=frame, context_protocol=protocol)
    return long[[*PAIR, "value"]]


def relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a - b| relative to the larger magnitude (0 where both are 0, NaN where one is NaN), as
    ``scores_agree``."""
    scale = np.maximum(np.abs(a), np.abs(b))
    diff = np.abs(a - b)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.isnan(scale), np.nan, np.where(scale > 0, diff / scale, 0.0))


def compare(a: pd.DataFrame, b: pd.DataFrame, rtol: float) -> pd.DataFrame:
    """One row per :data:`ROW` key in either store: ``paired``, ``max_abs``, ``max_rel``,
    ``over`` (objects over ``rtol``, NaN against a value included), ``only_a``, ``only_b``, and
    ``mean_rel``: the relative difference of the two means over the objects scored in both (what
    a table's mean moves by)."""
    both = a.merge(b, on=PAIR, how="outer", suffixes=("_a", "_b"), indicator=True)
    va, vb = both["value_a"].to_numpy(float), both["value_b"].to_numpy(float)
    paired = (both["_merge"] == "both").to_numpy()
    nan_a, nan_b = np.isnan(va), np.isnan(vb)
    one_nan = paired & (nan_a != nan_b)
    finite = paired & ~nan_a & ~nan_b
    both["paired"] = paired
    both["abs"] = np.where(finite, np.abs(va - vb), np.nan)
    both["rel"] = np.where(finite, relative(np.nan_to_num(va), np.nan_to_num(vb)), np.nan)
    both["a_paired"] = np.where(finite, va, np.nan)
    both["b_paired"] = np.where(finite, vb, np.nan)
    both["over"] = one_nan | (finite & (both["rel"].to_numpy() > rtol))
    both["only_a"] = (both["_merge"] == "left_only").to_numpy()
    both["only_b"] = (both["_merge"] == "right_only").to_numpy()
    rows = (
        both.groupby(ROW, dropna=False)
        .agg(
            paired=("paired", "sum"),
            max_abs=("abs", "max"),
            max_rel=("rel", "max"),
            over=("over", "sum"),
            only_a=("only_a", "sum"),
            only_b=("only_b", "sum"),
            mean_a=("a_paired", "mean"),
            mean_b=("b_paired", "mean"),
        )
        .reset_index()
    )
    rows["mean_rel"] = relative(rows["mean_a"].to_numpy(float), rows["mean_b"].to_numpy(float))
    # Across CPUs a meshed row's scores are another draw, not the same numbers: whether the two
    # stores' scores differ systematically is the paired test's question, not a tolerance's.
    from shapebench.boards.stats import paired_p

    pairs = both[both["a_paired"].notna() & both["b_paired"].notna()]
    p = {
        key: paired_p(g["a_paired"].to_numpy(float), g["b_paired"].to_numpy(float))
        for key, g in pairs.groupby(ROW, dropna=False)
    }
    rows["p"] = [p.get(tuple(r), float("nan")) for r in rows[ROW].itertuples(index=False)]
    return rows


def fmt(value: float) -> str:
    return "-" if value is None or math.isnan(value) else f"{value:.2e}"


def report(
    rows: pd.DataFrame,
    notes_a: dict[tuple, str],
    notes_b: dict[tuple, str],
    rtol: float,
    failing: bool,
) -> list[str]:
    """The printout: per section the paired rows, then the rows of one store only, then each
    label's largest relative difference."""
    lines: list[str] = []
    paired = rows[rows["paired"] > 0]
    width = max([28, *(len(str(label)) for label in rows["label"])])
    head = (
        f"{'label':<{width}} {'k':>5} {'seed':>4} {'metric':<16} {'paired':>6} {'max abs':>9} "
        f"{'max rel':>9} {f'>{rtol:g}':>7} {'only a':>6} {'only b':>6} {'mean rel':>9} "
        f"{'paired p':>9}"
    )
    for section, group in paired.groupby(SECTION, sort=True):
        shown = group[group["over"] > 0] if failing else group
        lines += [
            "",
            "{}/{}, {}, {}".format(*section),
            f"  a: data version {notes_a.get(section, '-')}",
            f"  b: data version {notes_b.get(section, '-')}",
            head,
            "-" * len(head),
        ]
        for r in shown.itertuples():
            lines.append(
                f"{r.label:<{width}} {r.context:>5} {r.seed:>4} {r.metric:<16} {r.paired:>6} "
                f"{fmt(r.max_abs):>9} {fmt(r.max_rel):>9} {r.over:>7} {r.only_a:>6} {r.only_b:>6} "
                f"{fmt(r.mean_rel):>9} {fmt(r.p):>9}"
            )
        if failing and shown.empty:
            lines.append(f"(all {len(group)} rows within {rtol:g})")
    alone = rows[rows["paired"] == 0]
    if not alone.empty:
        lines += ["", "rows no object of which pairs, per label (scores in a, in b; k; seeds):"]
        for key, group in alone.groupby([*SECTION, "label"], sort=True):
            contexts = ",".join(str(k) for k in sorted(group["context"].unique()))
            seeds = ",".join(str(s) for s in sorted(group["seed"].unique()))
            lines.append(
                "  {}/{}, {}, {}, {}: ".format(*key)
                + f"a {int(group['only_a'].sum())}, b {int(group['only_b'].sum())}; "
                + f"k {contexts}; seeds {seeds}"
            )
    if not paired.empty:
        lines += ["", f"largest relative difference per label ({rtol:g}: --rtol)"]
        worst = paired.groupby("label").agg(
            max_rel=("max_rel", "max"),
            mean_rel=("mean_rel", "max"),
            over=("over", "sum"),
            paired=("paired", "sum"),
            p=("p", "min"),
        )
        for label, r in worst.sort_values("max_rel", ascending=False).iterrows():
            lines.append(
                f"  {label:<{width}} {fmt(r.max_rel):>9}  {int(r.over)} of {int(r.paired)} "
                f"over; mean moved by {fmt(r.mean_rel)} at most; smallest paired p {fmt(r.p)}"
            )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--a", required=True, type=Path, help="a workspace (holds mlflow.db)")
    parser.add_argument("--b", required=True, type=Path, help="another workspace")
    parser.add_argument("--rtol", type=float, default=SCORE_RTOL)
    parser.add_argument("--metric", action="append", help="only this metric (repeatable)")
    parser.add_argument("--failing", action="store_true", help="print only rows over --rtol")
    args = parser.parse_args()
    for name in ("a", "b"):
        ws = getattr(args, name)
        if not (ws / "mlflow.db").is_file():
            parser.error(f"--{name} {ws}: no mlflow.db there (a workspace holds one)")
    if not args.rtol >= 0:
        parser.error(f"--rtol {args.rtol}: a relative tolerance is >= 0")
    a, notes_a = store_scores(args.a)
    b, notes_b = store_scores(args.b)
    if args.metric:
        known = set(a["metric"]) | set(b["metric"])
        unknown = sorted(set(args.metric) - known)
        if unknown:
            parser.error(f"--metric {unknown}: no cell scored it; scored: {sorted(known)}")
        a, b = a[a["metric"].isin(args.metric)], b[b["metric"].isin(args.metric)]
    rows = compare(a, b, args.rtol)
    print(f"a: {args.a.absolute()} ({len(a)} scores)\nb: {args.b.absolute()} ({len(b)} scores)")
    print("\n".join(report(rows, notes_a, notes_b, args.rtol, args.failing)))
    paired, over = int(rows["paired"].sum()), int(rows["over"].sum())
    bad = rows[rows["over"] > 0]
    print(
        f"\n{paired} scores paired (object x metric) in {int((rows['paired'] > 0).sum())} rows; "
        f"{over} over {args.rtol:g} in {len(bad)} rows; "
        f"{int(rows['only_a'].sum())} scores in a only, {int(rows['only_b'].sum())} in b only"
    )
    if paired == 0:
        print("no object paired: nothing was compared", file=sys.stderr)
        sys.exit(1)
    if len(bad):
        sys.exit(1)


if __name__ == "__main__":
    main()
