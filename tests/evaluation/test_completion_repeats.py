"""A completion depends on its context and seed only, not on what the process did before."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import SMALL_IGR, TINY

pytestmark = pytest.mark.slow  # runs the CLI in subprocesses


def _values(sb, k: int, label_runs) -> pd.Series:
    run = next(r for r in label_runs if r.data.tags["context_size"] == str(k))
    dst = sb.workspace / "dl" / run.info.run_id
    dst.mkdir(parents=True)
    path = sb.client().download_artifacts(run.info.run_id, "per_object.csv", str(dst))
    return pd.read_csv(path).set_index("object")["chamfer-l2"]


def test_a_cell_alone_equals_the_same_cell_after_others(shapebench):
    sb = shapebench
    base = ("run", "-m", "igr", "-d", "synthetic", *TINY, "--split", "novel", *SMALL_IGR, "-q")
    full = sb(*base, "--contexts", "50,100")
    assert full.returncode == 0, full.stderr
    first = _values(sb, 100, sb.cell_runs("synthetic-novel"))
    alone = sb(*base, "--contexts", "100", "--force")  # k=100 first in its process this time
    assert alone.returncode == 0, alone.stderr
    newest = sorted(sb.cell_runs("synthetic-novel"), key=lambda r: r.info.start_time)[-1:]
    second = _values(sb, 100, newest)
    np.testing.assert_array_equal(first.to_numpy(), second.loc[first.index].to_numpy())
