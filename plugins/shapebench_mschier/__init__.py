"""MSC with a hierarchical encoder: equation 2's per-point votes and precisions computed from each
point's neighbourhood (PointNet++-style local grouping) instead of from the point alone."""
