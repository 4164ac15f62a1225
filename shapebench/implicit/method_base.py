"""The base of the implicit-surface methods (IGR, DeepSDF, MSC, MSC-hier, and through
:class:`~shapebench.implicit.occupancy.OccupancyMethod` OccNet and ConvONet):
:class:`ImplicitMethod`, a :class:`~shapebench.train.lightning_method.LightningMethod` whose codes
define a surface.

:class:`LightningMethod` itself moved to :mod:`shapebench.train.lightning_method` (PCN, an
explicit method, uses it too); importing it from here still works until shapebench 0.3, with a
:class:`DeprecationWarning`.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar

from shapebench.api.types import Completion, Context
from shapebench.train.lightning_method import LightningMethod as _LightningMethod

if TYPE_CHECKING:  # annotations only: the method classes are imported by `shapebench methods`,
    import numpy as np  # which must not pay for torch (shapebench.api.method's lazy-torch rule)
    import torch


def __getattr__(name: str) -> Any:
    if name == "LightningMethod":
        warnings.warn(
            "shapebench.implicit.method_base.LightningMethod has moved to "
            "shapebench.train.lightning_method; import it from there "
            "(the old path works until shapebench 0.3)",
            DeprecationWarning,
            stacklevel=2,
        )
        return _LightningMethod
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class ImplicitMethod(_LightningMethod):
    """A LightningMethod whose codes define an implicit surface: :meth:`decode` meshes
    :meth:`field` by marching cubes at :meth:`level` and samples the completion on the mesh
    (:meth:`mesh`).

    The default field is an SDF, ``module.decoder(z, x)``; the options hold ``mesh_resolution``
    and ``largest_component`` (and ``mesh_bf16`` for the default field).
    """

    #: Whether the field is negative inside (an SDF) rather than positive (logits).
    inside_is_negative: ClassVar[bool] = True
    #: Marching cubes and the area-weighted sampler make the completion from the field: in the
    #: cell keys, not in the checkpoint keys (a training never meshes).
    completion_modules: ClassVar[tuple[str, ...]] = (
        "shapebench.geometry.meshing",
        "shapebench.geometry.sampling",
    )
    #: Recipe name -> option values that fill the options left at ``None`` (see
    #: :func:`shapebench.implicit.recipes.apply_recipe`); None: the options have no recipe.
    recipes: ClassVar[dict[str, dict[str, Any]] | None] = None

    def __init__(self, options: Any | None = None) -> None:
        super().__init__(options)
        if self.recipes is not None:
            from shapebench.implicit.recipes import apply_recipe

            self.options = apply_recipe(self.options, self.recipes, self.label)

    def field(self, code: Any) -> Callable[[np.ndarray], np.ndarray]:
        """The field of one code as a numpy function of (N, 3) points."""
        from shapebench.implicit.completion import field_of

        return field_of(self.module.decoder, code, self.device, bf16=self.options.mesh_bf16)

    def level(self) -> float:
        """The field's value on the surface."""
        return 0.0

    def decode(self, code: Any, ctx: Context, n_points: int) -> Completion:
        return self.mesh(code, ctx, n_points)

    def mesh(self, code: Any, ctx: Context, n_points: int) -> Completion:
        """Marching cubes on the field of ``code``, ``n_points`` sampled on the mesh."""
        from shapebench.implicit.completion import mesh_completion

        o = self.options
        return mesh_completion(
            self.field(code),
            ctx,
            n_points,
            o.mesh_resolution,
            level=self.level(),
            inside_is_negative=self.inside_is_negative,
            keep_largest=bool(o.largest_component),
        )

    def optimise_codes(
        self, loss: Callable[[torch.Tensor], torch.Tensor], init: torch.Tensor
    ) -> torch.Tensor:
        """Codes from ``init`` by the shared test-time optimiser (``opt_steps``, ``opt_lr``,
        ``opt_scale_by_error``), ``loss`` giving one value per object."""
        from shapebench.implicit.completion import optimise_latents

        o = self.options
        z, _ = optimise_latents(loss, init, o.opt_steps, o.opt_lr, o.opt_scale_by_error)
        return z
