"""The arithmetic of a leaderboard, as pure functions over a per-object table (no MLflow).

Input: one row per (variant, context size, seed, object) with the columns ``variant`` (the row's
key), ``label``, ``context``, ``seed``, ``object``, ``status`` (``ok`` or not) and ``value`` (the
metric, raw). Output: the raw and normalised tables and, per context size, which variant is best
and which are statistically tied with it.

Rules (documented in docs/metrics.md, footnoted under every table):

* **Failures count.** A failed object scores as the *worst* successful score of its cell (the same
  variant and context size), so a method cannot improve its mean by failing on hard objects. The
  success-only mean is kept beside it (``mean_ok``), with ``n_ok`` of ``n`` objects.
* **Samples.** With several seeds, every (object, seed) pair is one sample.
* **Normalised** (the paper's equation 8): each object's value divided by the reference variant's
  value on the same object, context size and seed, both with the failure rule above; then mean and
  sample standard deviation.
* **Significance.** At each context size the best variant is the one with the best mean. Every
  other variant is compared with it by a two-sided Wilcoxon signed-rank test over the samples
  both have (exact or approximate, with ties and zeros, as :func:`paired_p` states), and the
  p-values are Holm-corrected across the comparisons at that size. A variant whose corrected
  p-value is at least ``alpha`` is *tied* with the best.
* **Floors.** At each context size the floor is the better (by mean) of the floor rows present
  (returning the context unchanged, retrieving the nearest training shape). Every other row is
  compared with it by the same test (Holm-corrected across the rows at that size) and is *below
  the floor* unless its mean is better and its corrected p-value is below ``alpha``.
* **Tails.** Beside each mean, the median and, where the metric card states a tail threshold,
  the share of samples worse than it, both under the failure rule.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

ALPHA = 0.05
TEST_NAME = (
    "two-sided Wilcoxon signed-rank test over the same objects, zero differences dropped, exact "
    "up to 50 differing pairs and the tie-corrected normal approximation above, Holm-corrected"
)
KEYS = ["object", "seed"]


def with_failure_rule(per_obj: pd.DataFrame, higher_is_better: bool = False) -> pd.DataFrame:
    """``per_obj`` plus ``scored``: the value, or for a failed object the worst successful value
    of its cell (NaN when every object of the cell failed)."""
    out = per_obj.copy()
    ok = out["status"] == "ok"
    values = out["value"].where(ok)
    worst = values.groupby([out["variant"], out["context"]]).transform(
        "min" if higher_is_better else "max"
    )
    out["scored"] = values.fillna(worst)
    return out


def _mean_std(v: np.ndarray) -> tuple[float, float]:
    if len(v) == 0:
        return (np.nan, np.nan)
    return (float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0)


def raw_table(
    scored: pd.DataFrame, tail: float | None = None, higher_is_better: bool = False
) -> pd.DataFrame:
    """Per (variant, context): n, n_ok, failures, mean/std and ``median`` under the failure rule
    (the instance mean: every object weighs the same), the success-only mean_ok/std_ok,
    with ``tail`` (a value at the metric's own scale) ``tail_share``: the share of samples
    worse than it (above it; below it when ``higher_is_better``), and, where ``scored``
    has a ``category`` column, ``category_mean``: the mean of the per-category means under the
    failure rule (every category weighs the same: PCN's and PoinTr's "overall") over
    ``categories`` categories."""
    rows = []
    for (variant, ctx), g in scored.groupby(["variant", "context"], sort=True):
        ok = g[g["status"] == "ok"]["value"].to_numpy(dtype=float)
        mean_ok, std_ok = _mean_std(ok)
        values = g["scored"].dropna().to_numpy(dtype=float)
        row = _summary(variant, ctx, g, values)
        row.update(
            median=float(np.median(values)) if len(values) else np.nan,
            mean_ok=mean_ok,
            std_ok=std_ok,
            n=len(g),
            n_ok=len(ok),
            failures=len(g) - len(ok),
        )
        if tail is not None:
            worse = values < tail if higher_is_better else values > tail
            row["tail_share"] = float(worse.mean()) if len(values) else np.nan
        if "category" in g:
            per_category = g.dropna(subset=["scored"]).groupby("category")["scored"].mean()
            row.update(
                category_mean=float(per_category.mean()) if len(per_category) else np.nan,
                categories=len(per_category),
            )
        rows.append(row)
    return pd.DataFrame(rows, columns=RAW_COLUMNS if not rows else None)


#: The columns of an empty raw table (every object of every row without a value).
RAW_COLUMNS = [
    "variant",
    "label",
    "context",
    "mean",
    "std",
    "median",
    "mean_ok",
    "std_ok",
    "n",
    "n_ok",
]


def category_table(scored: pd.DataFrame) -> pd.DataFrame:
    """Per (variant, context, category): ``mean`` and ``median`` under the failure rule over the
    ``n`` samples of the category (empty without a ``category`` column): the per-category means
    that :func:`raw_table`'s ``category_mean`` averages."""
    columns = ["variant", "label", "context", "category", "mean", "median", "n"]
    if "category" not in scored or scored.empty:
        return pd.DataFrame(columns=columns)
    usable = scored.dropna(subset=["scored"])
    grouped = usable.groupby(["variant", "context", "category"], sort=True)
    out = grouped.agg(
        label=("label", "first"),
        mean=("scored", "mean"),
        median=("scored", "median"),
        n=("scored", "size"),
    ).reset_index()
    out["context"] = out["context"].astype(int)
    return out[columns]


def worst_samples(scored: pd.DataFrame, higher_is_better: bool = False) -> pd.DataFrame:
    """Per (variant, context): the sample with the worst value under the failure rule (the
    highest; the lowest when ``higher_is_better``), ties to the first object and seed:
    ``variant``, ``context``, ``object``, ``seed``, ``scored``, ``status``."""
    columns = ["variant", "context", "object", "seed", "scored", "status"]
    usable = scored.dropna(subset=["scored"])
    if usable.empty:
        return pd.DataFrame(columns=columns)
    ordered = usable.sort_values(
        ["variant", "context", "scored", "object", "seed"],
        ascending=[True, True, higher_is_better, True, True],
        kind="stable",
    )
    return (
        ordered.groupby(["variant", "context"], sort=True).head(1)[columns].reset_index(drop=True)
    )


def _summary(variant: str, ctx: int, group: pd.DataFrame, values: np.ndarray) -> dict:
    """The columns every table shares: the row, the context size, mean and std of ``values``."""
    mean, std = _mean_std(values)
    label = group["label"].iloc[0]
    return {"variant": variant, "label": label, "context": int(ctx), "mean": mean, "std": std}


def normalized_table(scored: pd.DataFrame, reference: str) -> pd.DataFrame | None:
    """Equation 8 against the variant ``reference`` (a variant key); None if it has no runs."""
    ref = scored[(scored["variant"] == reference) & scored["scored"].notna()]
    if ref.empty:
        return None
    ref = ref[["context", *KEYS, "scored"]].rename(columns={"scored": "ref"})
    merged = scored.merge(ref, on=["context", *KEYS], how="inner")
    rows = []
    for (variant, ctx), g in merged.groupby(["variant", "context"], sort=True):
        usable = g[g["scored"].notna() & (g["ref"] > 0)]
        row = _summary(variant, ctx, g, (usable["scored"] / usable["ref"]).to_numpy(dtype=float))
        row.update(n=len(usable), failures=int((g["status"] != "ok").sum()))
        rows.append(row)
    return pd.DataFrame(rows)


#: Up to this many nonzero differences :func:`paired_p` computes the exact null distribution.
EXACT_MAX_N = 50


def paired_p(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sided Wilcoxon signed-rank p-value of paired samples, by a method stated here, so that
    it does not depend on the SciPy version (1.0 when the samples never differ).

    ``scipy.stats.wilcoxon``'s default ``method="auto"`` picks the exact distribution, a
    permutation test or the normal approximation from the sample size, the ties and the zeros,
    and SciPy releases have drawn those lines differently; the failure rule creates ties by
    design (every failed object of a cell scores the same) and zero differences (an object both
    rows fail). So the test is computed here:

    * **Zeros** (pairs that do not differ) are dropped before ranking (Wilcoxon's own rule,
      ``zero_method="wilcox"``, the default of SciPy and of R's ``wilcox.test``): a pair both
      rows fail says nothing about which row is better. ``n`` counts the pairs left.
    * **Ties** among ``|d|`` take their average rank.
    * **n <= EXACT_MAX_N (50): exact.** The p-value is the exact permutation probability of a
      rank sum ``W+`` at least as extreme, over all ``2^n`` equally likely sign assignments of
      the observed (tie-averaged) ranks: two-sided, ``min(1, 2 min(P(W+ <= w), P(W+ >= w)))``.
      Without ties this is the classical exact test (R's ``wilcox.test`` and SciPy's
      ``method="exact"`` for small n); with ties it stays exact (conditional on the ranks),
      where the tabulated distribution does not apply. Our smallest tables, 22 validation
      objects with one seed, are tested this way.
    * **n > 50: normal approximation** of ``W+`` (mean ``n(n+1)/4``, variance
      ``n(n+1)(2n+1)/24 - sum(t^3 - t)/48`` over the groups of ``t`` tied ``|d|``), without a
      continuity correction: ``p = erfc(|z| / sqrt 2)``, what every SciPy version computes there
      (``zero_method="wilcox", correction=False, method="asymptotic"``) and accurate at the
      sizes of our test tables (150 objects x 3 seeds = 450 pairs).
    """
    from math import erfc, sqrt

    from scipy.stats import rankdata

    diff = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    diff = diff[diff != 0]
    n = len(diff)
    if n == 0:
        return 1.0
    ranks = rankdata(np.abs(diff))  # average ranks: whole or half numbers
    if n <= EXACT_MAX_N:
        return _exact_signed_rank_p(np.rint(2 * ranks).astype(int), diff > 0)
    w_plus = float(ranks[diff > 0].sum())
    _, ties = np.unique(np.abs(diff), return_counts=True)
    variance = n * (n + 1) * (2 * n + 1) / 24 - float((ties**3 - ties).sum()) / 48
    z = (w_plus - n * (n + 1) / 4) / sqrt(variance)
    return min(1.0, erfc(abs(z) / sqrt(2)))


def _exact_signed_rank_p(doubled_ranks: np.ndarray, positive: np.ndarray) -> float:
    """Two-sided exact p of the signed-rank sum: the distribution of the sum of the positive
    (doubled, hence integer) ranks over all sign assignments, built one rank at a time."""
    total = int(doubled_ranks.sum())
    counts = np.zeros(total + 1)
    counts[0] = 1.0  # below 2^53 for n <= 50: the counts stay exact in float64
    for r in doubled_ranks:
        shifted = np.zeros_like(counts)
        shifted[r:] = counts[: total + 1 - r]
        counts += shifted
    w = int(doubled_ranks[positive].sum())
    all_ = counts.sum()
    lower, upper = counts[: w + 1].sum() / all_, counts[w:].sum() / all_
    return float(min(1.0, 2 * min(lower, upper)))


def paired_shift(a: np.ndarray, b: np.ndarray) -> float:
    """The Hodges-Lehmann estimate of how far ``a`` lies from ``b`` (the median of the Walsh
    averages (d_i + d_j) / 2, i <= j, of the differences d = a - b): the shift the signed-rank
    test of :func:`paired_p` tests, so its sign says which way a small two-sided p points.
    Unlike the count of pairs where ``a`` is lower it weighs how far apart the pairs are, and
    unlike the difference of means a few far-off pairs do not carry it."""
    diff = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    n = len(diff)
    if n == 0:
        return float("nan")
    walsh = n * (n + 1) // 2
    if walsh <= _WALSH_IN_MEMORY:
        i, j = np.triu_indices(n)
        return float(np.median((diff[i] + diff[j]) / 2))
    # A board of 16,000 pairs has 128 million Walsh averages (1 GB): select the middle ones
    # instead, in O(n) memory.
    ordered = np.sort(diff)
    middle = _walsh_order_statistic(ordered, (walsh + 1) // 2)
    if walsh % 2:
        return middle
    return (middle + _walsh_order_statistic(ordered, walsh // 2 + 1)) / 2


#: Up to this many Walsh averages :func:`paired_shift` forms them all (16 MB).
_WALSH_IN_MEMORY = 2_000_000


def _walsh_order_statistic(ordered: np.ndarray, k: int) -> float:
    """The ``k``-th smallest (from 1) Walsh average (d_i + d_j) / 2, i <= j, of the sorted
    differences ``ordered``, to the last bits of a float: bisection on the value, counting the
    averages at or below it with one binary search per difference."""
    n = len(ordered)
    start = np.arange(n)

    def at_or_below(t: float) -> int:
        # For each i, the j >= i with d_j <= 2t - d_i.
        ends = np.searchsorted(ordered, 2 * t - ordered, side="right")
        return int(np.maximum(ends - start, 0).sum())

    lo, hi = float(ordered[0]) - 1.0, float(ordered[-1])  # fewer than k at lo, all at hi
    while True:
        mid = (lo + hi) / 2
        if not lo < mid < hi or hi - lo <= 1e-13 * max(1.0, abs(hi)):
            return hi
        if at_or_below(mid) >= k:
            hi = mid
        else:
            lo = mid


def holm(pvalues: list[float]) -> list[float]:
    """Holm's step-down correction; adjusted p-values in the input order."""
    m = len(pvalues)
    order = np.argsort(pvalues, kind="stable")
    adjusted = np.empty(m)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * pvalues[i]))
        adjusted[i] = running
    return adjusted.tolist()


#: The columns of :func:`floor_test`.
FLOOR_COLUMNS = ["variant", "context", "floor", "p_vs_floor", "p_floor_holm", "below_floor"]


def floor_test(
    scored: pd.DataFrame,
    floors: list[str],
    higher_is_better: bool = False,
    alpha: float = ALPHA,
) -> pd.DataFrame:
    """Per (variant, context) of every row but the floors: ``floor`` (the variant key of the
    better floor at that size: of the variants ``floors`` with a mean there, the one with the
    better mean), ``p_vs_floor`` (the paired test over the samples both have, as
    :func:`significance`), ``p_floor_holm`` (Holm-corrected across the rows at that size) and
    ``below_floor``: the row is not significantly better than the floor (its mean is not better,
    or its corrected p-value is at least ``alpha``). Empty when no floor has a mean."""
    rows = []
    for ctx, g in scored.groupby("context", sort=True):
        means = g.groupby("variant")["scored"].mean().dropna()
        present = means[means.index.isin(floors)]
        if present.empty:
            continue
        floor = present.idxmax() if higher_is_better else present.idxmin()
        floor_values = g[g["variant"] == floor].set_index(KEYS)["scored"]
        tested, pvals, better = [], [], []
        for variant in sorted(means.index):
            if variant in floors:  # the floors define the bar; they are not held to it
                continue
            values = g[g["variant"] == variant].set_index(KEYS)["scored"]
            both = pd.concat([floor_values, values], axis=1, join="inner").dropna()
            tested.append(variant)
            pvals.append(paired_p(both.iloc[:, 0].to_numpy(), both.iloc[:, 1].to_numpy()))
            better.append(
                means[variant] > means[floor] if higher_is_better else means[variant] < means[floor]
            )
        for variant, p, adj, is_better in zip(tested, pvals, holm(pvals), better, strict=True):
            rows.append(
                {
                    "variant": variant,
                    "context": int(ctx),
                    "floor": floor,
                    "p_vs_floor": p,
                    "p_floor_holm": adj,
                    "below_floor": not (is_better and adj < alpha),
                }
            )
    return pd.DataFrame(rows, columns=FLOOR_COLUMNS)


def significance(
    scored: pd.DataFrame, higher_is_better: bool = False, alpha: float = ALPHA
) -> pd.DataFrame:
    """Per (variant, context): ``best``, ``tied`` (with the best), ``p_vs_best`` (raw Wilcoxon),
    ``p_holm`` (corrected) and ``n_pairs`` (samples compared)."""
    rows = []
    for ctx, g in scored.groupby("context", sort=True):
        means = g.groupby("variant")["scored"].mean().dropna()
        if means.empty:
            continue
        best = means.idxmax() if higher_is_better else means.idxmin()
        best_values = g[g["variant"] == best].set_index(KEYS)["scored"]
        others, pvals, pairs = [], [], []
        for variant in sorted(means.index):
            if variant == best:
                continue
            values = g[g["variant"] == variant].set_index(KEYS)["scored"]
            both = pd.concat([best_values, values], axis=1, join="inner").dropna()
            others.append(variant)
            pvals.append(paired_p(both.iloc[:, 0].to_numpy(), both.iloc[:, 1].to_numpy()))
            pairs.append(len(both))
        rows.append(
            {
                "variant": best,
                "context": int(ctx),
                "best": True,
                "tied": False,
                "p_vs_best": np.nan,
                "p_holm": np.nan,
                "n_pairs": len(best_values),
            }
        )
        for variant, p, adj, n in zip(others, pvals, holm(pvals), pairs, strict=True):
            rows.append(
                {
                    "variant": variant,
                    "context": int(ctx),
                    "best": False,
                    "tied": adj >= alpha,
                    "p_vs_best": p,
                    "p_holm": adj,
                    "n_pairs": n,
                }
            )
    return pd.DataFrame(
        rows, columns=["variant", "context", "best", "tied", "p_vs_best", "p_holm", "n_pairs"]
    )
