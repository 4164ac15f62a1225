"""From latent codes to completions: batched latent optimisation and mesh extraction."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import torch
import trimesh
from torch import nn

from shapebench.api.types import Completion, Context
from shapebench.geometry.meshing import extract_mesh, sample_mesh_points
from shapebench.train.lightning_method import stack_contexts  # noqa: F401 (plugins import it here)


def require_normals(normals: torch.Tensor | None, setting: str, owner: str) -> torch.Tensor:
    """``normals``, or a clear error naming the option ``setting`` ("key=value") that asked for
    them."""
    if normals is None:
        option = setting.partition("=")[0]
        raise ValueError(
            f"{owner}: option {setting} needs context normals, but the contexts have none (the "
            f"benchmark protocol gives points only): change {option}, or run with "
            "--context-normals"
        )
    return normals


def optimise_latents(
    loss_fn: Callable[[torch.Tensor], torch.Tensor],
    init: torch.Tensor,
    steps: int,
    lr: float,
    scale_by_initial_loss: bool = False,
    decay_at: float = 0.5,
) -> tuple[torch.Tensor, list[float]]:
    """Adam on the latent codes alone; the learning rate is divided by 10 at ``decay_at`` of the
    way (the schedule of IGR's and DeepSDF's latent optimisers).

    ``loss_fn`` returns one loss per object (B,). Objects are optimised together but
    independently: Adam's moments are per element and each object has its own step size, which
    is ``lr`` or, with ``scale_by_initial_loss`` (the paper's "lr x error_0"), ``lr`` times that
    object's initial loss. Returns the codes and the mean loss before every step.
    """
    z = init.detach().clone()
    m = torch.zeros_like(z)
    v = torch.zeros_like(z)
    beta1, beta2, eps = 0.9, 0.999, 1e-8
    step_size = torch.full((len(z), 1), lr, device=z.device, dtype=z.dtype)
    history = []
    for t in range(1, steps + 1):
        z.requires_grad_(True)
        loss = loss_fn(z)
        (grad,) = torch.autograd.grad(loss.sum(), z)
        z = z.detach()
        if t == 1 and scale_by_initial_loss:
            step_size = step_size * loss.detach()[:, None]
        history.append(float(loss.detach().mean()))
        m = beta1 * m + (1 - beta1) * grad
        v = beta2 * v + (1 - beta2) * grad**2
        decay = 0.1 if t > decay_at * steps else 1.0
        z = z - decay * step_size * (m / (1 - beta1**t)) / ((v / (1 - beta2**t)).sqrt() + eps)
    return z.detach(), history


def initial_latents(
    contexts: list[Context], dim: int, std: float, device: torch.device
) -> torch.Tensor:
    """z_0 ~ N(0, std^2), seeded per object from its context seed (repeatable runs)."""
    rows = [np.random.default_rng(c.seed).normal(0.0, std, dim) for c in contexts]
    return torch.tensor(np.stack(rows), dtype=torch.float32, device=device)


def field_of(
    decoder: nn.Module, z: torch.Tensor, device: torch.device, bf16: bool = False
) -> Callable[[np.ndarray], np.ndarray]:
    """The SDF of one latent code as a numpy function, for the mesh extractor (through the
    decoder's ``forward_shared`` where it has one: the code's share computed once)."""
    evaluate = getattr(decoder, "forward_shared", decoder)

    @torch.no_grad()
    def field(points: np.ndarray) -> np.ndarray:
        x = torch.from_numpy(np.ascontiguousarray(points, dtype=np.float32)).to(device)[None]
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
            values = evaluate(z[None], x)
        return values.float()[0].cpu().numpy()

    return field


def component_labels(mesh: trimesh.Trimesh) -> np.ndarray:
    """One label per face; faces sharing an edge have the same label."""
    return trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))


def largest_component(mesh: trimesh.Trimesh, labels: np.ndarray | None = None) -> trimesh.Trimesh:
    """The connected component of ``mesh`` with the largest surface area (as IGR's evaluation,
    ``connected=True`` in ``utils/plots.py``)."""
    if len(mesh.faces) == 0:
        return mesh
    labels = component_labels(mesh) if labels is None else labels
    if labels.max() == 0:
        return mesh
    keep = labels == int(np.argmax(np.bincount(labels, weights=mesh.area_faces)))
    out = trimesh.Trimesh(mesh.vertices, mesh.faces[keep], process=False)
    out.remove_unreferenced_vertices()
    return out


def mesh_completion(
    field: Callable[[np.ndarray], np.ndarray],
    ctx: Context,
    n_points: int,
    resolution: int,
    level: float = 0.0,
    inside_is_negative: bool = True,
    keep_largest: bool = False,
) -> Completion:
    """Marching cubes on ``field`` (an SDF, or logits with ``inside_is_negative=False``), then
    ``n_points`` sampled area-weighted on the mesh.

    ``keep_largest`` drops every connected component but the one with the largest area before
    sampling (the ``largest_component`` option of every implicit method): a small detached
    component far from the object costs a lot under squared Chamfer.
    """
    start = time.perf_counter()
    mesh, stats = extract_mesh(
        field,
        resolution=resolution,
        level=level,
        inside_is_negative=inside_is_negative,
        coarse=min(32, resolution),
    )
    labels = component_labels(mesh) if len(mesh.faces) else np.zeros(0, dtype=int)
    components = int(labels.max()) + 1 if len(labels) else 0
    if keep_largest:
        mesh = largest_component(mesh, labels)
    points = sample_mesh_points(mesh, n_points, seed=ctx.seed)
    return Completion(
        points=points,
        mesh=mesh,
        info={
            "mesh_seconds": time.perf_counter() - start,
            "mesh_evaluations": float(stats.evaluations),
            "mesh_faces": float(len(mesh.faces)),
            "mesh_components": float(components),
        },
    )
