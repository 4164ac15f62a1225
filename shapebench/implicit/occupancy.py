"""The base of the occupancy methods (OccNet, ConvONet): :class:`OccupancyMethod`, an
:class:`~shapebench.implicit.method_base.ImplicitMethod` whose field is the occupancy logit of a
feed-forward encoder's code, trained on labelled queries.

Its LightningModule subclasses
:class:`~shapebench.implicit.occupancy_module.OccupancyModule` (imported lazily, like every
module: registering the method imports no torch), which noises the encoder's input and trains with
binary cross-entropy on the logits.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar

from shapebench.api.errors import ConfigError
from shapebench.api.types import Supervision
from shapebench.implicit.method_base import ImplicitMethod

if TYPE_CHECKING:  # annotations only: `shapebench methods` imports the method classes
    import numpy as np

    from shapebench.api.method import TrainingContext
    from shapebench.train.lightning_fit import ShapeDataModule


class OccupancyMethod(ImplicitMethod):
    """An implicit method whose module maps context points to a code (``module.encoder``) and
    (queries, code) to occupancy logits (``module.decoder(x, code)``), meshed where the
    probability is the option ``threshold``.

    The option ``queries`` chooses where the training queries come from: each method spells its
    values as its paper does, and :attr:`query_sources` maps every accepted value to whether the
    queries are DeepSDF's SDF samples, labelled inside where sdf < 0, or the dataset's occupancy
    samples (uniform in the padded box). A batch holds :meth:`encoder_points` surface points and
    ``query_points`` queries per object (batch keys ``points`` and ``occupancy``). The options also
    hold ``threshold``, ``mesh_resolution`` and ``largest_component``.
    """

    #: Every kind either query source may need (``prepare -m`` builds both); an instance asks
    #: for one through :meth:`needs`.
    supervision = frozenset(
        {Supervision.SURFACE_POINTS, Supervision.OCCUPANCY_SAMPLES, Supervision.SDF_SAMPLES}
    )
    inside_is_negative = False  # the field is the occupancy logit
    #: Value of the option ``queries`` -> whether the queries are drawn from the SDF samples
    #: (else from the occupancy samples), in the order error messages list them.
    query_sources: ClassVar[dict[str, bool]] = {}

    def __init__(self, options: Any | None = None) -> None:
        super().__init__(options)  # the recipe, if any, fills the option first
        if self.options.queries not in self.query_sources:
            raise ConfigError(
                f"{self.label}: queries must be one of {list(self.query_sources)}, "
                f"got {self.options.queries!r}"
            )

    @property
    def queries_from_sdf(self) -> bool:
        """Whether the training queries are the SDF samples, labelled (the option ``queries``)."""
        return self.query_sources[self.options.queries]

    def needs(self) -> frozenset[Supervision]:
        queries = (
            Supervision.SDF_SAMPLES if self.queries_from_sdf else Supervision.OCCUPANCY_SAMPLES
        )
        return frozenset({Supervision.SURFACE_POINTS, queries})

    def encoder_points(self) -> int:
        """Surface points per object and training step: the most the encoder reads (default:
        the option ``surface_points``)."""
        return self.options.surface_points

    def sample_sizes(self) -> dict[Supervision, int]:
        return {
            Supervision.SURFACE_POINTS: self.encoder_points(),
            Supervision.OCCUPANCY_SAMPLES: self.options.query_points,
        }

    def data_module(self, ctx: TrainingContext) -> ShapeDataModule:
        data = super().data_module(ctx)
        data.queries_from_sdf = self.queries_from_sdf
        return data

    def decoder_code(self, code: Any) -> Any:
        """One object's code as the decoder takes it, a batch of one (default: ``code[None]``)."""
        return code[None]

    def field(self, code: Any) -> Callable[[np.ndarray], np.ndarray]:
        import numpy as np
        import torch

        decoder, batched = self.module.decoder, self.decoder_code(code)

        @torch.no_grad()
        def logits(points: np.ndarray) -> np.ndarray:
            x = torch.from_numpy(np.ascontiguousarray(points, dtype=np.float32))[None]
            return decoder(x.to(self.device), batched).cpu().numpy()[0]

        return logits

    def level(self) -> float:
        tau = self.options.threshold
        return math.log(tau / (1 - tau))  # the logit of the threshold probability
