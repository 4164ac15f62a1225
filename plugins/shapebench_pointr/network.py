"""PoinTr's network, laid out as the official code (yuxumin/PoinTr ``models/PoinTr.py``,
``models/dgcnn_group.py``, ``models/Transformer.py``), with every size an option:

* point proxies (:class:`DGCNNGrouper`): Conv1d 3 -> 8, four EdgeConv layers (k = 16 neighbours
  in xyz; the edge feature [f_j - f_i, f_i]; a 1x1 convolution, GroupNorm(4), LeakyReLU(0.2), max
  over the neighbours; 32, 64, 64, 128 channels), farthest-point sampling 512 and then 128
  centres between them (fewer when the context has fewer points: 50 points give 50 proxies);
* the transformer: tokens = 1x1 convolutions 128 -> C -> C (BatchNorm, LeakyReLU(0.2)) of the
  proxies' features; an encoder of pre-LayerNorm blocks (self-attention, MLP of ratio 2) with
  the centres' embedding (3 -> 128 -> C, BatchNorm, LeakyReLU(0.2)) added before every block; a
  decoder of blocks (self-attention, cross-attention to the encoder, MLP). Attention maps q, k,
  v without bias (the official ``qkv_bias=False``). The first block of each also runs a geometry
  branch (k = 8 nearest centres: [f_j - f_i, f_i] -> Linear(2C -> C), LeakyReLU, max) whose
  output is concatenated with the attention's and merged by Linear(2C -> C); the first decoder
  block runs one for its cross-attention too (the 8 encoder centres nearest each query centre);
* queries: the encoder's tokens -> 1x1 convolutions C -> 1024 -> 1024 (BatchNorm, LeakyReLU),
  max-pooled to a global feature, an MLP 1024 -> 1024 -> 3M predicting M coarse centres; each
  query's feature is an MLP of [global, centre] (1027 -> 1024 -> 1024 -> C);
* rebuild: the decoder's tokens -> 1x1 convolutions C -> 1024 -> 1024 (BatchNorm, LeakyReLU),
  max-pooled; Linear(1024 + C + 3 -> C) of [that global feature, the query's feature, its
  centre], then FoldingNet: a step x step grid in [-1, 1]^2 folded twice by 1x1 convolutions
  (C + 2 -> 256 -> 128 -> 3, then C + 3 -> 256 -> 128 -> 3, BatchNorm and ReLU) into offsets
  from the centre. The output is the folded points and the input; the coarse cloud is the
  centres and a farthest-point sample of the input.

A 1x1 convolution over points is a Linear layer over tokens; :class:`TokenBatchNorm` takes its
BatchNorm over every token of the batch, as BatchNorm1d does over (B, C, N). The official
initialisation (:func:`official_init`) covers the grouper, the transformer and the query
layers, as the official ``PCTransformer._init_weights`` does; the rebuild and folding layers
keep PyTorch's defaults, as the official ``PoinTr`` module's do.

``global_dim`` (1024) is an option so that the CPU profile can shrink it with the width.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from shapebench_pointr.method import INITS


def farthest_point_sample(xyz: torch.Tensor, n: int) -> torch.Tensor:
    """(B, n) indices of a farthest-point sample of ``xyz`` (B, N, 3), from index 0 (as the
    official CUDA kernel); ``n`` <= N."""
    b, total, _ = xyz.shape
    idx = torch.zeros(b, n, dtype=torch.long, device=xyz.device)
    nearest = torch.full((b, total), float("inf"), device=xyz.device)
    last = torch.zeros(b, dtype=torch.long, device=xyz.device)
    rows = torch.arange(b, device=xyz.device)
    for i in range(n):
        idx[:, i] = last
        d = ((xyz - xyz[rows, last][:, None, :]) ** 2).sum(dim=-1)
        nearest = torch.minimum(nearest, d)
        last = nearest.argmax(dim=1)
    return idx


def gather_points(values: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``values`` (B, N, C) at ``idx`` (B, M) or (B, M, k): (B, M, C) or (B, M, k, C)."""
    b = values.shape[0]
    base = torch.arange(b, device=idx.device).view(b, *([1] * (idx.dim() - 1))) * values.shape[1]
    rows = values.reshape(-1, values.shape[-1]).index_select(0, (idx + base).reshape(-1))
    return rows.view(*idx.shape, values.shape[-1])


