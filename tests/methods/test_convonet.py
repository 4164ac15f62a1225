"""ConvONet (issue 30): the three-plane pieces by hand (cells, the per-cell mean and max, the
local pooling against brute force, bilinear reads of a plane), the U-Net's shapes, and that the
whole network learns occupancy (spheres of varying radius and centre, IoU on held-out ones)."""

from __future__ import annotations

import pytest
import torch
from shapebench_convonet.method import ConvONet, ConvONetOptions
from shapebench_convonet.module import ConvONetModule
from shapebench_convonet.network import (
    PLANES,
    LocalDecoder,
    LocalPoolPointnet,
    UNet,
    cell_index,
    plane_coordinates,
    scatter_cells,
)

from shapebench.api.errors import ConfigError


def test_cells_of_the_padded_box_by_hand() -> None:
    # The box [-1.1, 1.1] maps to [0, 1): its corner to cell 0, its centre to the middle cell,
    # and a point beyond the box is clamped into the last cell.
    points = torch.tensor([[[-1.1, -1.1, -1.1], [0.0, 0.0, 0.0], [5.0, 5.0, 5.0]]])
    assert cell_index(points, "xy", 4)[0].tolist() == [0, 2 + 4 * 2, 3 + 4 * 3]
    # xz reads x and z: a point at x = +1, z = -1 differs from one at x = -1, z = +1.
    uv = plane_coordinates(torch.tensor([[[1.0, 0.0, -1.0]]]), "xz")[0, 0]
    assert uv[0] > 0.9 and uv[1] < 0.1
    assert set(PLANES) == {"xz", "xy", "yz"}


def test_per_cell_mean_and_max_leave_empty_cells_zero() -> None:
    values = torch.tensor([[[1.0], [3.0], [-2.0]]])  # three points, one channel
    index = torch.tensor([[0, 0, 2]])  # two points in cell 0, one in cell 2, cell 1 empty
    assert scatter_cells(values, index, 3, "mean")[0, 0].tolist() == [2.0, 0.0, -2.0]
    assert scatter_cells(values, index, 3, "amax")[0, 0].tolist() == [3.0, 0.0, -2.0]


def test_local_pooling_equals_brute_force() -> None:
    torch.manual_seed(0)
    enc = LocalPoolPointnet(c_dim=4, hidden=6, reso=4, unet_depth=2, unet_start=4)
    points = torch.rand(2, 30, 3) * 2.2 - 1.1
    net = torch.randn(2, 30, 6)
    index = {key: cell_index(points, key, 4) for key in PLANES}
    pooled = enc.pool_local(index, net)
    for b in range(2):
        for n in range(30):
            expected = sum(
                net[b][index[key][b] == index[key][b, n]].max(dim=0).values for key in PLANES
            )
            assert torch.allclose(pooled[b, n], expected)


def test_the_decoder_reads_a_plane_bilinearly() -> None:
    # A plane whose value is its column index: at plane coordinate u it reads u (R - 1)
    # (align_corners: the box's edges are the first and last cells' centres).
    reso = 8
    ramp = torch.arange(reso, dtype=torch.float32).repeat(reso, 1)[None, None]  # (1, 1, R, R)
    planes = {"xy": ramp}
    points = torch.tensor([[[-1.1, 0.0, 0.0], [0.0, 0.3, 0.0], [0.55, -0.2, 0.9]]])
    u = plane_coordinates(points, "xy")[0, :, 0]
    read = LocalDecoder.sample(planes, points)[0, :, 0]
    assert torch.allclose(read, u * (reso - 1), atol=1e-4)


def test_unet_keeps_the_resolution_and_the_options_check_it() -> None:
    unet = UNet(5, 7, depth=3, start=4)
    assert unet(torch.randn(2, 5, 16, 16)).shape == (2, 7, 16, 16)
    with pytest.raises(ConfigError, match="divisible by 2\\^\\(unet_depth - 1\\) = 8"):
        ConvONet(ConvONetOptions(plane_resolution=36, unet_depth=4))
    with pytest.raises(ConfigError, match="queries must be one of"):
        ConvONet(ConvONetOptions(queries="random"))


@pytest.mark.slow  # trains for ~30 s
def test_convonet_learns_the_occupancy_of_spheres() -> None:
    torch.manual_seed(0)
    options = ConvONetOptions(c_dim=16, hidden=32, plane_resolution=16, unet_depth=2, unet_start=16)
    module = ConvONetModule(options)
    opt = torch.optim.Adam(module.parameters(), lr=3e-3)

    def spheres(b: int, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        radius = torch.rand(b, 1, 1, generator=gen) * 0.4 + 0.4
        centre = (torch.rand(b, 1, 3, generator=gen) - 0.5) * 0.4
        pts = torch.randn(b, 200, 3, generator=gen)
        pts = pts / pts.norm(dim=-1, keepdim=True) * radius + centre
        queries = (torch.rand(b, 512, 3, generator=gen) * 2 - 1) * 1.1
        inside = ((queries - centre).norm(dim=-1, keepdim=True) < radius).float()
        return pts, torch.cat([queries, inside], dim=-1)

    gen = torch.Generator().manual_seed(1)
    for _ in range(80):
        loss = module.loss(*spheres(4, gen))
        opt.zero_grad()
        loss.backward()
        opt.step()
    pts, occ = spheres(8, torch.Generator().manual_seed(99))  # spheres never trained on
    with torch.no_grad():
        predicted = module.decoder(occ[..., :3], module.encoder(pts)) > 0
    truth = occ[..., 3] > 0.5
    iou = (predicted & truth).sum() / (predicted | truth).sum()
    assert iou > 0.75, float(iou)
