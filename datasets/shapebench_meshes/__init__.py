"""The ``meshes`` dataset: any folder of mesh files becomes a benchmark, sub-folders categories."""
