import math

import pytest
import torch

from dsnet_core.model.cylinder import CylinderGrid, cylinder_features, voxelize

GRID = CylinderGrid(size=(8, 6, 4), min_bound=(3.0, -math.pi, -3.0), max_bound=(50.0, math.pi, 1.5))


def test_default_grid_is_the_paper_grid():
    g = CylinderGrid()
    assert g.size == (480, 360, 32)
    assert g.min_bound == (3.0, -math.pi, -3.0) and g.max_bound == (50.0, math.pi, 1.5)
    assert g.interval[0] == pytest.approx(47.0 / 480)
    assert CylinderGrid.from_dict(g.to_dict()) == g


def test_bad_grid_rejected():
    with pytest.raises(ValueError, match="min < max"):
        CylinderGrid(size=(2, 2, 2), min_bound=(1, 0, 0), max_bound=(1, 1, 1))


def test_features_and_cells_by_hand():
    # rho = 5, phi = 0, z = -0.75 -> cell (floor(2/5.875)=0, floor(pi/(2pi/6))=3, floor(2.25/1.125)=2)
    pts = torch.tensor([[5.0, 0.0, -0.75, 0.25]])
    cells, feats = cylinder_features(pts, GRID)
    assert cells.tolist() == [[0, 3, 2]]
    step = GRID.interval
    centre = [3.0 + 0.5 * step[0], -math.pi + 3.5 * step[1], -3.0 + 2.5 * step[2]]
    expect = [5.0 - centre[0], 0.0 - centre[1], -0.75 - centre[2], 5.0, 0.0, -0.75, 5.0, 0.0, 0.25]
    assert feats.shape == (1, 9) and feats.dtype == torch.float32
    torch.testing.assert_close(feats[0], torch.tensor(expect), atol=1e-5, rtol=0)


def test_out_of_range_points_are_clamped_not_dropped():
    pts = torch.tensor([[0.5, 0.0, -10.0, 0.0], [200.0, 0.0, 9.0, 0.0], [-1.0, -1e-7, 0.0, 0.0]])
    cells, _ = cylinder_features(pts, GRID)
    assert cells.tolist()[0] == [0, 3, 0]
    assert cells.tolist()[1] == [7, 3, 3]
    assert 0 <= cells[2, 1] < 6  # phi = -pi edge stays in range
    vox = voxelize([pts], GRID)
    assert vox.point_to_voxel.shape == (3,)


def test_maps_round_trip():
    g = torch.Generator().manual_seed(0)
    clouds = [torch.randn(200, 4, generator=g) * 20, torch.randn(150, 4, generator=g) * 20]
    vox = voxelize(clouds, GRID)
    n = 350
    assert vox.features.shape == (n, 9) and vox.point_cells.shape == (n, 3)
    # every point's voxel has the point's batch and cell
    batch = torch.cat([torch.zeros(200, dtype=torch.int64), torch.ones(150, dtype=torch.int64)])
    assert torch.equal(vox.coords[vox.point_to_voxel, 0], batch)
    assert torch.equal(vox.coords[vox.point_to_voxel, 1:], vox.point_cells)
    # voxels are unique and each owns at least one point
    assert torch.unique(vox.coords, dim=0).shape[0] == vox.coords.shape[0]
    assert torch.equal(torch.unique(vox.point_to_voxel), torch.arange(vox.coords.shape[0]))


def test_outside_grid_counts_exactly_the_points_the_model_clamps():
    """``bounds.outside_grid`` (numpy, used by ingest) marks the points whose polar coordinates
    ``cylinder_features`` clamps, on random points around and across every bound."""
    import numpy as np

    from dsnet_core.model.bounds import outside_grid

    rng = np.random.default_rng(0)
    pts = np.zeros((20000, 4), dtype=np.float32)
    rho = rng.uniform(0, 60, len(pts))
    phi = rng.uniform(-math.pi, math.pi, len(pts))
    pts[:, 0], pts[:, 1] = rho * np.cos(phi), rho * np.sin(phi)
    pts[:, 2] = rng.uniform(-4, 2.5, len(pts))
    pts[:5, :3] = [[3.0, 0, 0], [50.0, 0, 0], [10.0, 0, -3.0], [10.0, 0, 1.5], [-10.0, 0, 0]]  # on bounds
    x, y, z = (torch.from_numpy(pts[:, i]) for i in range(3))
    pol = torch.stack([torch.sqrt(x * x + y * y), torch.atan2(y, x), z], dim=1)
    lo, hi = (
        torch.tensor(GRID.min_bound, dtype=torch.float32),
        torch.tensor(GRID.max_bound, dtype=torch.float32),
    )
    clamped = (torch.minimum(torch.maximum(pol, lo), hi) != pol).any(dim=1).numpy()
    got = outside_grid(pts, GRID.min_bound, GRID.max_bound)
    assert np.array_equal(got, clamped) and 0 < got.sum() < len(pts) and not got[:5].any()
