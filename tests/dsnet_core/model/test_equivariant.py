"""The C_n-equivariant network: exact lifting on the cylinder grid, invariant semantics and
equivariant offsets under yaw rotations by multiples of 360°/n, refusals, and the eq. 9 loss."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from dsnet_core.errors import ConfigError
from dsnet_core.instance.clustering import DBSCANConfig, get_clusterer
from dsnet_core.model.cylinder import CylinderGrid
from dsnet_core.model.equivariant import (
    check_equivariant_grid,
    equivariant_offset_loss,
    lift,
    nearest_anchor,
    rotate_xy,
)
from dsnet_core.model.network import DSNet
from tests.dsnet_core.model.rotation_helpers import (
    CFG,
    GRID,
    assert_same_classes,
    away_from_cell_boundaries,
    calibrated,
    rotate64,
)


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _net(n: int, pooling: str = "mean", seed: int = 0, **kw) -> DSNet:
    torch.manual_seed(seed)
    cfg = dataclasses.replace(CFG, equivariant=n, pooling=pooling, **kw)
    pts = torch.from_numpy(away_from_cell_boundaries(1500, seed=10))
    priors = [torch.rand(1500, cfg.prior_channels)] if cfg.prior_channels else None
    return calibrated(DSNet(cfg), [pts], priors=priors)


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Two labelings define the same partition (ids may differ)."""
    pairs = np.unique(np.stack([a, b], 1), axis=0)
    return len(pairs) == len(np.unique(a)) == len(np.unique(b))


def test_refuses_grids_where_a_rotation_is_not_a_shift():
    with pytest.raises(ConfigError, match="n must divide the grid's 36 azimuth cells"):
        check_equivariant_grid(GRID, 8)
    half = CylinderGrid(size=(24, 36, 8), min_bound=(1.0, 0.0, -2.0), max_bound=(25.0, math.pi, 2.0))
    with pytest.raises(ConfigError, match=r"azimuth cells that tile the circle"):
        check_equivariant_grid(half, 4)

    @dataclasses.dataclass(frozen=True)
    class ReferenceGrid(CylinderGrid):  # the reference's (max − min)/(n − 1) cells
        convention: str = "reference"

        @property
        def interval(self):
            return tuple(
                (hi - lo) / (n - 1)
                for lo, hi, n in zip(self.min_bound, self.max_bound, self.size, strict=True)
            )

    with pytest.raises(ConfigError, match="convention reference"):
        check_equivariant_grid(
            ReferenceGrid(size=GRID.size, min_bound=GRID.min_bound, max_bound=GRID.max_bound), 4
        )
    with pytest.raises(ConfigError, match="n must divide"):
        DSNet(dataclasses.replace(CFG, equivariant=5))
    check_equivariant_grid(GRID, 1)  # the plain network runs on any grid


def test_lifting_is_an_azimuth_shift():
    pts = torch.from_numpy(away_from_cell_boundaries(300, seed=3))
    lifted = lift([pts], GRID, 4)
    cells = lifted.vox.point_cells.view(4, 300, 3)
    for j in range(4):
        assert torch.equal(cells[j, :, [0, 2]], cells[0, :, [0, 2]])
        assert torch.equal(cells[j, :, 1], torch.remainder(cells[0, :, 1] - 9 * j, 36))
        # copy j is the cloud rotated by -2πj/4, binned as the plain voxeliser would
        rotated = torch.from_numpy(rotate64(pts.numpy(), -2 * math.pi * j / 4))
        from dsnet_core.model.cylinder import cylinder_features

        plain_cells, plain_feats = cylinder_features(rotated, GRID)
        assert torch.equal(plain_cells, cells[j])
        torch.testing.assert_close(lifted.vox.features.view(4, 300, 9)[j], plain_feats, atol=2e-5, rtol=0)


@pytest.mark.parametrize("n,pooling", [(2, "mean"), (3, "max"), (4, "mean"), (4, "max")])
def test_rotating_the_input_rotates_the_outputs(n, pooling):
    net = _net(n, pooling)
    pts = away_from_cell_boundaries(1200, seed=4).astype(np.float64)
    clusterer = get_clusterer(DBSCANConfig(eps=0.6, min_samples=3))
    with torch.inference_mode():
        ref = net([torch.from_numpy(pts)])
    assert ref.logits.std() > 0.05 and ref.offsets.std() > 0.05  # not a trivially constant net
    ref_ids = clusterer.cluster(pts[:, :3], pts[:, :3] + ref.offsets.double().numpy(), None)
    assert len(np.unique(ref_ids)) > 5
    for j in range(1, n):
        angle = 2 * math.pi * j / n
        rot = rotate64(pts, angle, dtype=np.float64)
        with torch.inference_mode():
            out = net([torch.from_numpy(rot)])
        assert_same_classes(out.logits, ref.logits, atol=1e-5)
        expect = rotate_xy(ref.offsets.double(), torch.tensor(angle)).float()
        torch.testing.assert_close(out.offsets, expect, atol=1e-5, rtol=0)
        torch.testing.assert_close(out.features, ref.features, atol=1e-5, rtol=0)
        ids = clusterer.cluster(rot[:, :3], rot[:, :3] + out.offsets.double().numpy(), None)
        assert same_partition(ids, ref_ids)


