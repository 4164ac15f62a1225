"""Options the implicit methods share: fields whose meaning must be the same in every method
(the recipe, the test-time optimiser, the largest-component filter; see
:mod:`shapebench.implicit.recipes`), the options every auto-decoder shares
(:class:`AutoDecoderOptions`: DeepSDF, and IGR and MSC through IGR's decoder,
:class:`IGRDecoderOptions`), and their tiny options for ``shapebench check``
(:func:`auto_decoder_check_options`).

No torch here: the method classes import it at registration time.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from shapebench.api.options import completion_option, option, steps_option


def recipe_option(
    help_text: str = "where paper and official code disagree: 'paper' or 'official' values",
) -> Any:
    """``recipe``: which table fills the options left at ``None`` (``paper`` by default)."""
    return option("paper", help_text)


def opt_recipe_option() -> Any:
    """``opt_recipe`` of the auto-decoding methods: the test-time optimiser's recipe alone."""
    return completion_option(
        None,
        "test-time optimiser recipe, 'paper' (Adam, lr x error_0) or 'official' (Adam 5e-3); "
        "default: the method's recipe",
    )


def opt_steps_option() -> Any:
    return completion_option(None, "latent optimisation steps at completion [800 in both recipes]")


def opt_scale_option() -> Any:
    return completion_option(
        None, "multiply opt_lr by each object's initial loss [paper: yes, official: no]"
    )


def largest_component_option() -> Any:
    return completion_option(
        None,
        "keep only the mesh's largest connected component, by area [paper: no, official: "
        "yes, as IGR's evaluation]",
    )


@dataclass(frozen=True)
class AutoDecoderOptions:
    """The options of a method that decodes a latent code into an SDF with an MLP, trains the
    decoder for ``epochs`` (or ``steps``) with a learning rate halved on a schedule, and meshes the
    codes it finds at completion, optimising them on the context with the shared test-time
    optimiser (DeepSDF; IGR and MSC through :class:`IGRDecoderOptions`).

    A method adds its training options and ``lr`` (its recipe says the default), and redefines
    ``opt_lr`` to name its recipes' values.
    """

    recipe: str = recipe_option()
    latent_dim: int = option(256, "latent code size")
    width: int = option(512, "decoder layer width (paper: 512)")
    depth: int = option(8, "decoder hidden layers (paper: 8)")
    epochs: int = option(5000, "training epochs (paper: 5000)")
    steps: int = steps_option()
    batch_shapes: int = option(32, "objects per batch (paper: 32)")
    lr_halve_every: int = option(500, "epochs between lr halvings")
    lr_halve_steps: int | None = option(
        None, "optimiser steps between lr halvings, instead of epochs (0: never halve)"
    )
    # The test-time optimiser, shared by every auto-decoder (shapebench.implicit.recipes).
    opt_recipe: str | None = opt_recipe_option()
    opt_steps: int | None = opt_steps_option()
    opt_scale_by_error: bool | None = opt_scale_option()
    opt_lr: float | None = completion_option(
        None, "latent optimisation step [paper: the decoder's lr x error_0, official 5e-3]"
    )
    mesh_resolution: int = completion_option(
        256, "marching-cubes grid points per axis (paper: 256)"
    )
    mesh_bf16: bool = completion_option(
        False, "evaluate the decoder in bfloat16 while meshing (faster on CPU)"
    )
    largest_component: bool | None = largest_component_option()


@dataclass(frozen=True)
class IGRDecoderOptions(AutoDecoderOptions):
    """The options of IGR's decoder and training losses (IGR itself, and MSC which uses them)."""

    surface_points: int = option(16384, "surface points per object and step (paper: 16384)")
    lr: float | None = option(None, "decoder learning rate [paper 1e-4, official 5e-3]")
    eikonal_weight: float | None = option(None, "Eikonal weight lambda [paper 1.0, official 0.1]")
    normal_weight: float = option(1.0, "normal term weight tau")
    offsurface: str | None = option(
        None,
        "Eikonal samples [paper: 5k surface points + N(0, 0.04); official: N(0, 0.01^2) per "
        "point + N/8 uniform in [-1.8, 1.8]^3]",
    )


def auto_decoder_check_options(**more: Any) -> dict[str, Any]:
    """Tiny options of an auto-decoder for ``shapebench check`` (a method's ``check_options``):
    a 2 x 32 decoder with 8-d codes, one epoch of batches of 4, 32^3 meshes and 5 test-time
    steps, with ``more`` added or overriding."""
    return {
        "latent_dim": 8,
        "width": 32,
        "depth": 2,
        "epochs": 1,
        "batch_shapes": 4,
        "mesh_resolution": 32,
        "opt_steps": 5,
        **more,
    }
