"""What every implicit method must respect: points-only contexts, one test-time optimiser per
recipe, equation 6 as written by default, and the shared largest-component filter."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from shapebench_deepsdf.method import DeepSDF
from shapebench_igr.method import IGR
from shapebench_msc.method import MSC, MSCNoOpt
from shapebench_msc.module import MSCModule
from shapebench_occnet.method import OccNet

from shapebench import options as opts
from shapebench.config import load_profile, plugin_overrides
from shapebench.implicit.completion import mesh_completion, stack_contexts
from shapebench.implicit.networks import MSCEncoder
from shapebench.implicit.recipes import PAPER_OPT_LR
from shapebench.types import Context, ObjectRef

AUTO_DECODERS = {"igr": IGR, "deepsdf": DeepSDF, "msc": MSC}
OPTIMISER = ("opt_steps", "opt_lr", "opt_scale_by_error")


def _contexts(n: int = 200, normals: bool = False, count: int = 2) -> list[Context]:
    out = []
    for i in range(count):
        rng = np.random.default_rng(i)
        v = rng.normal(size=(n, 3)).astype(np.float32)
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        nrm = rng.normal(size=(n, 3)).astype(np.float32) if normals else None
        out.append(Context(ObjectRef(f"o{i}", "c"), 0.5 * v, nrm, seed=i))
    return out


def _tiny_msc(cls: type[MSCNoOpt] = MSC, **overrides) -> MSCNoOpt:
    """An MSC method with a tiny untrained module, as load_checkpoint would leave it."""
    method = cls(cls.Options(latent_dim=8, width=32, depth=2, encoder_width=16, encoder_layers=1,
                             opt_steps=3, mesh_resolution=16, **overrides))  # fmt: skip
    torch.manual_seed(0)
    o = method.options
    method.module = MSCModule(latent_dim=8, width=32, depth=2, encoder_width=16, encoder_layers=1,
                              mean_weights=o.mean_weights, lr=o.lr, lr_halve_every=10,
                              eikonal_weight=o.eikonal_weight, normal_weight=1.0,
                              offsurface=o.offsurface, max_target=64,
                              encoder_input=o.encoder_input).eval()  # fmt: skip
    # Make the encoder's votes non-zero, so that an input it read would move the code.
    torch.nn.init.normal_(method.module.encoder.f[-1].weight, std=0.5)
    method.device = torch.device("cpu")
    return method


def test_msc_encoder_has_no_normal_input_and_completes_points_only_contexts():
    encoder = MSCEncoder(latent_dim=8, hidden=16, layers=1)
    assert encoder.f[0].in_features == 4 and encoder.g[0].in_features == 4  # x, y, z, s = 0
    method = _tiny_msc()
    bare = method.infer_latents(_contexts())
    with_normals = method.infer_latents(_contexts(normals=True))
    assert torch.equal(bare, with_normals)  # arbitrary normals change nothing
    assert bare.abs().sum() > 0
    results = method.complete_batch(_contexts(), n_points=500)
    assert all(not isinstance(r, Exception) for r in results), results
    assert results[0].points.shape == (500, 3)


def test_options_that_read_normals_fail_clearly_without_them():
    with pytest.raises(ValueError, match="encoder_input=normals"):
        _tiny_msc(MSCNoOpt, encoder_input="normals").infer_latents(_contexts())
    igr = IGR(IGR.Options(latent_dim=8, width=32, depth=2, test_normals=True, opt_steps=1))
    from shapebench_igr.module import IGRModule

    igr.module = IGRModule(n_shapes=1, latent_dim=8, width=32, depth=2, lr=1e-3,
                           lr_halve_every=10, eikonal_weight=0.1, normal_weight=1.0,
                           latent_reg=1e-3, offsurface="official")  # fmt: skip
    igr.device = torch.device("cpu")
    with pytest.raises(ValueError, match="test_normals=true"):
        igr.infer_latents(_contexts())
    assert igr.infer_latents(_contexts(normals=True)).shape == (2, 8)


def test_stack_contexts_copes_with_missing_normals():
    pts, nrm = stack_contexts(_contexts(50), torch.device("cpu"))
    assert pts.shape == (2, 50, 3) and nrm is None
    _, nrm = stack_contexts(_contexts(50, normals=True), torch.device("cpu"))
    assert nrm.shape == (2, 50, 3)


@pytest.mark.parametrize("recipe", ["paper", "official"])
def test_auto_decoders_share_one_test_time_optimiser_per_recipe(recipe):
    resolved = {name: cls(cls.Options(recipe=recipe)).options
                for name, cls in AUTO_DECODERS.items()}  # fmt: skip
    settings = {name: tuple(getattr(o, k) for k in OPTIMISER) for name, o in resolved.items()}
    rules = {(s[0], s[2]) for s in settings.values()}
    assert len(rules) == 1  # the same rule and step count for the three
    if recipe == "official":
        assert set(settings.values()) == {(800, 5e-3, False)}  # DeepSDF's reconstruct.py, IGR's
    else:
        assert rules == {(800, True)}  # "lr x error_0", the paper's lr of each decoder family
        assert resolved["igr"].opt_lr == resolved["msc"].opt_lr == PAPER_OPT_LR["igr"] == 1e-4
        assert resolved["deepsdf"].opt_lr == PAPER_OPT_LR["deepsdf"] == 1e-3
    # opt_recipe picks the optimiser alone, the training recipe stays.
    other = "official" if recipe == "paper" else "paper"
    swapped = IGR(IGR.Options(recipe=recipe, opt_recipe=other)).options
    assert swapped.opt_scale_by_error == (other == "paper")
    assert swapped.lr == resolved["igr"].lr
    # An explicit value still wins.
    assert IGR(IGR.Options(recipe=recipe, opt_lr=0.3)).options.opt_lr == 0.3


def test_the_quick_profile_gives_the_three_the_same_test_time_optimiser():
    profile = load_profile("quick")
    settings = set()
    for name, cls in AUTO_DECODERS.items():
        values = plugin_overrides("method", name, profile)
        o = cls(opts.build(cls.Options, values, name)).options
        settings.add(tuple(getattr(o, k) for k in OPTIMISER))
    assert len(settings) == 1, settings


def test_equation_6_is_the_default_post_encoder_objective():
    method = _tiny_msc()
    assert method.options.opt_eikonal == 0.0  # nothing but the context likelihood
    pts, _ = stack_contexts(_contexts(), torch.device("cpu"))
    z = torch.zeros(2, 8, requires_grad=True)
    loss = method.module.context_nll(pts)(z)
    f = method.module.decoder(z, pts)
    expected = 0.5 * (f / method.module.sigma()).pow(2).mean(dim=1)
    assert torch.allclose(loss, expected) and (loss >= 0).all()
    # The gradient is that of the summed negative log-likelihood, up to a positive factor.
    (g_ours,) = torch.autograd.grad(loss.sum(), z)
    z2 = z.detach().clone().requires_grad_(True)
    (g_eq6,) = torch.autograd.grad(method.module.nll(method.module.decoder(z2, pts)).sum(), z2)
    assert torch.allclose(g_ours * pts.shape[1], g_eq6, rtol=1e-4, atol=1e-7)
    # The optional Eikonal regulariser is only there when asked for.
    torch.manual_seed(0)
    regularised = method.module.context_nll(pts, eikonal_weight=0.5)(z.detach())
    assert (regularised > loss.detach()).all()


def _two_spheres(points: np.ndarray) -> np.ndarray:
    big = np.linalg.norm(points, axis=1) - 0.5
    small = np.linalg.norm(points - np.array([0.8, 0.0, 0.0]), axis=1) - 0.1
    return np.minimum(big, small).astype(np.float32)


@pytest.mark.parametrize("keep", [False, True])
def test_largest_component_keeps_only_the_big_sphere(keep):
    ctx = _contexts(count=1)[0]
    completion = mesh_completion(_two_spheres, ctx, 4000, resolution=64, keep_largest=keep)
    assert completion.info["mesh_components"] == 2
    near_small = np.linalg.norm(completion.points - [0.8, 0.0, 0.0], axis=1) < 0.2
    if keep:
        assert not near_small.any()
        assert np.allclose(np.linalg.norm(completion.points, axis=1), 0.5, atol=0.02)
    else:
        assert near_small.sum() > 50  # about 4 % of the area


@pytest.mark.parametrize("cls", [IGR, DeepSDF, MSC, OccNet])
def test_largest_component_follows_the_recipe_for_every_implicit_method(cls):
    assert cls(cls.Options(recipe="official")).options.largest_component is True
    assert cls(cls.Options(recipe="paper")).options.largest_component is False
    assert cls(cls.Options(largest_component=True)).options.largest_component is True
