"""Built-in metrics: Chamfer variants with explicit cards, and F-score.

Which Chamfer the paper used: equation 7 writes Euclidean (non-squared) distances, but the
magnitudes of its tables only come out with squared distances (see ``docs/metrics.md`` for the
measurement). ``chamfer-l2`` (squared) is therefore the default of paper-comparable leaderboards,
and ``chamfer-l1`` is equation 7 as written.
"""
