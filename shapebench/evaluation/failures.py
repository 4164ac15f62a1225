"""What went wrong in a cell, read from its per-object table: objects that failed (column
``status``/``error``), metrics that raised on an object (columns ``metric_error.<name>``) and
metrics that did not apply to one (columns ``not_applicable.<name>``, not an error), ranked and
counted for the run's summary."""

from __future__ import annotations

import pandas as pd

#: Distinct failure reasons printed per cell: enough that a folder with a few broken files names
#: every one of them, few enough that a dataset failing object by object stays readable.
TOP_REASONS = 10
#: Per-object column prefix holding the error of a metric that raised on that object.
METRIC_ERROR = "metric_error."
#: Per-object column prefix holding why a metric does not apply to that object (the metric
#: raised :class:`~shapebench.api.metric.NotApplicable`): not an error, and no value.
NOT_APPLICABLE = "not_applicable."


def traceback_text(exc: BaseException) -> str:
    """The full traceback of ``exc``, as the per-object table keeps it (column ``traceback``)."""
    import traceback

    return "".join(traceback.format_exception(exc)).strip()


def failure_reasons(table: pd.DataFrame, top: int = TOP_REASONS) -> list[tuple[str, int]]:
    """The most common errors of a per-object table (failed objects, and metrics that raised
    on an object, as ``metric NAME: ...``), with their counts."""
    return [(reason, n) for reason, n, _ in distinct_errors(table, top)]


def distinct_errors(table: pd.DataFrame, top: int = TOP_REASONS) -> list[tuple[str, int, str]]:
    """(first line of the error, count, the first such object's traceback), most common first."""
    errors: list[tuple[str, str]] = []
    tracebacks = table["traceback"] if "traceback" in table else pd.Series("", index=table.index)
    if "status" in table and "error" in table:
        for i in table.index[table["status"] != "ok"]:
            errors.append((_first_line(table.at[i, "error"]), tracebacks.get(i, "")))
    for col in [c for c in table.columns if str(c).startswith(METRIC_ERROR)]:
        name = str(col)[len(METRIC_ERROR) :]
        for i in table.index[table[col].notna() & (table[col] != "")]:
            errors.append(
                (f"metric {name}: {_first_line(table.at[i, col])}", tracebacks.get(i, ""))
            )
    counts: dict[str, list] = {}
    for reason, tb in errors:
        entry = counts.setdefault(reason, [0, tb if isinstance(tb, str) else ""])
        entry[0] += 1
    ranked = sorted(counts.items(), key=lambda kv: -kv[1][0])[:top]
    return [(reason, n, tb) for reason, (n, tb) in ranked]


def _first_line(error: object) -> str:
    text = str(error) if isinstance(error, str) and error else "unknown"
    return text.splitlines()[0][:200]


def not_applicable(table: pd.DataFrame, metric: str) -> pd.Series:
    """Per row of a per-object table, whether ``metric`` did not apply to that object."""
    col = f"{NOT_APPLICABLE}{metric}"
    if col not in table:
        return pd.Series(False, index=table.index)
    return table[col].notna() & (table[col].astype(str) != "")


def not_applicable_reasons(table: pd.DataFrame) -> list[tuple[str, str, int]]:
    """(metric, reason, objects) for every metric that did not apply to some object."""
    out = []
    for col in [c for c in table.columns if str(c).startswith(NOT_APPLICABLE)]:
        reasons = table[col][not_applicable(table, str(col)[len(NOT_APPLICABLE) :])]
        for reason, n in reasons.astype(str).value_counts().items():
            out.append((str(col)[len(NOT_APPLICABLE) :], str(reason), int(n)))
    return out


def metric_errors(table: pd.DataFrame) -> list[str]:
    """The metrics that raised on some object of this per-object table."""
    return sorted(
        str(c)[len(METRIC_ERROR) :]
        for c in table.columns
        if str(c).startswith(METRIC_ERROR) and table[c].notna().any() and (table[c] != "").any()
    )
