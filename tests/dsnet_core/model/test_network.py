import math

import pytest
import torch

from dsnet_core.errors import ConfigError
from dsnet_core.model.cylinder import CylinderGrid
from dsnet_core.model.network import DSNet, count_parameters
from dsnet_core.model.presets import PRESETS, ModelConfig, get_preset

SMALL_GRID = CylinderGrid(size=(24, 20, 8), min_bound=(0.0, -math.pi, -2.0), max_bound=(12.0, math.pi, 1.0))


def test_paper_preset_parameter_count():
    m = DSNet(get_preset("paper"))
    # docs/algorithm.md: ≈55.7 M in the backbone, ≈56.5 M in the whole model
    assert count_parameters(m.backbone) == 55_671_424
    assert count_parameters(m) == 56_521_561
    assert m.backbone.out_channels == 128
    convs = [c.conv for c in m.ins_head.convs]
    assert [(c.in_channels, c.out_channels) for c in convs] == [(128, 128), (128, 64), (64, 32)]
    assert m.ins_head.offset[0].in_features == 35 and m.ins_head.offset[-1].out_features == 3


def test_unknown_preset():
    with pytest.raises(ConfigError, match="unknown model preset 'huge'"):
        get_preset("huge")


def test_config_round_trip():
    cfg = ModelConfig(width=4, grid=SMALL_GRID)
    assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ConfigError):
        ModelConfig.from_dict({"width": 4})


def test_forward_shapes_and_point_takes_its_voxel_logits():
    torch.manual_seed(0)
    cfg = ModelConfig(width=2, point_mlp=(8, 8), compress=4, ins_dim=6, grid=SMALL_GRID)
    net = DSNet(cfg).eval()
    g = torch.Generator().manual_seed(1)
    clouds = [torch.randn(300, 4, generator=g) * 4, torch.randn(200, 4, generator=g) * 4]
    with torch.inference_mode():
        out = net(clouds)
    assert out.logits.shape == (500, 20) and out.offsets.shape == (500, 3) and out.features.shape == (500, 6)
    assert torch.equal(out.logits, out.voxel_logits[out.point_to_voxel])
    assert out.sizes == [300, 200]
    # batching is per sample: the second cloud alone gives the same outputs (eval-mode BN)
    with torch.inference_mode():
        alone = net([clouds[1]])
    torch.testing.assert_close(alone.logits, out.logits[300:], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(alone.offsets, out.offsets[300:], atol=1e-5, rtol=1e-5)


def test_gradients_reach_every_parameter():
    torch.manual_seed(0)
    net = DSNet(ModelConfig(width=2, point_mlp=(8, 8), compress=4, ins_dim=6, grid=SMALL_GRID))
    clouds = [torch.randn(400, 4) * 4]
    out = net(clouds)
    (out.logits.square().mean() + out.offsets.square().mean()).backward()
    missing = [n for n, p in net.named_parameters() if p.grad is None or not torch.isfinite(p.grad).all()]
    assert missing == []


def test_presets_exist():
    assert set(PRESETS) == {"tiny", "small", "paper", "reference", "cylinder3d"}
    assert PRESETS["paper"].width == 32 and PRESETS["paper"].grid == CylinderGrid()
