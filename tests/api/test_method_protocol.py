"""What every implicit method must respect: points-only contexts, one test-time optimiser per
recipe, equation 6 as written by default, and the shared largest-component filter; and what the
base of the trained methods promises: declared batch samples, modules built from the options, and
a new method in one method class and one module (the example of docs/plugins.md)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import ROOT
from shapebench_deepsdf.method import DeepSDF
from shapebench_igr.method import IGR
from shapebench_msc.method import MSC, MSCNoOpt
from shapebench_occnet.method import OccNet
from tiny_datasets import Blobs

from shapebench.api import options as opts
from shapebench.api.errors import ConfigError
from shapebench.api.method import TrainerOptions, TrainingContext
from shapebench.api.types import (
    Context,
    ObjectRef,
    Supervision,
)
from shapebench.config import load_profile, plugin_overrides
from shapebench.implicit.completion import mesh_completion, stack_contexts
from shapebench.implicit.losses import offsurface_samples
from shapebench.implicit.networks import MSCEncoder
from shapebench.implicit.recipes import PAPER_OPT_LR
from shapebench.registry.discovery import get_registry

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
    method = cls(
        cls.Options(
            latent_dim=8,
            width=32,
            depth=2,
            encoder_width=16,
            encoder_layers=1,
            opt_steps=3,
            mesh_resolution=16,
            max_target=64,
            lr_halve_every=10,
            **overrides,
        )
    )
    torch.manual_seed(0)
    method.module = method.build_module(1).eval()
    # Make the encoder's votes non-zero, so that an input it read would move the code.
    torch.nn.init.normal_(method.module.encoder.f[-1].weight, std=0.5)
    method.device = torch.device("cpu")
    return method


def _codes(method: MSCNoOpt, contexts: list[Context]) -> torch.Tensor:
    """The codes MSC's ``encode`` gives (it pairs each with its posterior variance)."""
    return torch.stack([z for z, _ in method.encode(contexts)])


def test_msc_encoder_has_no_normal_input_and_completes_points_only_contexts():
    encoder = MSCEncoder(latent_dim=8, hidden=16, layers=1)
    assert encoder.f[0].in_features == 4 and encoder.g[0].in_features == 4  # x, y, z, s = 0
    method = _tiny_msc()
    bare = _codes(method, _contexts())
    with_normals = _codes(method, _contexts(normals=True))
    assert torch.equal(bare, with_normals)  # arbitrary normals change nothing
    assert bare.abs().sum() > 0
    results = method.complete_batch(_contexts(), n_points=500)
    assert all(not isinstance(r, Exception) for r in results), results
    assert results[0].points.shape == (500, 3)


def test_options_that_read_normals_fail_clearly_without_them():
    with pytest.raises(ValueError, match="encoder_input=normals"):
        _tiny_msc(MSCNoOpt, encoder_input="normals").encode(_contexts())
    igr = IGR(
        IGR.Options(
            recipe="official", latent_dim=8, width=32, depth=2, test_normals=True, opt_steps=1
        )
    )
    igr.module = igr.build_module(1)
    igr.device = torch.device("cpu")
    with pytest.raises(ValueError, match="test_normals=true"):
        igr.encode(_contexts())
    assert igr.encode(_contexts(normals=True)).shape == (2, 8)


def test_stack_contexts_copes_with_missing_normals():
    pts, nrm = stack_contexts(_contexts(50), torch.device("cpu"))
    assert pts.shape == (2, 50, 3) and nrm is None
    _, nrm = stack_contexts(_contexts(50, normals=True), torch.device("cpu"))
    assert nrm.shape == (2, 50, 3)


@pytest.mark.parametrize("recipe", ["paper", "official"])
def test_auto_decoders_share_one_test_time_optimiser_per_recipe(recipe):
    resolved = {
        name: cls(cls.Options(recipe=recipe)).options for name, cls in AUTO_DECODERS.items()
    }
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


