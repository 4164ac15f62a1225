"""ConvONet's three-plane networks, as the official ``convolutional_occupancy_networks`` code lays
them out (``src/encoder/pointnet.py``, ``src/encoder/unet.py``,
``src/conv_onet/models/decoder.py``):

* :class:`LocalPoolPointnet`: Linear 3 -> 2h, five ResnetBlockFC(2h -> h); before blocks 2 to 5
  every point's feature is joined by the max over the points that fall into its cell of each of
  the three planes (xz, xy, yz; the three maxima summed); Linear h -> c; then each plane is the
  mean of the features of the points in each cell (``reso`` x ``reso``, empty cells 0), put
  through one U-Net shared by the three planes.
* :class:`UNet`: ``depth`` levels of two 3x3 convolutions with ReLU (no normalisation), channels
  ``start``, 2 ``start``, ... , max-pooling between levels; back up by 2x2 transposed convolutions,
  concatenation with the level's features, two 3x3 convolutions with ReLU; a 1x1 convolution to
  ``c`` channels.
* :class:`LocalDecoder`: each query's feature is the sum over the planes of a bilinear
  ``grid_sample`` (align_corners, border padding) at its projection; Linear 3 -> hidden, then five
  ResnetBlockFC(hidden), each preceded by adding Linear(c -> hidden) of the feature; one logit.

Coordinates of the unit-radius frame map to plane cells as the official ``normalize_coordinate``
maps its unit cube: p / (2 (1 + padding) + 1e-5) + 0.5, clamped below 1, padding 0.1 (the box
[-1.1, 1.1] the occupancy queries fill).
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from shapebench.train.blocks import ResnetBlockFC

#: The planes and the coordinate axes each spans (official: xz, xy, yz).
PLANES = {"xz": (0, 2), "xy": (0, 1), "yz": (1, 2)}
PADDING = 0.1


def plane_coordinates(points: torch.Tensor, plane: str) -> torch.Tensor:
    """(B, N, 2) coordinates in [0, 1) of ``points`` (B, N, 3) projected on ``plane``."""
    xy = points[..., list(PLANES[plane])] / (2 * (1 + PADDING) + 1e-5) + 0.5
    return xy.clamp(0.0, 1.0 - 1e-6)


def cell_index(points: torch.Tensor, plane: str, reso: int) -> torch.Tensor:
    """(B, N) index of each point's cell in the flattened ``reso`` x ``reso`` plane."""
    ij = (plane_coordinates(points, plane) * reso).long()
    return ij[..., 0] + reso * ij[..., 1]


def scatter_cells(
    values: torch.Tensor, index: torch.Tensor, cells: int, reduce: str
) -> torch.Tensor:
    """(B, C, cells): ``values`` (B, N, C) reduced per cell (``amax`` or ``mean``); 0 where no
    point falls (torch_scatter's behaviour in the official code)."""
    b, _, c = values.shape
    out = values.new_zeros(b, c, cells)
    idx = index[:, None, :].expand(-1, c, -1)
    return out.scatter_reduce(2, idx, values.transpose(1, 2), reduce=reduce, include_self=False)


class LocalPoolPointnet(nn.Module):
    """Points (B, N, 3) -> three feature planes, each (B, c_dim, reso, reso)."""

    def __init__(self, c_dim: int, hidden: int, reso: int, unet_depth: int, unet_start: int):
        super().__init__()
        self.reso = reso
        self.fc_pos = nn.Linear(3, 2 * hidden)
        self.blocks = nn.ModuleList(ResnetBlockFC(2 * hidden, hidden) for _ in range(5))
        self.fc_c = nn.Linear(hidden, c_dim)
        self.unet = UNet(c_dim, c_dim, unet_depth, unet_start)

    def pool_local(self, index: dict[str, torch.Tensor], net: torch.Tensor) -> torch.Tensor:
        """Per point, the sum over the planes of the max of ``net`` over its cell's points."""
        cells = self.reso * self.reso
        out = torch.zeros_like(net)
        for key in PLANES:
            pooled = scatter_cells(net, index[key], cells, "amax")  # (B, C, cells)
            idx = index[key][:, None, :].expand(-1, net.shape[-1], -1)
            out = out + pooled.gather(2, idx).transpose(1, 2)
        return out

    def forward(self, points: torch.Tensor) -> dict[str, torch.Tensor]:
        index = {key: cell_index(points, key, self.reso) for key in PLANES}
        net = self.blocks[0](self.fc_pos(points))
        for block in self.blocks[1:]:
            net = block(torch.cat([net, self.pool_local(index, net)], dim=2))
        c = self.fc_c(net)
        planes = {}
        for key in PLANES:
            plane = scatter_cells(c, index[key], self.reso * self.reso, "mean")
            plane = plane.view(len(points), -1, self.reso, self.reso)
            planes[key] = self.unet(plane)
        return planes


def _double_conv(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1),
        nn.ReLU(),
        nn.Conv2d(cout, cout, 3, padding=1),
        nn.ReLU(),
    )


class UNet(nn.Module):
    """The official 2-D U-Net (``depth`` levels from ``start`` channels, no normalisation)."""

    def __init__(self, cin: int, cout: int, depth: int, start: int) -> None:
        super().__init__()
        widths = [start * 2**i for i in range(depth)]
        self.down = nn.ModuleList(
            _double_conv(cin if i == 0 else widths[i - 1], w) for i, w in enumerate(widths)
        )
        self.up = nn.ModuleList(
            nn.ConvTranspose2d(widths[i], widths[i - 1], 2, stride=2)
            for i in range(depth - 1, 0, -1)
        )
        self.merge = nn.ModuleList(
            _double_conv(2 * widths[i - 1], widths[i - 1]) for i in range(depth - 1, 0, -1)
        )
        self.out = nn.Conv2d(widths[0], cout, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for i, block in enumerate(self.down):
            x = block(x)
            if i < len(self.down) - 1:
                skips.append(x)
                x = F.max_pool2d(x, 2)
        for up, merge, skip in zip(self.up, self.merge, reversed(skips), strict=True):
            x = merge(torch.cat([up(x), skip], dim=1))
        return self.out(x)


class LocalDecoder(nn.Module):
    """Occupancy logits (B, T) of queries (B, T, 3) given the planes of their objects."""

    def __init__(self, c_dim: int, hidden: int, blocks: int = 5) -> None:
        super().__init__()
        self.fc_p = nn.Linear(3, hidden)
        self.fc_c = nn.ModuleList(nn.Linear(c_dim, hidden) for _ in range(blocks))
        self.blocks = nn.ModuleList(ResnetBlockFC(hidden, hidden) for _ in range(blocks))
        self.fc_out = nn.Linear(hidden, 1)

    @staticmethod
    def sample(planes: dict[str, torch.Tensor], points: torch.Tensor) -> torch.Tensor:
        """(B, T, c): the planes' features at the queries' projections, summed."""
        out = 0
        for key, plane in planes.items():
            grid = (2.0 * plane_coordinates(points, key) - 1.0)[:, :, None, :]  # (B, T, 1, 2)
            feature = F.grid_sample(
                plane, grid, mode="bilinear", padding_mode="border", align_corners=True
            )
            out = out + feature[..., 0].transpose(1, 2)
        return out

    def forward(self, points: torch.Tensor, planes: dict[str, torch.Tensor]) -> torch.Tensor:
        c = self.sample(planes, points)
        net = self.fc_p(points)
        for fc_c, block in zip(self.fc_c, self.blocks, strict=True):
            net = block(net + fc_c(c))
        return self.fc_out(F.relu(net))[..., 0]