def knn(query: torch.Tensor, points: torch.Tensor, k: int) -> torch.Tensor:
    """(B, M, k) indices of the k points of ``points`` (B, N, 3) nearest each query (B, M, 3)."""
    return torch.cdist(query, points).topk(min(k, points.shape[1]), largest=False).indices


class EdgeConv(nn.Module):
    """[f_j - f_i, f_i] over the k nearest neighbours j of each centre i, 1x1 conv, GroupNorm(4),
    LeakyReLU(0.2), max over j."""

    def __init__(self, cin: int, cout: int) -> None:
        super().__init__()
        self.conv = nn.Conv2d(2 * cin, cout, 1, bias=False)
        self.norm = nn.GroupNorm(4, cout)

    def forward(self, q_xyz, q_f, k_xyz, k_f, k: int = 16) -> torch.Tensor:
        idx = knn(q_xyz, k_xyz, k)  # (B, M, k)
        neighbours = gather_points(k_f, idx)  # (B, M, k, C)
        centre = q_f[:, :, None, :].expand_as(neighbours)
        edge = torch.cat([neighbours - centre, centre], dim=-1).permute(0, 3, 1, 2)
        out = F.leaky_relu(self.norm(self.conv(edge)), 0.2)  # (B, C', M, k)
        return out.max(dim=-1).values.transpose(1, 2)  # (B, M, C')


class DGCNNGrouper(nn.Module):
    """Points (B, N, 3) -> proxy centres (B, P, 3) and features (B, P, 128)."""

    def __init__(self, first: int = 512, proxies: int = 128) -> None:
        super().__init__()
        self.first, self.proxies = first, proxies
        self.input_trans = nn.Linear(3, 8)
        self.layers = nn.ModuleList(
            [EdgeConv(8, 32), EdgeConv(32, 64), EdgeConv(64, 64), EdgeConv(64, 128)]
        )

    @staticmethod
    def _sample(xyz, f, n):
        idx = farthest_point_sample(xyz, min(n, xyz.shape[1]))
        return gather_points(xyz, idx), gather_points(f, idx)

    def forward(self, xyz: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        f = self.input_trans(xyz)
        f = self.layers[0](xyz, f, xyz, f)
        q_xyz, q_f = self._sample(xyz, f, self.first)
        f = self.layers[1](q_xyz, q_f, xyz, f)
        xyz = q_xyz
        f = self.layers[2](xyz, f, xyz, f)
        q_xyz, q_f = self._sample(xyz, f, self.proxies)
        f = self.layers[3](q_xyz, q_f, xyz, f)
        return q_xyz, f


class TokenBatchNorm(nn.BatchNorm1d):
    """BatchNorm1d over the tokens of (..., C): statistics over every token of the batch, as the
    official BatchNorm1d after a 1x1 Conv1d takes them over (B, C, N)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(x.reshape(-1, x.shape[-1])).view_as(x)


def pointwise_mlp(cin: int, hidden: int, cout: int) -> nn.Sequential:
    """The official 1x1 Conv1d(cin -> hidden), BatchNorm1d, LeakyReLU(0.2), Conv1d(hidden -> cout)
    over tokens (B, N, C)."""
    return nn.Sequential(
        nn.Linear(cin, hidden), TokenBatchNorm(hidden), nn.LeakyReLU(0.2), nn.Linear(hidden, cout)
    )


class Attention(nn.Module):
    """Multi-head scaled dot-product attention of ``query`` (B, M, C) over ``source`` (B, N, C):
    q, k, v maps without bias (official ``qkv_bias=False``), an output projection with bias."""

    def __init__(self, dim: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.q = nn.Linear(dim, dim, bias=False)
        self.kv = nn.Linear(dim, 2 * dim, bias=False)
        self.proj = nn.Linear(dim, dim)

    def forward(self, query: torch.Tensor, source: torch.Tensor) -> torch.Tensor:
        b, m, c = query.shape
        h = self.heads
        q = self.q(query).view(b, m, h, c // h).transpose(1, 2)
        k, v = self.kv(source).view(b, source.shape[1], 2, h, c // h).permute(2, 0, 3, 1, 4)
        # Spelled out rather than scaled_dot_product_attention, whose CPU kernels may pick a
        # different reduction order with the thread count (trainings are bitwise repeatable).
        weights = ((q @ k.transpose(-2, -1)) * (c // h) ** -0.5).softmax(dim=-1)
        return self.proj((weights @ v).transpose(1, 2).reshape(b, m, c))


class GeometryBranch(nn.Module):
    """For each query token i, its k nearest tokens j of ``source`` (by their centres):
    [f_j - f_i, f_i] -> Linear(2C -> C), LeakyReLU(0.2), max over j."""

    def __init__(self, dim: int, k: int = 8) -> None:
        super().__init__()
        self.k = k
        self.linear = nn.Linear(2 * dim, dim)

    def forward(self, x, xyz, source=None, source_xyz=None) -> torch.Tensor:
        source = x if source is None else source
        source_xyz = xyz if source_xyz is None else source_xyz
        neighbours = gather_points(source, knn(xyz, source_xyz, self.k))
        centre = x[:, :, None, :].expand_as(neighbours)
        out = F.leaky_relu(self.linear(torch.cat([neighbours - centre, centre], dim=-1)), 0.2)
        return out.max(dim=2).values


class Block(nn.Module):
    """A pre-LayerNorm transformer block: self-attention, cross-attention to ``memory`` when
    ``cross``, an MLP of ratio ``mlp_ratio``. When ``geometric``, each attention's output is
    merged with a geometry branch's (official: the first block of the encoder and decoder)."""

    def __init__(self, dim: int, heads: int, mlp_ratio: float, cross: bool, geometric: bool):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim)
        self.attn = Attention(dim, heads)
        self.geometry = GeometryBranch(dim) if geometric else None
        self.merge = nn.Linear(2 * dim, dim) if geometric else None
        self.cross = Attention(dim, heads) if cross else None
        self.norm_q = nn.LayerNorm(dim) if cross else None
        self.norm_m = nn.LayerNorm(dim) if cross else None
        self.cross_geometry = GeometryBranch(dim) if cross and geometric else None
        self.cross_merge = nn.Linear(2 * dim, dim) if cross and geometric else None
        self.norm2 = nn.LayerNorm(dim)
        hidden = int(dim * mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, dim))

    def forward(self, x, xyz, memory=None, memory_xyz=None):
        h = self.norm1(x)
        attended = self.attn(h, h)
        if self.geometry is not None:
            attended = self.merge(torch.cat([attended, self.geometry(h, xyz)], dim=-1))
        x = x + attended
        if self.cross is not None:
            q, m = self.norm_q(x), self.norm_m(memory)
            attended = self.cross(q, m)
            if self.cross_geometry is not None:
                local = self.cross_geometry(q, xyz, m, memory_xyz)
                attended = self.cross_merge(torch.cat([attended, local], dim=-1))
            x = x + attended
        return x + self.mlp(self.norm2(x))


