"""Results in a notebook: per-category scores, a paired comparison of two rows, a plot.

Run it (or paste its cells into a notebook) after a run or sweep has filled the workspace:

    shapebench run -m gauss -d synthetic
    shapebench run -m gauss -d synthetic -O sigma=0.05
    python docs/examples/notebook.py [WORKSPACE]

tests/boards/test_frames.py runs it on a small workspace.
"""

import sys

import matplotlib

matplotlib.use("Agg")  # no display needed; in a notebook, leave this out
import matplotlib.pyplot as plt  # noqa: E402
from scipy.stats import wilcoxon  # noqa: E402

import shapebench  # noqa: E402

workspace = sys.argv[1] if len(sys.argv) > 1 else None

# One row per (object, cell): method, label, context, seed, object, category, ... and a column per
# metric, in the metric's own units (the tables show chamfer-l2 x1000).
scores = shapebench.load_results("synthetic", "trained", workspace=workspace)
print(scores.groupby(["label", "context"])["chamfer-l2"].mean().mul(1000).unstack().round(2))

# Chamfer at 50 points per category, one column per row label.
at_50 = scores[scores.context == 50]
print(at_50.pivot_table("chamfer-l2", "category", "label", aggfunc="mean").mul(1000).round(2))

# A paired comparison of two rows over the same objects (what the leaderboard's ties use).
a, b = sorted(scores.label.unique())[:2]
pairs = at_50.pivot_table("chamfer-l2", ["object", "seed"], "label").dropna()
stat = wilcoxon(pairs[a], pairs[b])
print(
    f"{a} vs {b} at 50 points: {len(pairs)} pairs, {a} lower on {(pairs[a] < pairs[b]).sum()}, "
    f"p = {stat.pvalue:.3g}"
)

# The leaderboard's own table (means, significance, training cost), as written to its CSV.
table = shapebench.load_leaderboard("synthetic", "trained", reference=a, workspace=workspace)
raw = table[table.kind == "raw"].pivot_table("mean", "label", "context")
ax = raw.T.plot(marker="o", logx=True, ylabel="chamfer-l2 x1000", title="synthetic / trained")
plt.savefig("notebook-example.png")
print("wrote notebook-example.png")