def test_igr_eikonal_sample_count_follows_the_recipe_not_the_context_size():
    assert IGR(IGR.Options(recipe="paper")).options.opt_eikonal_samples == 5000  # App. A.1's 5k
    assert IGR(IGR.Options(recipe="official")).options.opt_eikonal_samples == 0  # one per point
    quick = opts.build(IGR.Options, plugin_overrides("method", "igr", load_profile("quick")), "igr")
    assert IGR(quick).options.opt_eikonal_samples == 1000
    assert IGR(IGR.Options(opt_eikonal_samples=7)).options.opt_eikonal_samples == 7
    # The count follows the training recipe, not the test-time optimiser's (opt_recipe).
    swapped = IGR(IGR.Options(recipe="paper", opt_recipe="official")).options
    assert swapped.opt_eikonal_samples == 5000
    for bad in (-1, True):  # from a config file or the command line
        with pytest.raises(ConfigError, match="opt_eikonal_samples"):
            opts.build(IGR.Options, {"opt_eikonal_samples": bad}, "igr")
    with pytest.raises(ConfigError, match="opt_eikonal_samples"):  # from Python
        IGR.Options(opt_eikonal_samples=2.5)


def test_a_fixed_eikonal_count_draws_its_base_points_once():
    # With no move (variance 0) the samples are the base points themselves: 1000 draws with
    # replacement from 1000 points hit about 1 - 1/e = 632 distinct ones. Drawing twice (picks,
    # then picks of the picks) would hit about 470.
    surface = torch.arange(3000, dtype=torch.float32).reshape(1, 1000, 3)
    torch.manual_seed(0)
    off = offsurface_samples(surface, "paper", paper_variance=0.0, count=1000)
    assert off.shape == (1, 1000, 3)
    assert 590 < len(torch.unique(off[0], dim=0)) < 670
    assert torch.isin(off, surface).all()
    # count=0 keeps each mode's own rule: min(paper_count, n) picks, or every point + n/8.
    assert offsurface_samples(surface, "paper", paper_count=300).shape == (1, 300, 3)
    assert offsurface_samples(surface[:, :50], "paper").shape == (1, 50, 3)
    assert offsurface_samples(surface, "official", count=80).shape == (1, 80 + 10, 3)


