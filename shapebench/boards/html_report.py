"""``shapebench report``: one self-contained HTML page per dataset, built from the MLflow runs.

Per split (one leaderboard each, :func:`shapebench.boards.leaderboard.build_board`): who wins at
each context size and which rows are statistically tied with the winner, the raw and normalised
tables (sortable: click a header; their HTML is :mod:`shapebench.boards.html_tables`), the cost
of each row, the metric card, the figures of :mod:`shapebench.boards.figures` (inline SVG), the
qualitative grids of :mod:`shapebench.evaluation.pictures` (rows = methods, columns = context
sizes, drawn from the pictures the cells logged) and, for methods that return posterior
samples, the completions coloured by their per-point spread; then
where the numbers come from (versions, git commits, dataset fingerprints).

The page needs nothing but a browser: images are inline (SVG, PNG data URIs), the sorting is a
few lines of vanilla JavaScript, and nothing is fetched from the network. It is written beside
the leaderboards as ``<dataset>-report.html`` and logged to each table's MLflow run.
"""

from __future__ import annotations

import base64
import importlib.metadata
import platform
import shlex
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pandas as pd

from shapebench import __version__
from shapebench.api.errors import ShapebenchError
from shapebench.api.protocol import DEFAULT_FRAME, FRAMES
from shapebench.boards.board import Board, table_id, table_title
from shapebench.boards.html_tables import categories_html, tables_html, winners_html
from shapebench.boards.html_tables import escape as _e
from shapebench.boards.leaderboard import BoardQuery, board_path, build_board
from shapebench.boards.markdown import card_line, floor_legend
from shapebench.boards.report_pictures import grids_and_spreads, worst_pictures
from shapebench.boards.splits import protocols_with_runs, splits_with_runs
from shapebench.config import Settings
from shapebench.store.tracking import Tracker, experiment_name

#: Distributions whose versions the provenance section lists.
VERSIONS = ["shapebench", "mlflow", "numpy", "scipy", "torch", "pytorch-lightning", "matplotlib"]


@dataclass
class Section:
    """What the page shows of one table (one split)."""

    board: Board
    figures: dict[str, str]  # name -> inline SVG
    grids: list[tuple[str, str]] = field(default_factory=list)  # (object, PNG data URI)
    spreads: list[tuple[str, str]] = field(default_factory=list)  # (caption, PNG data URI)
    #: Per row, its worst sample at the largest context size: (label, object, seed, value,
    #: status, PNG data URI or "" where the cell did not picture that object).
    worst: list[tuple[str, str, int, float, str, str]] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)  # written beside the report


def report_path(out_dir: Path, dataset: str, frame: str = DEFAULT_FRAME) -> Path:
    suffix = "" if frame == DEFAULT_FRAME else f"-{frame}"
    return out_dir / f"{dataset}{suffix}-report.html"


def _svg(fig: Any) -> str:
    """A matplotlib figure as inline SVG markup (no XML prologue, scales with the page)."""
    import io

    buf = io.StringIO()
    fig.savefig(buf, format="svg")
    text = buf.getvalue()
    return text[text.index("<svg") :]


# -- pictures read back from the cells -------------------------------------------------------


