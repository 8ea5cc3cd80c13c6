"""The MOST network: polar → Cartesian BEV resampling, shapes, the shared DS-Net backbone."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from dsnet_core.model.cylinder import CylinderGrid
from dsnet_core.model.network import DSNet
from dsnet_core.model.presets import PRESETS
from dsnet_core.model.sparse_conv import SparseTensor
from dsnet_core.most.bev import (
    flatten_height,
    level_shape,
    polar_sampling_grid,
    polar_to_cartesian,
    sample_bev,
)
from dsnet_core.most.config import BevGrid, MostConfig
from dsnet_core.most.network import MostNet, load_backbone_from

GRID = CylinderGrid(size=(48, 72, 8), min_bound=(0.0, -math.pi, -3.0), max_bound=(24.0, math.pi, 1.5))
BB = replace(PRESETS["tiny"], width=2, point_mlp=(8, 8), compress=4, grid=GRID)
CFG = MostConfig(backbone=BB, bev=BevGrid(half_extent=12.0, cell=0.5), bev_channels=8, mem_widths=(16, 16, 8))


def test_level_shapes_follow_the_unet_strides():
    assert level_shape((480, 360, 32), 2) == (120, 90, 8)
    assert level_shape((480, 360, 32), 4) == (30, 23, 8)


@pytest.mark.parametrize("level", [0, 2])
def test_polar_map_resampled_at_cartesian_cells(level):
    """A polar map holding each cell's own (ρ, cos φ, sin φ, φ) comes back as the Cartesian cell's
    (ρ and φ exactly, being linear in the cell index; the direction within the chord error of
    bilinear interpolation, also across the ±π seam)."""
    bev = BevGrid(half_extent=20.0, cell=0.5)
    nr, nphi, _ = level_shape(GRID.size, level)
    s = 2**level
    (r0, p0, _), (dr, dp, _) = GRID.min_bound, GRID.interval
    rho = r0 + (torch.arange(nr, dtype=torch.float64) * s + 0.5) * dr
    phi = p0 + (torch.arange(nphi, dtype=torch.float64) * s + 0.5) * dp
    polar = torch.stack(
        [
            rho[:, None].expand(nr, nphi),
            torch.cos(phi).expand(nr, nphi),
            torch.sin(phi).expand(nr, nphi),
            phi.expand(nr, nphi),
        ]
    )[None]
    out = polar_to_cartesian(polar, polar_sampling_grid(GRID, level, bev).double())[0]
    c = (torch.arange(bev.size, dtype=torch.float64) + 0.5) * bev.cell - bev.half_extent
    x, y = torch.meshgrid(c, c, indexing="ij")
    r = torch.sqrt(x * x + y * y)
    ok = (r > r0 + s * dr) & (r < rho[-1])  # inside the covered ring
    assert torch.allclose(out[0][ok], r[ok], atol=1e-6)  # ρ is linear in the cell index
    true = torch.atan2(y, x)
    inner = ok & (true.abs() < phi[-1])  # not between the last and the first cell
    assert torch.allclose(out[3][inner], true[inner], atol=1e-5)
    err = torch.remainder(torch.atan2(out[2], out[1]) - true + math.pi, 2 * math.pi) - math.pi
    assert err[ok].abs().max() < (s * dp) ** 2 / 4  # the chord error, seam included
    # sampling the Cartesian map at cell centres gives the cells back
    xy = torch.stack([x[ok], y[ok]], 1)
    np.testing.assert_allclose(sample_bev(out, xy, bev)[:, 0], r[ok], atol=1e-6)


def test_flatten_height_folds_z_into_channels():
    feats = torch.arange(6, dtype=torch.float32).view(3, 2)
    coords = torch.tensor([[0, 1, 2, 0], [0, 1, 2, 3], [1, 0, 0, 1]])
    dense = flatten_height(SparseTensor(feats, coords, (2, 3, 4), 2))
    assert dense.shape == (2, 8, 2, 3)  # C·Z channels, channel-major
    assert dense[0, 0 * 4 + 0, 1, 2] == 0 and dense[0, 1 * 4 + 0, 1, 2] == 1
    assert dense[0, 0 * 4 + 3, 1, 2] == 2 and dense[1, 1 * 4 + 1, 0, 0] == 5
    assert dense.abs().sum() == feats.sum()


def test_forward_shapes_and_gradients():
    torch.manual_seed(0)
    net = MostNet(CFG)
    pts = torch.rand(500, 5) * torch.tensor([30.0, 30.0, 3.0, 1.0, 0.2]) - torch.tensor(
        [15.0, 15.0, 2.0, 0.0, 0.0]
    )
    out = net([pts, pts[:200]])
    s = CFG.bev.size
    assert out.logits.shape == (700, 20) and out.point_features.shape == (700, 8)
    assert out.bev.features.shape == (2, 8, s, s) and out.bev.heatmap.shape == (2, 8, s, s)
    assert out.bev.regress.shape == (2, 8, s, s) and out.sizes == [500, 200]
    (out.logits.sum() + out.bev.heatmap.sum() + out.bev.regress.sum()).backward()
    assert net.point_encoder.mlp[1].weight.grad[:, 9].abs().sum() > 0  # the time input is used


def test_backbone_from_dsnet_gives_dsnet_semantics():
    torch.manual_seed(1)
    ds = DSNet(BB).eval()
    for m in ds.modules():  # non-trivial BN statistics
        if isinstance(m, torch.nn.BatchNorm1d):
            m.running_mean.uniform_(-0.5, 0.5)
            m.running_var.uniform_(0.5, 2.0)
    net = MostNet(CFG)
    copied = load_backbone_from(net, ds.state_dict())
    assert len(copied) == len([k for k in ds.state_dict() if not k.startswith("ins_head.")])
    net.eval()
    pts = torch.rand(400, 4) * 20 - 10
    with torch.no_grad():
        ref = ds([pts], instance=False).logits
        cur = net([torch.cat([pts, torch.zeros(400, 1)], 1)]).logits
        past = net([torch.cat([pts, torch.full((400, 1), 0.2)], 1)]).logits
    torch.testing.assert_close(cur, ref)
    torch.testing.assert_close(past, ref)  # the time column starts at weight 0