class Folding(nn.Module):
    """FoldingNet's two folds of a step x step grid into offsets of ``dim``-feature proxies."""

    def __init__(self, dim: int, step: int) -> None:
        super().__init__()
        g = torch.linspace(-1.0, 1.0, step)
        grid = torch.stack(torch.meshgrid(g, g, indexing="ij"), dim=-1).reshape(-1, 2)
        self.register_buffer("grid", grid.t().contiguous(), persistent=False)  # (2, S)

        def fold(cin: int) -> nn.Sequential:
            return nn.Sequential(
                nn.Conv1d(cin, 256, 1),
                nn.BatchNorm1d(256),
                nn.ReLU(),
                nn.Conv1d(256, 128, 1),
                nn.BatchNorm1d(128),
                nn.ReLU(),
                nn.Conv1d(128, 3, 1),
            )

        self.fold1, self.fold2 = fold(dim + 2), fold(dim + 3)

    def forward(self, feature: torch.Tensor) -> torch.Tensor:
        """(R, dim) features -> (R, S, 3) offsets."""
        r, s = feature.shape[0], self.grid.shape[1]
        f = feature[:, :, None].expand(-1, -1, s)
        grid = self.grid[None].expand(r, -1, -1)
        first = self.fold1(torch.cat([grid, f], dim=1))
        second = self.fold2(torch.cat([first, f], dim=1))
        return second.transpose(1, 2)