@pytest.mark.parametrize(
    ("samples", "mode", "seen"),
    [
        (0, "paper", 50),
        (None, "paper", 50),
        (0, "official", 50 + 50 // 8),
        (300, "paper", 300),
        (300, "official", 300 + 300 // 8),
    ],
)
def test_igr_completion_evaluates_the_eikonal_term_on_the_option_s_count(samples, mode, seen):
    # The official recipe's count is 0 (one per context point); ``offsurface`` is explicit.
    method = IGR(
        IGR.Options(
            recipe="official",
            latent_dim=8,
            width=32,
            depth=2,
            opt_steps=2,
            offsurface=mode,
            opt_eikonal_samples=samples,
        )
    )
    method.module = method.build_module(1).eval()
    method.device = torch.device("cpu")
    sizes = []
    decoder = method.module.decoder
    shared = decoder.forward_shared  # what the test-time search evaluates (one code per object)

    def recording(z, x):
        sizes.append(x.shape)
        return shared(z, x)

    decoder.forward_shared = recording
    method.encode(_contexts(n=50))
    # Every step sees the 50 context points, then its Eikonal samples, for both objects.
    assert sizes and set(sizes) == {torch.Size([2, 50 + seen, 3])}


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


# -- the LightningMethod base: sample sizes, hyper-parameters, a sixth method -------------------


def _first_batch(method) -> dict[str, torch.Tensor]:
    ctx = TrainingContext(Blobs(), TrainerOptions(), Path("."), "", quiet=True)
    data = method.data_module(ctx)
    data.load_objects()
    return next(iter(data.train_dataloader()))


#: Per method: small options, and the batch shapes they must give (3 objects of 2 per batch).
SAMPLE_SIZES = {
    "igr": (dict(surface_points=40), {"points": (2, 40, 3), "normals": (2, 40, 3)}),
    "msc": (dict(surface_points=40), {"points": (2, 40, 3)}),
    "deepsdf": (dict(sdf_points=30), {"sdf": (2, 30, 4), "points": (2, 1, 3)}),
    "occnet": (
        dict(surface_points=20, query_points=30),
        {"points": (2, 20, 3), "occupancy": (2, 30, 4)},
    ),
    "pcn": (
        dict(surface_points=20, target_points=50),
        {"points": (2, 20, 3), "complete": (2, 50, 3)},
    ),
}


@pytest.mark.parametrize("name", sorted(SAMPLE_SIZES))
def test_each_method_declares_the_samples_of_its_batches(name):
    cls = get_registry().load("method", name)
    options, shapes = SAMPLE_SIZES[name]
    method = cls(cls.Options(batch_shapes=2, **options))
    assert set(method.sample_sizes()) <= method.needs() | {Supervision.OCCUPANCY_SAMPLES}
    batch = _first_batch(method)
    assert {k: tuple(batch[k].shape) for k in shapes} == shapes
    kinds = {"sdf", "occupancy", "complete"}
    assert kinds & set(batch) == kinds & set(shapes)  # nothing the method did not declare


@pytest.mark.parametrize("name", ["deepsdf", "igr", "msc", "occnet", "pcn"])
def test_modules_take_the_options_and_rebuild_them_from_their_hyperparameters(name):
    cls = get_registry().load("method", name)
    method = cls(cls.Options())
    module = method.build_module(3)
    assert module.options == method.options and module.n_shapes == 3
    saved = dict(module.hparams)
    assert all(
        isinstance(v, (int, float, str, bool, list, tuple, type(None))) for v in saved.values()
    )
    again = method.Module(**saved)
    assert again.options == method.options and again.n_shapes == 3
    # A checkpoint written before the modules took their options: hyper-parameters named as the
    # options it had then, and others; the missing ones take their defaults.
    legacy = {k: v for k, v in saved.items() if k not in ("recipe", "epochs", "batch_shapes")}
    old = method.Module(**legacy, sinkhorn_eps=0.01)
    shapes = {k: v.shape for k, v in module.state_dict().items()}
    assert {k: v.shape for k, v in old.state_dict().items()} == shapes


def _docs_example(root: Path) -> str:
    """The PointSDF plugin of docs/plugins.md, written under ``root``; its package name."""
    doc = (ROOT / "docs" / "plugins.md").read_text()
    doc = doc.split("## A trained method (PyTorch Lightning)")[1].split("\n## ")[0]
    package = root / "shapebench_pointsdf"
    package.mkdir()
    (package / "__init__.py").write_text("")
    for name in ("method.py", "module.py"):
        block = re.search(rf"`shapebench_pointsdf/{name}`:\n\n```python\n(.*?)```", doc, re.DOTALL)
        assert block, f"docs/plugins.md has no block for {name}"
        (package / name).write_text(block.group(1))
    return package.name


@pytest.mark.slow  # trains a small network with Lightning: about 10 s
def test_a_sixth_trained_method_is_one_method_class_and_one_module(tmp_path, monkeypatch):
    """The docs' PointSDF trains, checkpoints, loads and completes with no core code of its own,
    and registering it imports no torch."""
    import subprocess
    import sys

    monkeypatch.syspath_prepend(str(tmp_path))
    _docs_example(tmp_path)
    probe = (
        "import sys; import shapebench_pointsdf.method; "
        "assert 'torch' not in sys.modules, 'method.py imports torch'"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}
    subprocess.run([sys.executable, "-c", probe], check=True, env=env)
    from shapebench_pointsdf.method import PointSDF

    method = PointSDF(
        PointSDF.Options(
            epochs=30,
            batch_shapes=3,
            surface_points=100,
            sdf_points=256,
            lr=3e-3,
            mesh_resolution=32,
        )
    )
    trainer = TrainerOptions(accelerator="cpu", devices=1, seed=0)
    ctx = TrainingContext(Blobs(), trainer, tmp_path / "train", "", quiet=True)
    path = method.fit(ctx)
    fresh = PointSDF(method.options)
    fresh.load_checkpoint(path)
    sphere = Blobs().load(ObjectRef("blob/0", "blob"))
    context = Context(sphere.ref, sphere.surface_points[:100], None, seed=0)
    results = fresh.complete_batch([context, context], n_points=500)
    assert all(not isinstance(r, Exception) for r in results), results
    assert results[0].points.shape == (500, 3)
    assert np.array_equal(results[0].points, results[1].points)
