"""Every row of a leaderboard against one reference row, paired over the same objects.

An ordering claim ("IGR beats Gauss densification at 50 points") is only made with its paired
test: for each row and context size this prints the mean and median, how many objects the row
wins against the reference, the two-sided Wilcoxon signed-rank p-value over the shared
(object, seed) pairs and the shift it tests (the Hodges-Lehmann estimate of row - reference:
negative where the row is lower for the typical pair, so it says which way a small p points when
the wins and the means disagree); then each row at its smallest against its largest context
size, paired the same way (objects lower at the largest, p, the ratios of means and of medians).

    .venv/bin/python benchmarks/paired_vs_reference.py -d synthetic --split trained \
        --reference gauss [--workspace shapebench-runs] [--before OTHER_WORKSPACE] [--by-seed]

With ``--before``, it also compares every row with the row of the same label in another
workspace's store (an earlier version of the same benchmark: same objects and context points),
paired over the objects: the mean before and now, the objects where now is lower, and p.

It reads the same per-object tables as ``shapebench leaderboard`` (failed objects scored by
the leaderboard's failure rule), from the workspace's MLflow store.
"""

from __future__ import annotations

import argparse

import numpy as np

from shapebench.boards.leaderboard import BoardQuery, build_board
from shapebench.boards.stats import paired_p, paired_shift
from shapebench.config import make_settings
from shapebench.store.tracking import Tracker


def compare(board, reference: str) -> list[str]:
    scored = board.scored
    labels = {r.variant: r.label for r in board.rows}
    ref = next((r.variant for r in board.rows if r.label == reference), None)
    if ref is None:
        known = ", ".join(repr(r.label) for r in board.rows)
        raise SystemExit(
            f"no row labelled {reference!r} in {board.dataset}/{board.split}; "
            f"--reference takes one of: {known}"
        )
    lines = [
        f"{board.dataset}/{board.split}, {board.metric} x{board.scale:g}, against "
        f"{reference} (wins: objects where the row is lower)",
        f"{'row':<28} {'k':>5} {'mean':>8} {'median':>8} {'wins':>7} {'p':>8} {'shift':>8}",
    ]
    for row in board.rows:
        for k in board.contexts:
            mine = scored[(scored["variant"] == row.variant) & (scored["context"] == k)]
            theirs = scored[(scored["variant"] == ref) & (scored["context"] == k)]
            pairs = mine.merge(theirs, on=["object", "seed"], suffixes=("", "_ref"))
            if pairs.empty:
                continue
            a = pairs["scored"].to_numpy() * board.scale
            b = pairs["scored_ref"].to_numpy() * board.scale
            wins = f"{int((a < b).sum())}/{len(a)}"
            p, shift = "-", "-"
            if row.variant != ref:
                p, shift = f"{paired_p(a, b):.2g}", f"{paired_shift(a, b):+.2f}"
            lines.append(
                f"{labels[row.variant]:<28} {k:>5} {a.mean():>8.2f} "
                f"{np.median(a):>8.2f} {wins:>7} {p:>8} {shift:>8}"
            )
    return lines + more_points(board)


def more_points(board) -> list[str]:
    """Each row at its smallest against its largest context size, paired over the same
    (object, seed): does the row improve with more points, and is the change in the mean the
    typical object's (median ratio) or a few objects' (the tail)?"""
    scored = board.scored
    lo, hi = min(board.contexts), max(board.contexts)
    head = f"{'row':<28} {'lower':>7} {'p':>8} {'ratio of means':>15} {'of medians':>11}"
    lines = [
        f"k={lo} against k={hi} (lower: objects lower at k={hi}; ratios: k={lo} / k={hi})",
        head,
    ]
    for row in board.rows:
        mine = scored[scored["variant"] == row.variant]
        small, large = mine[mine["context"] == lo], mine[mine["context"] == hi]
        pairs = small.merge(large, on=["object", "seed"], suffixes=("", "_hi"))
        if pairs.empty:
            continue
        a, b = pairs["scored"].to_numpy(), pairs["scored_hi"].to_numpy()
        if b.mean() <= 0 or np.median(b) <= 0:
            continue
        ratios = f"{a.mean() / b.mean():>15.2f} {np.median(a) / np.median(b):>11.2f}"
        lines.append(
            f"{row.label:<28} {int((b < a).sum())}/{len(a):<5} {paired_p(a, b):>8.2g} " + ratios
        )
    return lines