class PoinTrNetwork(nn.Module):
    """A context (B, N, 3) -> (coarse (B, M + m, 3), fine (B, M S + N, 3))."""

    def __init__(
        self,
        dim: int = 384,
        heads: int = 6,
        depth: tuple[int, int] = (6, 8),
        mlp_ratio: float = 2.0,
        num_query: int = 224,
        fold_step: int = 8,
        global_dim: int = 1024,
        first_sample: int = 512,
        proxies: int = 128,
        init: str = "official",
    ) -> None:
        super().__init__()
        if init not in INITS:
            raise ValueError(f"init must be one of {list(INITS)}, got {init!r}")
        self.num_query = num_query
        self.grouper = DGCNNGrouper(first_sample, proxies)
        self.input_proj = pointwise_mlp(128, dim, dim)
        self.pos_embed = pointwise_mlp(3, 128, dim)
        self.encoder = nn.ModuleList(
            Block(dim, heads, mlp_ratio, cross=False, geometric=i == 0) for i in range(depth[0])
        )
        self.decoder = nn.ModuleList(
            Block(dim, heads, mlp_ratio, cross=True, geometric=i == 0) for i in range(depth[1])
        )
        self.increase_dim = pointwise_mlp(dim, global_dim, global_dim)
        self.coarse_pred = nn.Sequential(
            nn.Linear(global_dim, global_dim), nn.ReLU(), nn.Linear(global_dim, 3 * num_query)
        )
        self.query_mlp = nn.Sequential(
            nn.Linear(global_dim + 3, global_dim),
            nn.LeakyReLU(0.2),
            nn.Linear(global_dim, global_dim),
            nn.LeakyReLU(0.2),
            nn.Linear(global_dim, dim),
        )
        self.rebuild_dim = pointwise_mlp(dim, global_dim, global_dim)
        self.reduce_map = nn.Linear(global_dim + dim + 3, dim)
        self.folding = Folding(dim, fold_step)
        if init == "torch":
            return  # every layer keeps PyTorch's default initialisation
        official_init(
            [self.grouper, self.input_proj, self.pos_embed, self.encoder, self.increase_dim]
            + [self.coarse_pred, self.query_mlp, self.decoder],
            convolutions=[self.grouper.input_trans, self.input_proj, self.pos_embed]
            + [self.increase_dim, self.query_mlp],
        )

    def forward(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b = points.shape[0]
        centres, features = self.grouper(points)
        x = self.input_proj(features)
        pos = self.pos_embed(centres)
        for block in self.encoder:
            x = block(x + pos, centres)
        global_feature = self.increase_dim(x).max(dim=1).values  # (B, G)
        coarse = self.coarse_pred(global_feature).view(b, self.num_query, 3)
        q = self.query_mlp(
            torch.cat([global_feature[:, None].expand(-1, self.num_query, -1), coarse], dim=-1)
        )
        for block in self.decoder:
            q = block(q, coarse, memory=x, memory_xyz=centres)
        decoded = self.rebuild_dim(q).max(dim=1).values  # (B, G)
        rebuild = torch.cat([decoded[:, None].expand(-1, self.num_query, -1), q, coarse], dim=-1)
        feature = self.reduce_map(rebuild).reshape(b * self.num_query, -1)
        offsets = self.folding(feature).view(b, self.num_query, -1, 3)
        fine = (coarse[:, :, None, :] + offsets).reshape(b, -1, 3)
        # The input is part of the output (official): the observed points are kept exactly.
        sample = gather_points(
            points, farthest_point_sample(points, min(self.num_query, points.shape[1]))
        )
        return torch.cat([coarse, sample], dim=1), torch.cat([fine, points], dim=1)


def official_init(modules: list[nn.Module], convolutions: list[nn.Module]) -> None:
    """The official ``PCTransformer._init_weights`` over ``modules``: Linear weights truncated
    normal (std 0.02) with zero biases, LayerNorm and BatchNorm 1 and 0, and the Linear layers
    under ``convolutions`` (the official 1x1 Conv1d ones) Xavier-normal weights (their biases
    keep the default, as a Conv1d's do there)."""
    conv = {id(m) for c in convolutions for m in c.modules() if isinstance(m, nn.Linear)}
    for module in modules:
        for m in module.modules():
            if isinstance(m, nn.Linear) and id(m) in conv:
                nn.init.xavier_normal_(m.weight)
            elif isinstance(m, nn.Linear):
                nn.init.trunc_normal_(m.weight, std=0.02)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, (nn.LayerNorm, nn.BatchNorm1d)):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
