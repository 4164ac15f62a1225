"""The paper's preprocessing (§4.1–4.2), shared by every mesh dataset.

1. normalise: centre of mass to the origin, scale so the largest vertex distance is 1;
2. *disemboweled* surface points: points on the surface visible from viewpoints around the object,
   with outward normals (interior structure never seen by a sensor is left out);
3. ground truth: points sampled area-weighted over the whole mesh.
"""

from shapebench.preprocess.pipeline import (
    PREPROCESS_VERSION,
    PreprocessError,
    PreprocessParams,
    prepare_ground_truth,
    prepare_mesh,
)

__all__ = [
    "PREPROCESS_VERSION",
    "PreprocessError",
    "PreprocessParams",
    "prepare_ground_truth",
    "prepare_mesh",
]