def by_seed(board) -> list[str]:
    """Each row's mean at each context size, per seed: the spread across training seeds."""
    scored = board.scored
    lines = [
        f"{board.dataset}/{board.split}, mean {board.metric} x{board.scale:g} per seed",
        f"{'row':<28} {'k':>5}  means by seed",
    ]
    for row in board.rows:
        mine = scored[scored["variant"] == row.variant]
        for k in board.contexts:
            means = mine[mine["context"] == k].groupby("seed")["scored"].mean() * board.scale
            text = "  ".join(f"{seed}: {m:.2f}" for seed, m in means.items())
            lines.append(f"{row.label:<28} {k:>5}  {text}")
    return lines


def split_pair(text: str) -> tuple[str, str]:
    """``NOW=BEFORE`` at the ``=`` outside the labels' brackets, so both sides may carry options:
    ``igr=igr[profile=standard]``, ``pointr[weights=local]=pointr``; ("", "") without one."""
    depth = 0
    for i, char in enumerate(text):
        depth += {"[": 1, "]": -1}.get(char, 0)
        if char == "=" and depth == 0:
            return text[:i], text[i + 1 :]
    return "", ""


def compare_before(now, before, renamed: dict[str, str] | None = None) -> list[str]:
    """Each row of ``now`` against the row of the same label in ``before`` (or of the label
    ``renamed`` gives it), per context size."""
    old = {r.label: r.variant for r in before.rows}
    old |= {mine: old[theirs] for mine, theirs in (renamed or {}).items() if theirs in old}
    lines = [
        "now against before (wins: objects where now is lower)",
        f"{'row':<28} {'k':>5} {'before':>8} {'now':>8} {'wins':>7} {'p':>8}",
    ]
    for row in now.rows:
        if row.label not in old:
            continue
        for k in now.contexts:
            mine = now.scored[(now.scored["variant"] == row.variant) & (now.scored["context"] == k)]
            theirs = before.scored[
                (before.scored["variant"] == old[row.label]) & (before.scored["context"] == k)
            ]
            pairs = mine.merge(theirs, on=["object", "seed"], suffixes=("", "_ref"))
            if pairs.empty:
                continue
            a = pairs["scored"].to_numpy() * now.scale
            b = pairs["scored_ref"].to_numpy() * now.scale
            p = "-" if np.array_equal(a, b) else f"{paired_p(a, b):.2g}"
            lines.append(
                f"{row.label:<28} {k:>5} {b.mean():>8.2f} {a.mean():>8.2f} "
                f"{int((a < b).sum())}/{len(a):<5} {p:>8}"
            )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-d", "--dataset", required=True)
    parser.add_argument("--split", required=True)
    parser.add_argument("--reference", default="gauss")
    parser.add_argument("--metric", default=None)
    parser.add_argument("--workspace", default=None)
    parser.add_argument("--before", default=None, help="another workspace to compare rows with")
    parser.add_argument(
        "--pair",
        action="append",
        default=[],
        metavar="NOW=BEFORE",
        help="pair the row labelled NOW with BEFORE's row labelled BEFORE (repeatable), e.g. "
        "'pointr[weights=local]=pointr' for a local training against shipped weights",
    )
    parser.add_argument("--by-seed", action="store_true", help="also each row's means per seed")
    args = parser.parse_args()
    renamed = {}
    for pair in args.pair:
        now, before = split_pair(pair)
        if not now or not before:
            parser.error(f"--pair takes NOW=BEFORE, got {pair!r}")
        renamed[now] = before
    tracker = Tracker(make_settings(workspace=args.workspace))
    query = BoardQuery(args.dataset, args.reference, args.metric)
    board = build_board(tracker, query, args.split)
    if board is None or board.scored is None:
        raise SystemExit(f"no runs of {args.dataset}-{args.split} in this store")
    print("\n".join(compare(board, args.reference)))
    if args.by_seed:
        print()
        print("\n".join(by_seed(board)))
    if args.before:
        before = build_board(Tracker(make_settings(workspace=args.before)), query, args.split)
        if before is None or before.scored is None:
            raise SystemExit(f"no runs of {args.dataset}-{args.split} in {args.before}")
        print()
        print("\n".join(compare_before(board, before, renamed)))


if __name__ == "__main__":
    main()
