"""Samples produced from a normalised mesh: for training, SDF samples, occupancy samples and
complete point clouds; for metrics that need more than ground-truth points, oriented points
(normal consistency) and uniform occupancy queries (IoU).

SDF samples follow DeepSDF's ``PreprocessMesh`` procedure: 47/50 of the points are surface
samples perturbed with Gaussian noise of variance 0.005 and 0.0005 (one each), 3/50 are uniform in
[-1, 1]^3. The distance magnitude is the distance to the nearest of dense surface samples,
point-to-plane when that sample is closer than sqrt(0.005) (as DeepSDF does). The sign comes from
an inside test when the mesh is a closed solid; otherwise (scanned or CAD meshes with holes) from
the vote of the 11 nearest surface normals, and points where they disagree are dropped, as in
DeepSDF. Negative is inside.
"""

from __future__ import annotations

import numpy as np
import trimesh

from shapebench.geometry.containment import inside
from shapebench.geometry.nearest import kdtree
from shapebench.geometry.sampling import sample_surface

NEAR_VARIANCES = (0.005, 0.0005)
VOTE_NEIGHBOURS = 11


#: Uniform occupancy queries per object for volumetric IoU (ConvONet's ``points.npz``: 100k).
IOU_POINTS = 100_000
#: Half the side of the box IoU queries fill: the unit sphere padded by 10 %, as OccNet pads its
#: unit cube.
IOU_BOUND = 1.1


def oriented_points(mesh: trimesh.Trimesh, n: int, rng: np.random.Generator) -> np.ndarray:
    """``(n, 6)``: ``n`` points area-weighted over the surface and the unit normals of their
    faces (ConvONet's evaluation point cloud, for normal consistency)."""
    pts, face = sample_surface(mesh.vertices, mesh.faces, n, rng)
    normals = np.asarray(mesh.face_normals, dtype=np.float64)[face]
    return np.concatenate([pts, normals], axis=1).astype(np.float32)


def complete_points(mesh: trimesh.Trimesh, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points area-weighted over the whole surface (PCN's complete target cloud)."""
    pts, _ = sample_surface(mesh.vertices, mesh.faces, n, rng)
    return pts.astype(np.float32)


def sdf_samples(
    mesh: trimesh.Trimesh, n: int, rng: np.random.Generator, reference: int = 100_000
) -> np.ndarray:
    """``(m, 4)`` rows of x, y, z, sdf with m <= n (points with an ambiguous sign are dropped)."""
    n_near = (47 * n // 50) // 2
    base, _ = sample_surface(mesh.vertices, mesh.faces, n_near, rng)
    near = [base + rng.normal(scale=np.sqrt(v), size=base.shape) for v in NEAR_VARIANCES]
    uniform = rng.uniform(-1.0, 1.0, size=(n - 2 * n_near, 3))
    points = np.concatenate([*near, uniform])

    ref_pts, ref_face = sample_surface(mesh.vertices, mesh.faces, reference, rng)
    ref_nrm = np.asarray(mesh.face_normals)[ref_face]
    tree = kdtree(ref_pts)
    dist, idx = tree.query(points, k=VOTE_NEIGHBOURS, workers=-1)
    nearest, nearest_n = ref_pts[idx[:, 0]], ref_nrm[idx[:, 0]]
    plane = np.abs(np.einsum("ij,ij->i", points - nearest, nearest_n))
    magnitude = np.where(dist[:, 0] < np.sqrt(NEAR_VARIANCES[0]), plane, dist[:, 0])

    if mesh.is_watertight and mesh.is_winding_consistent:
        inside = mesh.contains(points)
        keep = np.ones(len(points), dtype=bool)
    else:
        outward = np.einsum("ikj,ikj->ik", points[:, None, :] - ref_pts[idx], ref_nrm[idx]) > 0
        votes = outward.sum(axis=1)
        keep = (votes == 0) | (votes == VOTE_NEIGHBOURS)
        inside = votes == 0
    sdf = np.where(inside, -magnitude, magnitude)
    return np.concatenate([points, sdf[:, None]], axis=1)[keep].astype(np.float32)


def occupancy_samples(
    mesh: trimesh.Trimesh, n: int, rng: np.random.Generator, bound: float = IOU_BOUND
) -> np.ndarray:
    """``(n, 4)`` rows of x, y, z, occupancy (1 inside) for points uniform in [-bound, bound]^3.

    OccNet samples uniformly in its unit cube padded by 10 %; the unit-sphere frame used here is
    padded the same way.
    """
    points = rng.uniform(-bound, bound, size=(n, 3))
    occ = inside(mesh, points).astype(np.float32)
    return np.concatenate([points, occ[:, None]], axis=1).astype(np.float32)


def occupancy_from_sdf(sdf: np.ndarray) -> np.ndarray:
    """``(m, 4)`` rows of x, y, z, occupancy from SDF samples: inside (1) where sdf < 0.

    The paper's OccNet queries (§4.1: points "randomly sampled from those used in DeepSDF",
    annotated inside or outside). DeepSDF's samples lie mostly near the surface, so about half of
    them are inside, where uniform samples in the padded box would be mostly outside.
    """
    inside = (sdf[:, 3] < 0).astype(np.float32)
    return np.concatenate([sdf[:, :3], inside[:, None]], axis=1).astype(np.float32)