def test_plain_network_is_not_equivariant():
    """The check has teeth: the plain network's outputs change under the same rotation."""
    net = _net(1)
    pts = away_from_cell_boundaries(1200, seed=4)
    with torch.inference_mode():
        a = net([torch.from_numpy(pts)])
        b = net([torch.from_numpy(rotate64(pts, math.pi / 2))])
    assert (a.logits - b.logits).abs().max() > 1e-2


def test_prior_and_batches_compose_with_the_lifting():
    net = _net(3, prior_channels=5, semantic_head=False)
    g = torch.Generator().manual_seed(0)
    clouds = [torch.from_numpy(away_from_cell_boundaries(n, seed=s)) for n, s in ((400, 5), (300, 6))]
    priors = [torch.rand(len(c), 5, generator=g) for c in clouds]
    with torch.inference_mode():
        both = net(clouds, priors=priors)
        alone = net([clouds[1]], priors=[priors[1]])
        rot = net([torch.from_numpy(rotate64(clouds[1].numpy(), 2 * math.pi / 3))], priors=[priors[1]])
    assert both.logits is None and both.offsets.shape == (700, 3) and both.anchor_scores.shape == (700, 3)
    torch.testing.assert_close(alone.offsets, both.offsets[400:], atol=1e-5, rtol=0)
    torch.testing.assert_close(
        rot.offsets, rotate_xy(alone.offsets, torch.tensor(2 * math.pi / 3)), atol=1e-5, rtol=0
    )


def test_nearest_anchor_and_loss():
    v = torch.tensor([[1.0, 0.0, 0], [0.0, 1.0, 0], [-1.0, 0.1, 0], [0.2, -1.0, 0], [1.0, -0.2, 0]])
    assert nearest_anchor(v, 4).tolist() == [0, 1, 2, 3, 0]
    xyz = torch.zeros(5, 3)
    valid = torch.ones(5, dtype=torch.bool)
    anchor = nearest_anchor(v, 4)
    local = rotate_xy(v, -torch.arange(4, dtype=torch.float64)[anchor] * math.pi / 2)
    offsets = torch.zeros(5, 4, 3)
    offsets[torch.arange(5), anchor] = local
    sharp = torch.full((5, 4), -50.0)
    sharp[torch.arange(5), anchor] = 50.0
    assert float(equivariant_offset_loss(sharp, offsets, xyz, v, valid)) < 1e-6
    assert float(equivariant_offset_loss(-sharp, offsets, xyz, v, valid)) > 50
    # in the selected anchor's frame the target's yaw is within ±π/n
    assert (torch.atan2(local[:, 1], local[:, 0]).abs() <= math.pi / 4 + 1e-6).all()


def test_trainable_end_to_end():
    net = _net(4)
    net.train()
    pts = torch.from_numpy(away_from_cell_boundaries(600, seed=7))
    out = net([pts])
    centres = pts[:, :3] + torch.randn(600, 3)
    valid = torch.rand(600) < 0.5
    loss = out.logits.square().mean() + equivariant_offset_loss(
        out.anchor_scores, out.anchor_offsets, pts[:, :3], centres, valid
    )
    loss.backward()
    missing = [n for n, p in net.named_parameters() if p.grad is None or not torch.isfinite(p.grad).all()]
    assert missing == []


def test_a_lifted_plain_model_shares_its_weights_and_is_equivariant():
    """``lift_model``: the plain network's weights on every rotated copy (its semantics become their
    mean), a fresh anchor scorer, and the lifted network is equivariant as one trained lifted."""
    from dsnet_core.model.network import lift_model

    plain = _net(1)
    lifted = lift_model(plain, 4).eval()
    assert lifted.config.equivariant == 4
    own = lifted.state_dict()
    for k, v in plain.state_dict().items():
        assert torch.equal(own[k], v), k
    assert {k for k in own if k not in plain.state_dict()} == {k for k in own if k.startswith("anchor_head.")}
    pts = away_from_cell_boundaries(1200, seed=4).astype(np.float64)
    with torch.inference_mode():
        ref = lifted([torch.from_numpy(pts)])
        rot = lifted([torch.from_numpy(rotate64(pts, math.pi / 2, dtype=np.float64))])
        copies = [
            plain([torch.from_numpy(rotate64(pts, -math.pi / 2 * j, dtype=np.float64))]) for j in range(4)
        ]
    assert_same_classes(rot.logits, ref.logits, atol=1e-5)
    mean = torch.stack([c.logits for c in copies]).mean(0)  # invariant pooling = the rotations' mean
    torch.testing.assert_close(ref.logits, mean, atol=1e-4, rtol=0)
    with pytest.raises(ConfigError, match="already C_4"):
        lift_model(lifted, 2)
