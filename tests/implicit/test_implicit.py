"""The pieces of IGR, DeepSDF and MSC that can fail silently."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from shapebench.api.types import Context, ObjectRef
from shapebench.implicit.completion import initial_latents, optimise_latents
from shapebench.implicit.networks import DeepSDFDecoder, IGRDecoder, MSCEncoder


def _sphere(n: int, r: float = 0.5, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    v = torch.randn(n, 3, generator=g)
    v = v / v.norm(dim=1, keepdim=True)
    return r * v, v


def test_geometric_initialisation_is_close_to_a_sphere_sdf():
    # Random features make it approximate: f(x) ~ c ||x|| - 1 with c near 1, zero near r = 1.
    torch.manual_seed(0)
    decoder = IGRDecoder(latent_dim=16, width=512, depth=8, radius_init=1.0)
    x = (torch.rand(1, 4000, 3) * 2 - 1) * 1.5
    with torch.no_grad():
        f = decoder(torch.zeros(1, 16), x)[0]
    r = x[0].norm(dim=1)
    slope = float(((f + 1) * r).sum() / (r * r).sum())
    assert 0.85 < slope < 1.2
    assert (f - (r - 1)).abs().mean() < 0.2
    clear = (r - 1).abs() > 0.4
    assert (torch.sign(f[clear]) == torch.sign(r[clear] - 1)).float().mean() > 0.97


def test_decoders_take_the_latent_first_and_deepsdf_ends_in_tanh():
    igr = IGRDecoder(latent_dim=8, width=64, depth=4)
    assert igr.layers[0].in_features == 11 and igr.layers[igr.skip - 1].out_features == 64 - 11
    deepsdf = DeepSDFDecoder(latent_dim=8, width=64, depth=4).eval()
    x = torch.randn(2, 100, 3) * 10
    out = deepsdf(torch.randn(2, 8), x)
    assert out.shape == (2, 100) and out.abs().max() < 1.0


@pytest.mark.parametrize(
    "make",
    [
        lambda: IGRDecoder(128, width=128, depth=4),  # MSC's: the code wider than the layers
        lambda: IGRDecoder(16, width=64, depth=4),  # IGR's: the skip concatenation fits
        lambda: DeepSDFDecoder(16, width=64, depth=4).eval(),  # weight norm, tanh
    ],
)
def test_the_shared_code_forward_is_the_forward(make):
    """``forward_shared`` computes the code's share of the first and skip layers once per object:
    the same values and gradients (to the code and to the points, twice: the Eikonal term) as
    ``forward`` up to rounding, for the decoders' three layouts (in float64, where rounding is
    far below the tolerance: the algebra is what is tested)."""
    torch.manual_seed(0)
    dec = make().double()
    z = (torch.randn(3, dec.latent_dim, dtype=torch.float64) * 0.3).requires_grad_(True)
    x = (torch.rand(3, 200, 3, dtype=torch.float64) * 2 - 1).requires_grad_(True)

    def grads(forward):
        f = forward(z, x)
        (gx,) = torch.autograd.grad(f.sum(), x, create_graph=True)
        loss = f.abs().mean() + ((gx.norm(dim=-1) - 1) ** 2).mean()
        gz, gx2 = torch.autograd.grad(loss, (z, x))
        return f, gx, gz, gx2

    for want, got in zip(grads(dec.forward), grads(dec.forward_shared), strict=True):
        scale = want.abs().max().item()
        assert scale > 0
        assert (want - got).abs().max().item() <= 1e-10 * scale
    # Per-point codes (B, n, d) take forward itself.
    per_point = z.detach()[:, None, :].expand(-1, 200, -1)
    assert torch.equal(dec.forward_shared(per_point, x), dec.forward(per_point, x))


def test_msc_posterior_variance_shrinks_as_points_are_added_and_ignores_order():
    torch.manual_seed(1)
    encoder = MSCEncoder(latent_dim=32, hidden=64, layers=2)
    pts, _ = _sphere(1000)
    variances = []
    for n in (0, 10, 50, 100, 300, 1000):
        _, var = encoder(pts[None, :n])
        variances.append(var)
    prior = 1.0 / encoder.prior_precision()
    assert torch.allclose(variances[0][0], prior)  # no points: the prior
    for fewer, more in zip(variances, variances[1:], strict=False):
        assert (more <= fewer + 1e-7).all()  # never grows, in any dimension
    assert (variances[-1] < 0.5 * variances[1]).all()  # and really shrinks
    perm = torch.randperm(1000)
    m1, v1 = encoder(pts[None])
    m2, v2 = encoder(pts[None, perm])
    assert torch.allclose(m1, m2, atol=1e-5) and torch.allclose(v1, v2, atol=1e-7)
    # The mask drops padded points exactly.
    padded = torch.cat([pts[:100], torch.randn(20, 3)])[None]
    mask = torch.cat([torch.ones(100), torch.zeros(20)])[None]
    m3, v3 = encoder(padded, mask=mask)
    m4, v4 = encoder(pts[None, :100])
    assert torch.allclose(m3, m4, atol=1e-5) and torch.allclose(v3, v4)


@pytest.mark.slow  # optimises latents: about 6 s each
@pytest.mark.parametrize("scale", [False, True])
def test_latent_optimisation_lowers_the_context_loss(scale):
    from shapebench_igr.method import IGR

    torch.manual_seed(2)
    module = IGR(IGR.Options(recipe="official", latent_dim=16, width=64, depth=4)).build_module(1)
    for p in module.parameters():
        p.requires_grad_(False)
    pts = torch.stack([_sphere(200, 0.4, seed=s)[0] for s in (3, 4)])  # two objects
    ctxs = [
        Context(ObjectRef(str(i), "c"), np.zeros((1, 3)), np.zeros((1, 3)), seed=i)
        for i in range(2)
    ]
    z0 = initial_latents(ctxs, 16, 0.01, torch.device("cpu"))
    loss = module.completion_loss(pts, None)
    lr = 0.5 if scale else 5e-2  # "lr x error_0" needs a larger base step for the same effect
    z, history = optimise_latents(loss, z0, steps=60, lr=lr, scale_by_initial_loss=scale)
    assert history[-1] < 0.8 * history[0]
    assert not torch.equal(z, z0)
    torch.manual_seed(5)
    assert loss(z).mean() < loss(z0).mean()


def test_an_igr_objects_test_time_loss_does_not_depend_on_its_batch_mates():
    """IGR's test-time Eikonal samples are drawn per object (its context seed and the step):
    the same object's loss is the same alone and beside another, step after step; from one
    generator for the whole batch (no seeds) it is not."""
    from shapebench_igr.method import IGR

    torch.manual_seed(2)
    module = IGR(IGR.Options(recipe="official", latent_dim=16, width=64, depth=4)).build_module(1)
    a, b = (_sphere(200, 0.4, seed=s)[0] for s in (3, 4))
    z = torch.randn(2, 16) * 0.01

    def first_losses(points, seeds, steps=3) -> list[torch.Tensor]:
        torch.manual_seed(0)  # the global generator, as complete_batch seeds it per batch
        loss = module.completion_loss(points, None, 0, seeds)
        return [loss(z[: len(points)])[0] for _ in range(steps)]

    alone = first_losses(torch.stack([a]), [11])
    beside = first_losses(torch.stack([a, b]), [11, 12])
    assert all(torch.allclose(x, y, rtol=1e-6, atol=0) for x, y in zip(alone, beside, strict=True))
    assert not torch.equal(alone[0], alone[1])  # a new draw every step
    assert not torch.allclose(first_losses(torch.stack([a]), [13])[0], alone[0], rtol=1e-6, atol=0)

    # One generator for the batch: A's draws depend on what else the batch holds.
    def unseeded(points: torch.Tensor, index: int) -> torch.Tensor:
        torch.manual_seed(0)
        return module.completion_loss(points, None)(z[: len(points)])[index]

    assert not torch.allclose(
        unseeded(torch.stack([a]), 0), unseeded(torch.stack([b, a]), 1), rtol=1e-6, atol=0
    )


def test_initial_latents_are_seeded_per_object():
    ctxs = [
        Context(ObjectRef(str(i), "c"), np.zeros((1, 3)), np.zeros((1, 3)), seed=s)
        for i, s in enumerate((7, 8, 7))
    ]
    z = initial_latents(ctxs, 64, 0.01, torch.device("cpu"))
    assert torch.equal(z[0], z[2]) and not torch.equal(z[0], z[1])
    assert 0.005 < float(z.std()) < 0.02
