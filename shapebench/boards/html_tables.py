"""The HTML of one leaderboard's numbers, for ``shapebench report``
(:mod:`shapebench.boards.html_report` lays out the page): who wins at each context size and who
is tied with the winner, the raw and normalised tables (sortable: the cells carry ``data-sort``
keys, missing values sort last), each row's cost, the rows marked against the floors, and the
per-category tables.
"""

from __future__ import annotations

import html
from typing import Any

import numpy as np
import pandas as pd

from shapebench.boards.board import Board, Row, below_floor, floor_labels, table_id
from shapebench.boards.markdown import FLOOR_MARK, cell_marks
from shapebench.boards.stats import ALPHA


def escape(value: object) -> str:
    """``value`` as HTML text (quotes escaped too: it goes into attributes)."""
    return html.escape(str(value), quote=True)


_e = escape


def _num(value: float) -> str:
    """A sort key: missing values sort last (ascending)."""
    return "Infinity" if value is None or not np.isfinite(value) else repr(float(value))


def _sig(board: Board, row: Row, ctx: int) -> pd.Series | None:
    s = board.significance
    hit = s[(s.variant == row.variant) & (s.context == ctx)]
    return None if hit.empty else hit.iloc[0]


def _raw_cell(board: Board, row: Row, ctx: int) -> str:
    r = board.raw[(board.raw.variant == row.variant) & (board.raw.context == ctx)]
    if r.empty:
        return '<td data-sort="Infinity">–</td>'
    r = r.iloc[0]
    if r["n_ok"] == 0:
        return f'<td data-sort="Infinity">failed (0/{int(r["n"])})</td>'
    text, cls, title = f"{r['mean']:.2f} ± {r['std']:.2f}", "", ""
    sig = _sig(board, row, ctx)
    if sig is not None and bool(sig["best"]):
        cls, title = "best", "best at this context size"
    elif sig is not None:
        title = f"p vs best {sig['p_vs_best']:.3g}, Holm {sig['p_holm']:.3g}"
        if bool(sig["tied"]):
            cls, text = "tied", text + " ≈"
    floor = below_floor(board, row.variant, ctx)
    if floor is not None:
        labels = {x.variant: x.label for x in board.rows}
        title += (
            f"{'; ' if title else ''}p vs floor {labels.get(floor['floor'], floor['floor'])} "
            f"{floor['p_vs_floor']:.3g}, Holm {floor['p_floor_holm']:.3g}"
        )
    text += cell_marks(board, r, floor is not None and bool(floor["below_floor"]))
    attrs = f' class="{cls}"' if cls else ""
    return f'<td data-sort="{_num(r["mean"])}"{attrs} title="{_e(title)}">{_e(text)}</td>'


def _norm_cell(board: Board, row: Row, ctx: int) -> str:
    if row.label == board.reference:
        return '<td data-sort="1">1</td>'
    df = board.normalized
    r = None if df is None or df.empty else df[(df.variant == row.variant) & (df.context == ctx)]
    if r is None or r.empty or not np.isfinite(r.iloc[0]["mean"]):
        return '<td data-sort="Infinity">–</td>'
    m, s = r.iloc[0]["mean"], r.iloc[0]["std"]
    return f'<td data-sort="{_num(m)}">{m:.2f} ± {s:.2f}</td>'


def _cost(board: Board, row: Row) -> dict[str, Any]:
    if board.costs is None:
        return {}
    hit = board.costs[board.costs.variant == row.variant]
    return {} if hit.empty else hit.iloc[0].to_dict()


def tables_html(board: Board) -> str:
    from shapebench.boards.cost import describe_seconds, describe_training

    ctxs = board.contexts
    head = "".join(f"<th>{c}</th>" for c in ctxs)
    raw = [
        f'<table class="sortable" id="raw-{_e(table_id(board))}"><thead><tr><th>method</th>'
        f"{head}<th>objects</th><th>failed</th><th>test time / object</th>"
        '<th>training device-hours</th><th class="wrap">training</th></tr></thead>'
        "<tbody>"
    ]
    for row in board.rows:
        r = board.raw[board.raw.variant == row.variant]
        cost = _cost(board, row)
        secs = cost.get("seconds_per_object", np.nan)
        hours = cost.get("train_device_hours", np.nan)
        raw.append(
            f'<tr><td title="{_e(row.display)}">{_e(row.label)}</td>'
            + "".join(_raw_cell(board, row, c) for c in ctxs)
            + f"<td>{int(r['n'].max())}</td><td>{int(r['failures'].sum())}</td>"
            + f'<td data-sort="{_num(secs)}">{_e(describe_seconds(secs))}</td>'
            + f'<td data-sort="{_num(hours)}">'
            + (f"{hours:.3g}" if np.isfinite(hours) else "–")
            + f'</td><td class="wrap">{_e(describe_training(cost, False) if cost else "–")}'
            + "</td></tr>"
        )
    raw.append("</tbody></table>")
    norm = [
        f'<table class="sortable" id="norm-{_e(table_id(board))}"><thead><tr><th>method</th>'
        f"{head}</tr></thead><tbody>"
    ]
    for row in board.rows:
        norm.append(
            f"<tr><td>{_e(row.label)}</td>"
            + "".join(_norm_cell(board, row, c) for c in ctxs)
            + "</tr>"
        )
    norm.append("</tbody></table>")
    return "\n".join(raw), "\n".join(norm)


