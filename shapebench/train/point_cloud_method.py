"""The base of the methods whose network outputs a point cloud directly (PCN, PoinTr):
:class:`PointCloudMethod`, a :class:`~shapebench.train.lightning_method.LightningMethod` trained on
context points against the complete cloud, completing with the network's output as it is.

Its LightningModule subclasses
:class:`~shapebench.train.point_cloud_module.PointCloudModule` (imported lazily, like every
module: registering the method imports no torch), which draws each batch's context size, sums and
logs the loss terms. A new method declares its options, a network and its loss terms; see
docs/plugins.md, "A point-cloud method".
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, ClassVar

from shapebench.api.types import Completion, Context, Supervision
from shapebench.train.lightning_method import LightningMethod, stack_contexts

if TYPE_CHECKING:  # annotations only: `shapebench methods` imports the method classes
    import numpy as np


class PointCloudMethod(LightningMethod):
    """A method whose network maps (B, k, 3) context points to (B, N, 3) output clouds.

    Training: each batch holds ``surface_points`` surface points per object, of which the module
    feeds the first k, k drawn per batch from ``context_sizes``, and the ``target_points``-point
    complete cloud as the target (batch keys ``points`` and ``complete``). Completion: the
    module's ``network`` on the context points, without gradients; its last output (or its only
    one) is the completion, whatever its size (Chamfer averages per set, so it may differ from the
    ground truth's).

    The options read here and by the module base: ``surface_points``, ``target_points``,
    ``context_sizes``, ``batch_shapes``, ``epochs`` (and ``steps``); ``lr`` for the default
    optimiser. A subclass sets ``Options``, ``module_path`` and, for its keys, ``code_modules``
    beyond these bases (a shared loss module, say).
    """

    supervision = frozenset({Supervision.SURFACE_POINTS, Supervision.COMPLETE_POINTS})
    batch_size = 16
    #: The module base draws the context sizes and sums the loss: its file is part of the keys.
    code_modules: ClassVar[tuple[str, ...]] = (
        *LightningMethod.code_modules,
        "shapebench.train.point_cloud_module",
    )

    def sample_sizes(self) -> dict[Supervision, int]:
        o = self.options
        return {
            Supervision.SURFACE_POINTS: o.surface_points,
            Supervision.COMPLETE_POINTS: o.target_points,
        }

    def encode(self, contexts: list[Context]) -> Iterable[np.ndarray]:
        """The output clouds, (B, N, 3) float32: the network's last output (a network returning
        a coarse and a fine cloud completes with the fine one)."""
        import numpy as np
        import torch

        points, _ = stack_contexts(contexts, self.device)
        with torch.no_grad():
            out = self.module.network(points)
        cloud = out[-1] if isinstance(out, (tuple, list)) else out
        return cloud.cpu().numpy().astype(np.float32)

    def decode(self, code: np.ndarray, ctx: Context, n_points: int) -> Completion:
        return Completion(points=code)  # the output as it is: its size is the method's
