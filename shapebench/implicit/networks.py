"""Decoders and the MSC encoder, following the official code and the paper.

* :class:`IGRDecoder`: IGR's ``ImplicitNet``: ``depth`` hidden layers of ``width``, Softplus with
  beta = 100, the network input re-injected at the middle layer (concatenated and divided by
  sqrt(2)), the latent code *before* xyz, and the geometric initialisation that makes the initial
  function approximately the SDF of a sphere of radius ``radius_init``. MSC uses it too.
* :class:`DeepSDFDecoder`: DeepSDF's decoder: ReLU (the paper's choice), dropout 0.2 and weight
  norm on every hidden layer, the input re-injected at the middle layer without scaling, and the
  final tanh that the official forward always applies.
* :class:`MSCEncoder`: the posterior of equation 2 from per-point networks f and g.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F


def _dims(in_dim: int, width: int, depth: int, skip: int) -> list[tuple[int, int]]:
    """(in, out) of each linear layer, the skip concatenation included.

    As in IGR and DeepSDF, the layer before the skip outputs ``width - in_dim`` so that the
    concatenation with the input is ``width`` wide. When the input is wider than the layers (MSC's
    1024-d code with 512-wide layers, which that design cannot fit), the layer before the skip
    keeps its full width and the layer after it takes ``width + in_dim`` inputs instead.
    """
    fits = width > in_dim
    layers = []
    prev = in_dim
    for i in range(depth + 1):
        out = 1 if i == depth else width
        if i + 1 == skip and fits:
            out = width - in_dim
        layers.append((prev, out))
        prev = out
        if i + 1 == skip:
            prev = out + in_dim
    return layers


class SkipMLP(nn.Module):
    """f(z, x): latent ``z`` (B, d) or (B, n, d) and points ``x`` (B, n, 3) -> values (B, n).

    The code goes first, the network input is concatenated again before layer ``skip`` (scaled
    by ``skip_scale``); subclasses give the layers, the hidden activation and the output map.
    """

    layers: nn.ModuleList
    skip: int
    skip_scale: float = 1.0

    def hidden(self, h: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def output(self, h: torch.Tensor) -> torch.Tensor:
        return h

    def forward(self, z: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        if z.dim() == 2:
            z = z[:, None, :].expand(-1, x.shape[1], -1)
        inp = torch.cat([z, x], dim=-1)
        h = inp
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            if i == self.skip:
                h = torch.cat([h, inp], dim=-1) * self.skip_scale
            h = layer(h)
            if i < last:
                h = self.hidden(h)
        return self.output(h).squeeze(-1)

    def forward_shared(self, z: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """:meth:`forward` for one code per object, ``z`` (B, d): the same function, computed
        with the code's share of the first layer and of the skip layer once per object instead of
        once per point, and without concatenating the code to every point.

        Used where one code meets many points (the field meshed at completion, the test-time
        latent search): about 1.4x faster for MSC's field on a CPU, equal to :meth:`forward` up to
        float rounding (the sums are ordered differently). Training keeps :meth:`forward`, so
        the trained weights do not depend on this.
        """
        if z.dim() != 2 or self.skip == 0:
            return self.forward(z, x)
        b, d = z.shape
        last = len(self.layers) - 1

        def per_point(w: torch.Tensor) -> torch.Tensor:  # (out, k) -> (B, k, out) for baddbmm
            return w.t().expand(b, -1, -1)

        h = x
        for i, layer in enumerate(self.layers):
            w = layer.weight
            if i == 0:  # [z, x] W^T + c = x W_x^T + (z W_z^T + c); fused adds (baddbmm)
                code = torch.addmm(layer.bias, z, w[:, :d].t())[:, None, :]
                h = torch.baddbmm(code, x, per_point(w[:, d:]))
            elif i == self.skip:  # s [h, z, x] W^T + c, the code's share once per object
                s, wh = self.skip_scale, h.shape[-1]
                code = torch.addmm(layer.bias, z, w[:, wh : wh + d].t(), alpha=s)[:, None, :]
                h = torch.baddbmm(code, h, per_point(w[:, :wh]), alpha=s)
                h = h.baddbmm(x, per_point(w[:, wh + d :]), alpha=s)
            else:
                h = layer(h)
            if i < last:
                h = self.hidden(h)
        return self.output(h).squeeze(-1)


class IGRDecoder(SkipMLP):
    """IGR's ``ImplicitNet``: Softplus(beta), skip input scaled by 1/sqrt(2), linear output."""

    skip_scale = 1 / math.sqrt(2)

    def __init__(
        self,
        latent_dim: int,
        width: int = 512,
        depth: int = 8,
        beta: float = 100.0,
        radius_init: float = 1.0,
        geometric_init: bool = True,
    ) -> None:
        super().__init__()
        self.latent_dim = latent_dim
        self.skip = depth // 2
        dims = _dims(latent_dim + 3, width, depth, self.skip)
        self.layers = nn.ModuleList(nn.Linear(i, o) for i, o in dims)
        self.activation = nn.Softplus(beta=beta)
        if geometric_init:
            self._geometric_init(radius_init)

    def _geometric_init(self, radius: float) -> None:
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            if i == last:
                mean = math.sqrt(math.pi) / math.sqrt(layer.in_features)
                nn.init.normal_(layer.weight, mean=mean, std=1e-5)
                nn.init.constant_(layer.bias, -radius)
            else:
                nn.init.normal_(layer.weight, 0.0, math.sqrt(2) / math.sqrt(layer.out_features))
                nn.init.constant_(layer.bias, 0.0)

    def hidden(self, h: torch.Tensor) -> torch.Tensor:
        return self.activation(h)