def winners_html(board: Board) -> str:
    """In words, per context size: the best row and the rows tied with it."""
    from shapebench.boards.cards import higher_is_better

    labels = {r.variant: r.label for r in board.rows}
    direction = "highest" if higher_is_better(board.metric, board.card) else "lowest"
    items = []
    for ctx in board.contexts:
        s = board.significance[board.significance.context == ctx]
        best = s[s.best]
        if best.empty:
            continue
        tied = [labels.get(v, v) for v in s[s.tied].variant]
        text = f"<b>{ctx} points</b>: <b>{_e(labels.get(best.iloc[0].variant, ''))}</b>"
        text += (
            f" (not significantly better than {_e(', '.join(tied))})"
            if tied
            else " (significantly better than every other row)"
        )
        items.append(f"<li>{text}</li>")
    return (
        f"<p>Winner ({direction} mean) per context size, paired Wilcoxon over the same "
        f'objects, Holm-corrected:</p><ul class="winners">{"".join(items)}</ul>'
        + _floor_summary(board)
    )


def floor_sentences(board: Board) -> list[str]:
    """Per context size, in words: how many rows are not significantly better than the floor,
    and which (plain text; none without floor rows)."""
    if board.floors is None or board.floors.empty:
        return []
    labels = {r.variant: r.label for r in board.rows}
    out = []
    for ctx in board.contexts:
        f = board.floors[board.floors.context == ctx]
        if f.empty:
            continue
        floor = labels.get(f.iloc[0]["floor"], f.iloc[0]["floor"])
        below = [labels.get(v, v) for v in f[f.below_floor.astype(bool)].variant]
        order = {r.label: i for i, r in enumerate(board.rows)}
        below.sort(key=lambda label: order.get(label, len(order)))
        text = (
            f"At {ctx} points {len(below)} of {len(f)} rows are not better than the "
            f"{'better ' if len(floor_labels(board)) > 1 else ''}floor ({floor})"
        )
        out.append(text + (": " + ", ".join(below) + "." if below else "."))
    return out


def _floor_summary(board: Board) -> str:
    sentences = floor_sentences(board)
    if not sentences:
        return ""
    items = "".join(f"<li>{_e(t)}</li>" for t in sentences)
    return (
        f"<p>Floors ({FLOOR_MARK} in the table): a row is better than the floor only with a "
        "better mean and a Holm-corrected paired Wilcoxon p below α = "
        f'{ALPHA}.</p><ul class="floors">{items}</ul>'
    )


def categories_html(board: Board) -> str:
    """The per-category means (median in the title), one table per context size, the largest
    open; "" without categories."""
    cats = board.categories
    if cats is None or cats.empty or cats["category"].nunique() < 2:
        return ""
    names = sorted(cats["category"].unique(), key=str)
    parts = [
        "<h3>Per category</h3>",
        '<p class="note">Mean over each category\'s samples under the failure rule (hover a '
        "cell for its median and sample count); <code>shapebench leaderboard</code> writes them "
        "all beside the table as <code>&lt;table&gt;-categories.csv</code>.</p>",
    ]
    for ctx in sorted(board.contexts, reverse=True):
        at = cats[cats.context == ctx]
        if at.empty:
            continue
        head = "".join(f"<th>{_e(c)}</th>" for c in names)
        body = []
        for row in board.rows:
            mine = at[at.variant == row.variant].set_index("category")
            if mine.empty:
                continue
            cells = []
            for c in names:
                if c not in mine.index:
                    cells.append('<td data-sort="Infinity">–</td>')
                    continue
                m = mine.loc[c]
                cells.append(
                    f'<td data-sort="{_num(m["mean"])}" title="median {m["median"]:.2f}, '
                    f'n {int(m["n"])}">{m["mean"]:.2f}</td>'
                )
            body.append(f"<tr><td>{_e(row.label)}</td>{''.join(cells)}</tr>")
        table = (
            f'<table class="sortable" id="cat-{_e(table_id(board))}-{ctx}"><thead><tr>'
            f"<th>method</th>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"
        )
        opened = " open" if ctx == max(board.contexts) else ""
        parts.append(
            f"<details{opened}><summary>{ctx} points</summary>"
            f'<div class="scroll">{table}</div></details>'
        )
    return "\n".join(parts)
