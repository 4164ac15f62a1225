"""Options shared by the IGR decoder methods (IGR itself, and MSC which uses its decoder)."""

from __future__ import annotations

from dataclasses import dataclass, field


def _c(default, help_text: str):
    """A completion-time option: changing it never retrains."""
    return field(default=default, metadata={"help": help_text, "completion_only": True})


@dataclass(frozen=True)
class DecoderOptions:
    recipe: str = field(
        default="paper",
        metadata={"help": "where paper and official code disagree: 'paper' or 'official' values"},
    )
    latent_dim: int = field(default=256, metadata={"help": "latent code size"})
    width: int = field(default=512, metadata={"help": "decoder layer width (paper: 512)"})
    depth: int = field(default=8, metadata={"help": "decoder hidden layers (paper: 8)"})
    epochs: int = field(default=5000, metadata={"help": "training epochs (paper: 5000)"})
    batch_shapes: int = field(default=32, metadata={"help": "objects per batch (paper: 32)"})
    surface_points: int = field(
        default=16384, metadata={"help": "surface points per object and step (paper: 16384)"}
    )
    lr: float | None = field(
        default=None, metadata={"help": "decoder learning rate [paper 1e-4, official 5e-3]"}
    )
    lr_halve_every: int = field(default=500, metadata={"help": "epochs between lr halvings"})
    eikonal_weight: float | None = field(
        default=None, metadata={"help": "Eikonal weight lambda [paper 1.0, official 0.1]"}
    )
    normal_weight: float = field(default=1.0, metadata={"help": "normal term weight tau"})
    offsurface: str | None = field(
        default=None,
        metadata={
            "help": "Eikonal samples [paper: 5k surface points + N(0, 0.04); official: "
            "N(0, 0.01^2) per point + N/8 uniform in [-1.8, 1.8]^3]"
        },
    )
    mesh_resolution: int = _c(256, "marching-cubes grid points per axis (paper: 256)")
    mesh_bf16: bool = _c(False, "evaluate the decoder in bfloat16 while meshing (faster on CPU)")
    largest_component: bool | None = _c(
        None,
        "keep only the mesh's largest connected component, by area [paper: no, official: "
        "yes, as IGR's evaluation]",
    )


def opt_recipe_option():
    """``opt_recipe`` of the auto-decoding methods (see ``shapebench.implicit.recipes``)."""
    return _c(
        None,
        "test-time optimiser recipe, 'paper' (Adam, lr x error_0) or 'official' (Adam 5e-3); "
        "default: the method's recipe",
    )


def opt_steps_option():
    return _c(None, "latent optimisation steps at completion [800 in both recipes]")


def opt_scale_option():
    return _c(None, "multiply opt_lr by each object's initial loss [paper: yes, official: no]")
