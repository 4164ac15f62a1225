"""MSC-hier's LightningModule: MSC's, with local towers as the encoder's f and g."""

from __future__ import annotations

from shapebench_msc.module import MSCModule
from torch import nn

from shapebench.implicit.networks import MSCEncoder
from shapebench_mschier.method import MSCHierOptions
from shapebench_mschier.network import LocalTower


class MSCHierModule(MSCModule):
    Options = MSCHierOptions
    options: MSCHierOptions

    def __init__(self, options: MSCHierOptions | None = None, n_shapes: int = 0, **saved) -> None:
        super().__init__(options, n_shapes, **saved)
        o = self.options
        inputs = MSCEncoder.INPUTS[o.encoder_input]

        def tower() -> LocalTower:
            return LocalTower(
                inputs,
                o.encoder_width,
                o.latent_dim,
                o.neighbours,
                o.local_levels,
                o.encoder_layers,
            )

        # The encoder's aggregation (equation 2) reads self.f(inp) and self.g(inp) per point;
        # only what computes them changes.
        self.encoder.f, self.encoder.g = tower(), tower()
        # Votes start at zero, as MSC's: the first codes are the prior mean and the decoder
        # starts from its geometric initialisation.
        last = self.encoder.f.head[-1]
        assert isinstance(last, nn.Linear)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
