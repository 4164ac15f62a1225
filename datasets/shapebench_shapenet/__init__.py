"""The ``shapenet`` dataset: a local copy of ShapeNetCore v1 or v2, split as in the paper."""