STYLE = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2rem auto;
max-width:1400px;padding:0 1rem;color:#222;line-height:1.4}
h1{font-size:1.6rem}h2{border-bottom:2px solid #ddd;padding-bottom:.2rem;margin-top:2.5rem}
table{border-collapse:collapse;margin:.8rem 0;font-size:.85rem}
th,td{border:1px solid #ccc;padding:.25rem .5rem;text-align:right;white-space:nowrap}
th{background:#f2f2f2;cursor:pointer;user-select:none}
th[data-dir=asc]::after{content:" \\25B2"}th[data-dir=desc]::after{content:" \\25BC"}
td:first-child,th:first-child{text-align:left}.wrap{white-space:normal;text-align:left;
min-width:14rem}.scroll{overflow-x:auto}
td.best{font-weight:bold;background:#e6f4ea}td.tied{background:#f3f9f4}
.note{color:#555;font-size:.85rem}.figure svg{max-width:100%;height:auto}
.pictures img{max-width:100%;border:1px solid #eee;margin:.3rem 0}
code{background:#f5f5f5;padding:0 .2rem}dl.prov dt{font-weight:bold}
dl.prov dd{margin:0 0 .4rem 1rem}
"""

SORT_JS = """
document.querySelectorAll("table.sortable").forEach(function (table) {
  table.querySelectorAll("th").forEach(function (th, col) {
    th.addEventListener("click", function () {
      var dir = th.dataset.dir === "asc" ? "desc" : "asc";
      table.querySelectorAll("th").forEach(function (h) { delete h.dataset.dir; });
      th.dataset.dir = dir;
      var key = function (row) {
        var cell = row.cells[col], v = cell.dataset.sort !== undefined ? cell.dataset.sort
          : cell.textContent.trim(), n = parseFloat(v);
        return isNaN(n) ? v.toLowerCase() : n;
      };
      var body = table.tBodies[0];
      Array.from(body.rows).sort(function (a, b) {
        var x = key(a), y = key(b);
        var c = (typeof x === "number" && typeof y === "number") ? x - y
          : String(x).localeCompare(String(y));
        return dir === "asc" ? c : -c;
      }).forEach(function (row) { body.appendChild(row); });
    });
  });
});
"""


def _worst(sec: Section) -> str:
    """Per row, its worst sample at the largest context size: named, and pictured where the
    cell pictured that object."""
    if not sec.worst:
        return ""
    b = sec.board
    ctx = max(b.contexts)
    items, pictures = [], []
    for label, obj, seed, value, status, uri in sec.worst:
        shown = "pictured below" if uri else "not pictured by its cell"
        if status != "ok":  # scored as the worst success of its cell
            shown = f"{status}, scored as the worst success; {shown}"
        items.append(
            f"<li><code>{_e(label)}</code>: <code>{_e(obj)}</code>, seed {seed}: "
            f"{value:.2f} ({_e(shown)})</li>"
        )
        if uri:
            pictures.append(
                f'<div class="pictures"><img alt="worst object of {_e(label)}: {_e(obj)}" '
                f'src="{uri}"></div>'
            )
    return "\n".join(
        [
            f"<h3>Worst objects at {ctx} points</h3>",
            '<p class="note">Per row, the (object, seed) pair with the worst value at the '
            "largest context size, so that failures are seen and not averaged away. A cell "
            "pictures only the split's fixed objects (the grids above): a worst object among "
            "them is pictured, the others are named.</p>",
            f"<ul>{''.join(items)}</ul>",
            *pictures,
        ]
    )


def _provenance(board: Board) -> str:
    runs = board.runs.copy() if board.runs is not None else pd.DataFrame()
    if {"plugin_distribution", "plugin_version"} <= set(runs.columns):
        runs["_plugin"] = (
            runs["plugin_distribution"].fillna("") + " " + runs["plugin_version"].fillna("")
        ).str.strip()

    def used(col: str) -> str:
        if col not in runs:
            return "–"
        counts = runs[col].fillna("").replace("", "unknown").value_counts()
        return ", ".join(f"<code>{_e(v)}</code> ({n} runs)" for v, n in counts.items())

    rows = "".join(
        f"<li><code>{_e(r.label)}</code>: {_e(r.method)}, code <code>{_e(r.code or '–')}</code>"
        + (f", checkpoint <code>{_e(r.checkpoint[:16])}</code>" if r.checkpoint else "")
        + "</li>"
        for r in board.rows
    )
    return (
        '<dl class="prov">'
        f"<dt>dataset</dt><dd>{_e(board.dataset)} / {_e(board.split)}, fingerprint "
        f"<code>{_e(board.fingerprint)}</code>"
        + (f", data root <code>{_e(board.data_root)}</code>" if board.data_root else "")
        + f"; versions {used('dataset_version')}</dd>"
        f"<dt>shapebench that computed the runs</dt><dd>{used('shapebench_version')}</dd>"
        f"<dt>git commits of the runs</dt><dd>{used('git_commit')}</dd>"
        f"<dt>plugins</dt><dd>{used('_plugin')}</dd>"
        f"<dt>MLflow experiment</dt><dd><code>{_e(experiment_name(board.dataset, board.split))}"
        f"</code> (id {_e(board.experiment_id)})</dd>"
        f"<dt>rows</dt><dd><ul>{rows}</ul></dd></dl>"
    )


def _environment() -> str:
    from shapebench.store.provenance import git_commit

    versions = []
    for dist in VERSIONS:
        try:
            versions.append(f"{dist} {importlib.metadata.version(dist)}")
        except importlib.metadata.PackageNotFoundError:
            continue
    return (
        f"shapebench {_e(__version__)} at commit <code>{_e(git_commit())}</code>; Python "
        f"{_e(platform.python_version())} on {_e(platform.platform())}; "
        f"{_e(', '.join(versions))}"
    )


def _tail_note(board: Board) -> str:
    """What the parenthesis beside each mean says."""
    from shapebench.boards.cards import higher_is_better, worse_word

    text = "Beside each mean: the median (med.)"
    if board.tail_threshold is not None:
        worse = worse_word(higher_is_better(board.metric, board.card))
        text += (
            f" and the share of samples {worse} {board.tail_threshold:g}, the metric card's "
            "tail threshold"
        )
    return text + "."


def _section(sec: Section) -> str:
    b = sec.board
    raw, norm = tables_html(b)
    sid = _e(table_id(b))
    parts = [
        f'<h2 id="split-{sid}">{_e(b.dataset)} / {_e(table_title(b))}: {_e(b.metric)}</h2>',
        winners_html(b),
        f"<p><b>Metric card</b>: {_e(card_line(b))}. <b>Protocol</b>: {_e(b.protocol)}; "
        f"distances in the {_e(FRAMES[b.frame][1])}.</p>",
        *(f'<p class="note">Left out: {_e(item)}.</p>' for item in b.left_out),
        f"<h3>Raw: {_e(b.metric)} x{b.scale:g}, mean ± std over objects</h3>",
        '<p class="note">Bold: the winner at that context size; ≈ (shaded): not significantly '
        "different from it; hover a cell for its p-values. Click a header to sort. Failed "
        "objects score as the worst success of their cell. " + _e(_tail_note(b)) + "</p>",
        *([f'<p class="note">{_e(floor_legend(b).replace("`", ""))}</p>'] if b.floor_rows else []),
        f'<div class="scroll">{raw}</div>',
        f"<h3>Normalised: per object divided by <code>{_e(b.reference)}</code> "
        "(the paper's eq. 8)</h3>",
        norm if b.normalized is not None else f'<p class="note">{_e(b.note)}</p>',
        categories_html(b),
        "<h3>Figures</h3>",
        *(
            f'<div class="figure" id="fig-{name}-{sid}">{svg}</div>'
            for name, svg in sec.figures.items()
        ),
        "<h3>Completions</h3>",
    ]
    if sec.grids:
        parts.append(
            '<p class="note">Rows: methods; columns: context sizes (first row: the '
            "context points every method was given, and the ground truth). The same "
            "objects for every method.</p>"
        )
        parts += [
            f'<div class="pictures"><img alt="qualitative grid {_e(obj)}" src="{uri}"></div>'
            for obj, uri in sec.grids
        ]
    else:
        parts.append('<p class="note">No pictures logged by these runs.</p>')
    parts.append(_worst(sec))
    if sec.spreads:
        parts.append(
            '<h3>Posterior uncertainty</h3><p class="note">Completions coloured by '
            "the per-point spread over posterior samples (RMS distance to each "
            "sample's nearest point): where the method is unsure.</p>"
        )
        parts += [
            f'<div class="pictures"><img alt="{_e(cap)}" src="{uri}"></div>'
            for cap, uri in sec.spreads
        ]
    parts += ["<h3>Provenance</h3>", _provenance(b)]
    return "\n".join(parts)


def render_html(sections: list[Section], dataset: str, command: str, uri: str) -> str:
    toc = " · ".join(
        f'<a href="#split-{_e(table_id(s.board))}">{_e(table_title(s.board))}</a>' for s in sections
    )
    body = "\n".join(_section(s) for s in sections)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>shapebench report: {_e(dataset)}</title><style>{STYLE}</style></head>
<body>
<h1>shapebench report: {_e(dataset)}</h1>
<p class="note">Generated {datetime.now(timezone.utc):%Y-%m-%d %H:%M UTC} by <code>{_e(command)}
</code> from <code>{_e(uri)}</code>. Splits: {toc}.</p>
{body}
<h2>Environment of this report</h2><p class="note">{_environment()}</p>
<script>{SORT_JS}</script>
</body></html>
"""


def build_report(
    settings: Settings, query: BoardQuery, splits: list[str] | None, out_dir: Path
) -> tuple[Path, float]:
    """Write ``<out_dir>/<dataset>-report.html`` (and each table's figures beside it), log it to
    the tables' MLflow runs; return the page and the seconds it took. One section per split
    (``splits``, or every split with runs) and context protocol of ``query``'s dataset."""
    dataset, frame = query.dataset, query.frame
    from shapebench.boards.figures import board_figures, log_board_artifacts, save

    start = time.perf_counter()
    tracker = Tracker(settings)
    if splits is None:
        splits = splits_with_runs(tracker, dataset)
    sections = []
    tables = [
        (split, one) for split in splits for one in protocols_with_runs(tracker, dataset, split)
    ]
    for split, one in tables:
        board = build_board(tracker, query, split, one)
        if board is None:
            continue
        md = board_path(out_dir, dataset, split, frame, one)
        figures, files = {}, []
        for name, fig in board_figures(board).items():
            files += save(fig, md.with_name(f"{md.stem}-{name}"))
            figures[name] = _svg(fig)
        grids, spreads = grids_and_spreads(tracker, board)
        for obj, uri in grids:  # the grids as files too, beside the figures
            path = md.with_name(f"{md.stem}-grid-{obj.replace('/', '__')}.png")
            path.write_bytes(base64.b64decode(uri.split(",", 1)[1]))
            files.append(path)
        worst = worst_pictures(tracker, board)
        sections.append(Section(board, figures, grids, spreads, files=files, worst=worst))
    if not sections:
        raise ShapebenchError(
            f"no finished runs of dataset {dataset!r} in the {frame} frame in "
            f"{settings.tracking_uri}",
            f"run one first: shapebench run --method gauss --dataset {dataset}",
        )
    command = "shapebench " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    page = report_path(out_dir, dataset, frame)
    page.write_text(render_html(sections, dataset, command, settings.tracking_uri))
    for sec in sections:
        log_board_artifacts(tracker, sec.board, [page, *sec.files])
    return page, time.perf_counter() - start
