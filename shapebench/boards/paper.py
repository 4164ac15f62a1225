"""The paper's own figures (Tables 1-6), shipped as tidy CSV, to stand beside our results.

``data/paper_results.csv`` columns: table, dataset, split, category, method, context, metric,
kind (``raw_x1000`` or ``normalized``), mean, std. The paper's Chamfer is logged x1000 and, from
its magnitudes, squared (see docs/metrics.md); its normalised values divide by MSC without
latent optimisation.
"""

from __future__ import annotations

from importlib.resources import files

import pandas as pd

#: Row order of the paper's tables.
PAPER_METHOD_ORDER = [
    "Gauss densification",
    "PCN",
    "OccNet",
    "DeepSDF",
    "IGR",
    "MSC (w/o opt)",
    "MSC (w/ opt)",
]


def paper_results() -> pd.DataFrame:
    with files("shapebench").joinpath("data/paper_results.csv").open() as fh:
        return pd.read_csv(fh)


def paper_table(dataset: str, split: str) -> pd.DataFrame:
    """The overall ('all' categories) rows for a dataset and split; empty if the paper has none."""
    df = paper_results()
    split_in_paper = "all" if dataset == "icl-nuim" else split
    return df[(df.dataset == dataset) & (df.split == split_in_paper) & (df.category == "all")]
