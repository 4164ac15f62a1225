"""The paired test of the leaderboards (issue 59): one stated method, not SciPy's "auto".

The p-values are pinned to values worked out by hand below (ranks, rank sum, then every sign
assignment for small n, the tie-corrected normal tail for large n), not by calling
:func:`paired_p` again.
"""

from __future__ import annotations

from math import comb, erfc, sqrt
from statistics import NormalDist

import numpy as np
import pytest

from shapebench.boards import stats as board_stats


def two_sided_normal(z: float) -> float:
    return erfc(abs(z) / sqrt(2))


def brute_force_p(ranks: list[float], w_plus: float) -> float:
    """Two-sided exact p by enumerating every sign assignment of ``ranks``."""
    sums = [
        sum(r for i, r in enumerate(ranks) if signs >> i & 1) for signs in range(2 ** len(ranks))
    ]
    lower = sum(s <= w_plus for s in sums) / len(sums)
    upper = sum(s >= w_plus for s in sums) / len(sums)
    return min(1.0, 2 * min(lower, upper))


def test_ties_and_zeros_small_n_give_the_exact_p():
    # Differences a - b: two zeros (both rows failed: the failure rule gives both the same
    # worst score) and ties among the rest.
    d = np.array([0, 0, 1, -1, 2, 2, 2, 3, 3, -4], dtype=float)
    b = np.arange(10.0, 10.0 + len(d))  # integers: a - b gives d back exactly
    a = b + d
    # Zeros dropped: n = 8, |d| = 1 1 2 2 2 3 3 4 -> average ranks 1.5 1.5 4 4 4 6.5 6.5 8,
    # W+ = 1.5 + 3 * 4 + 2 * 6.5 = 26.5 of 36; 2^8 = 256 sign assignments.
    expected = brute_force_p([1.5, 1.5, 4, 4, 4, 6.5, 6.5, 8], 26.5)
    assert expected == pytest.approx(72 / 256)  # 36 of 256 assignments have W+ >= 26.5
    assert board_stats.paired_p(a, b) == pytest.approx(expected, rel=1e-12)
    assert board_stats.paired_p(b, a) == pytest.approx(expected, rel=1e-12)  # two-sided


def test_every_difference_tied_in_size():
    # |d| all equal (n = 6, all ranks 3.5): W+ is 3.5 x the number of positive signs, a
    # Binomial(6, 1/2); 5 positive: P(>= 5) = 7/64, two-sided 14/64.
    d = np.array([1, 1, 1, 1, 1, -1], dtype=float)
    assert board_stats.paired_p(d, np.zeros(6)) == pytest.approx(14 / 64, rel=1e-12)


def test_ties_at_the_validation_tables_size_stay_exact():
    # 22 differing pairs (the validation tables' objects), all |d| tied, 16 positive, and three
    # zeros: W+ is 11.5 x a Binomial(22, 1/2); two-sided p = 2 P(K >= 16). SciPy's "auto"
    # answers this with the normal approximation (ties, n > 13); here it stays exact.
    d = np.array([0.0] * 3 + [0.5] * 16 + [-0.5] * 6)
    expected = 2 * sum(comb(22, k) for k in range(16, 23)) / 2**22
    assert board_stats.paired_p(d, np.zeros(len(d))) == pytest.approx(expected, rel=1e-12)


def test_one_nonzero_difference_and_all_zeros():
    # One pair differs: its sign is + or - with probability 1/2 each, two-sided p = 1.
    a, b = np.array([1.0, 2.0, 8.0]), np.array([1.0, 2.0, 3.0])
    assert board_stats.paired_p(a, b) == 1.0
    assert board_stats.paired_p(a, a.copy()) == 1.0  # no pair differs: no evidence, no error
    assert board_stats.paired_p(np.array([]), np.array([])) == 1.0


def test_ties_and_zeros_large_n_give_the_hand_computed_normal_p():
    # 5 zeros, then 60 nonzero differences: 20 x +1, 10 x -1, 15 x +2, 15 x -3.
    d = np.array([0] * 5 + [1] * 20 + [-1] * 10 + [2] * 15 + [-3] * 15, dtype=float)
    assert board_stats.EXACT_MAX_N < 60
    # |1| x 30 -> ranks 1..30, average 15.5; |2| x 15 -> 31..45, 38; |3| x 15 -> 46..60, 53.
    # W+ = 20 * 15.5 + 15 * 38 = 880; mean 60*61/4 = 915;
    # variance 60*61*121/24 - ((30^3-30) + 2 (15^3-15)) / 48 = 18452.5 - 701.875.
    z = (880 - 915) / sqrt(18452.5 - 701.875)
    expected = two_sided_normal(z)
    assert expected == pytest.approx(2 * (1 - NormalDist().cdf(abs(z))), rel=1e-12)
    assert expected == pytest.approx(0.7927813, abs=1e-7)
    assert board_stats.paired_p(d, np.zeros(len(d))) == pytest.approx(expected, rel=1e-12)


def test_it_is_scipys_test_with_the_stated_options():
    """The same test as SciPy's with its options named, at the sizes of our tables (22
    validation objects; 150 objects x 3 seeds) and with failure-rule ties and zeros."""
    from scipy.stats import PermutationMethod, wilcoxon

    rng = np.random.default_rng(0)
    a = rng.gamma(2.0, 1.0, 22)
    b = a * rng.lognormal(0.05, 0.3, 22)
    assert board_stats.paired_p(a, b) == pytest.approx(wilcoxon(a, b, method="exact").pvalue)
    for n in (12, 450):
        a = rng.gamma(2.0, 1.0, n)
        b = a * rng.lognormal(0.05, 0.3, n)
        worst_a, worst_b = a.max(), b.max()
        failed = rng.random(n) < 0.2  # both rows fail these: zero differences
        a[failed], b[failed] = worst_a, worst_a
        b[rng.random(n) < 0.1] = worst_b  # only b fails these: ties among the differences
        # 2^12 sign assignments: SciPy's permutation test enumerates them all.
        method = PermutationMethod() if n == 12 else "asymptotic"
        reference = wilcoxon(a, b, zero_method="wilcox", correction=False, method=method)
        assert board_stats.paired_p(a, b) == pytest.approx(reference.pvalue, rel=1e-9)
