"""The eval-mode fast paths of the point MLPs (batch norms folded, chunked) equal the modules."""

import torch
from torch import nn

from dsnet_core.model import heads
from dsnet_core.model.heads import InstanceHead, PointEncoder, fold_mlp
from dsnet_core.model.sparse_conv import SparseTensor


def _randomise_bn(module: nn.Module, seed: int) -> None:
    g = torch.Generator().manual_seed(seed)
    for m in module.modules():
        if isinstance(m, nn.BatchNorm1d):
            n = m.num_features
            m.running_mean.copy_(torch.randn(n, generator=g))
            m.running_var.copy_(torch.rand(n, generator=g) * 2 + 0.2)
            m.weight.data.copy_(torch.randn(n, generator=g))
            m.bias.data.copy_(torch.randn(n, generator=g))


def test_point_encoder_fast_path_equals_the_module(monkeypatch):
    monkeypatch.setattr(heads, "POINT_CHUNK", 64)  # several chunks and a ragged last one
    torch.manual_seed(0)
    enc = PointEncoder(9, (16, 32, 8), 5).eval()
    _randomise_bn(enc, 1)
    feats = torch.randn(300, 9)
    ptv = torch.randint(0, 40, (300,))
    ptv[:40] = torch.arange(40)
    slow = enc(feats, ptv, 40)  # parameters require grad: the module path
    with torch.inference_mode():
        fast = enc(feats, ptv, 40)
    torch.testing.assert_close(fast, slow, atol=1e-5, rtol=1e-5)
    assert slow.requires_grad and not fast.requires_grad


def test_fold_mlp_layout():
    mlp = nn.Sequential(nn.BatchNorm1d(3), nn.Linear(3, 4), nn.BatchNorm1d(4), nn.ReLU(), nn.Linear(4, 2))
    layers = fold_mlp(mlp)
    assert [(tuple(w.shape), tuple(b.shape), r) for w, b, r in layers] == [
        ((3, 4), (4,), True),
        ((4, 2), (2,), False),
    ]


def test_instance_head_fast_path_equals_the_module(monkeypatch):
    monkeypatch.setattr(heads, "POINT_CHUNK", 50)
    torch.manual_seed(2)
    head = InstanceHead(8, ins_dim=6).eval()
    _randomise_bn(head, 3)
    g = torch.Generator().manual_seed(4)
    keys = torch.sort(torch.randperm(6 * 6 * 6, generator=g)[:60]).values
    coords = torch.stack([keys * 0, keys // 36, (keys // 6) % 6, keys % 6], dim=1)
    x = SparseTensor(torch.randn(60, 8, generator=g), coords, (6, 6, 6), 1)
    ptv = torch.randint(0, 60, (230,), generator=g)
    xyz = torch.randn(230, 3, generator=g)
    slow = head(x, ptv, xyz)
    with torch.inference_mode():
        fast = head(SparseTensor(x.features, coords, (6, 6, 6), 1), ptv, xyz)
    for a, b in zip(fast, slow, strict=True):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)


def test_conv_bn_act_fast_path_equals_the_modules():
    from dsnet_core.model.backbone import ConvBNAct

    g = torch.Generator().manual_seed(7)
    keys = torch.sort(torch.randperm(6 * 6 * 6, generator=g)[:80]).values
    coords = torch.stack([keys * 0, keys // 36, (keys // 6) % 6, keys % 6], dim=1)
    feats = torch.randn(80, 5, generator=g)
    for bn_first, act in ((False, None), (True, None), (True, nn.Sigmoid())):
        torch.manual_seed(1)
        layer = ConvBNAct(5, 6, 3, act=act, bn_first=bn_first).eval()
        _randomise_bn(layer, 8)
        slow = layer(SparseTensor(feats, coords, (6, 6, 6), 1)).features  # parameters require grad
        with torch.inference_mode():
            fast = layer(SparseTensor(feats, coords, (6, 6, 6), 1)).features
        torch.testing.assert_close(fast, slow, atol=1e-5, rtol=1e-5)