class DeepSDFDecoder(SkipMLP):
    """DeepSDF's decoder: weight-normed hidden layers, ReLU, dropout, unscaled skip, tanh."""

    def __init__(
        self, latent_dim: int, width: int = 512, depth: int = 8, dropout: float = 0.2
    ) -> None:
        super().__init__()
        self.latent_dim = latent_dim
        self.skip = depth // 2
        layers = []
        for i, (a, b) in enumerate(_dims(latent_dim + 3, width, depth, self.skip)):
            lin = nn.Linear(a, b)
            layers.append(nn.utils.parametrizations.weight_norm(lin) if i < depth else lin)
        self.layers = nn.ModuleList(layers)
        self.dropout = dropout

    def hidden(self, h: torch.Tensor) -> torch.Tensor:
        return F.dropout(F.relu(h), p=self.dropout, training=self.training)

    def output(self, h: torch.Tensor) -> torch.Tensor:
        return torch.tanh(h)


def mlp(sizes: list[int]) -> nn.Sequential:
    mods: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        mods.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            mods.append(nn.ReLU())
    return nn.Sequential(*mods)


class MSCEncoder(nn.Module):
    """The posterior p(h | D) of equation 2, a diagonal Gaussian over the latent code.

    Each observation (x_n, y_n) -- a position and the signed distance observed there, 0 for the
    surface points the benchmark gives (s_n = 0 in equation 3) -- goes through two per-point MLPs:
    f gives its vote f_n for the code, g its precision. Normals are not an input by default: the
    protocol gives methods points only at test time (``inputs="normals"`` takes y_n = the normal
    instead, for protocols that supply normals). Equation 2 writes the precision as
    sum_n (1/g_n^2 - 1/g_0^2) + 1/g_0^2, which goes negative whenever a point's 1/g_n^2 is below
    the prior's. Here the per-point increment r_n = 1/g_n^2 - 1/g_0^2 is produced directly through
    a softplus, so it is never negative, and the prior precision 1/g_0^2 is a learned positive
    vector: the precision starts at the prior with no points and only grows as points are added,
    so the variance shrinks like 1/N. The mean weights each vote by the point's full precision
    1/g_n^2 = r_n + 1/g_0^2, as printed (``mean_weights="printed"``); ``"increment"`` weights by
    r_n, the exact linear-Gaussian posterior. Sums make it order-invariant and accept any N.
    """

    #: Per-point inputs: x, y, z and y_n, the observed signed distance (1) or the normal (3).
    INPUTS = {"sdf": 4, "normals": 6}

    def __init__(
        self,
        latent_dim: int,
        hidden: int = 512,
        layers: int = 3,
        mean_weights: str = "printed",
        inputs: str = "sdf",
    ) -> None:
        super().__init__()
        if inputs not in self.INPUTS:
            raise ValueError(f"inputs must be one of {list(self.INPUTS)}, got {inputs!r}")
        self.inputs = inputs
        sizes = [self.INPUTS[inputs]] + [hidden] * layers
        self.f = mlp([*sizes, latent_dim])
        self.g = mlp([*sizes, latent_dim])
        self.prior_precision_raw = nn.Parameter(torch.zeros(latent_dim))
        # The votes start at zero, so the first codes are the prior mean 0 and the decoder starts
        # from its geometric initialisation (a sphere), as IGR's zero-initialised codes do.
        nn.init.zeros_(self.f[-1].weight)
        nn.init.zeros_(self.f[-1].bias)
        if mean_weights not in ("printed", "increment"):
            raise ValueError(f"mean_weights must be 'printed' or 'increment', got {mean_weights!r}")
        self.mean_weights = mean_weights

    def prior_precision(self) -> torch.Tensor:
        return F.softplus(self.prior_precision_raw) + 1e-4

    def forward(
        self, points: torch.Tensor, y: torch.Tensor | None = None, mask: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``points`` (B, N, 3); ``y`` their observed signed distances (B, N), zeros when omitted
        (surface points), or their normals (B, N, 3) with ``inputs="normals"``; optional ``mask``
        (B, N) of real points.

        Returns the posterior mean and variance, each (B, d).
        """
        if self.inputs == "sdf":
            y = (points.new_zeros(points.shape[:-1]) if y is None else y)[..., None]
        elif y is None:
            raise ValueError("an MSC encoder with inputs='normals' needs the points' normals")
        inp = torch.cat([points, y], dim=-1)
        f = self.f(inp)
        r = F.softplus(self.g(inp))
        if mask is not None:
            r = r * mask[..., None]
        p0 = self.prior_precision()
        precision = p0 + r.sum(dim=1)
        weights = r + p0 if self.mean_weights == "printed" else r
        if mask is not None:
            weights = weights * mask[..., None]
        var = 1.0 / precision
        mean = var * (f * weights).sum(dim=1)
        return mean, var
