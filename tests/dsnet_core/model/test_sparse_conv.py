"""Sparse convolution against dense conv3d / conv_transpose3d in float64 (tolerance 1e-10)."""

import pytest
import torch
import torch.nn.functional as F

from dsnet_core.model.sparse_conv import (
    SparseConv3d,
    SparseInverseConv3d,
    SparseTensor,
    SubMConv3d,
)

TOL = dict(atol=1e-10, rtol=1e-10)


def random_sites(shape, batch, n, seed):
    g = torch.Generator().manual_seed(seed)
    total = batch * shape[0] * shape[1] * shape[2]
    keys = torch.sort(torch.randperm(total, generator=g)[:n]).values
    s0, s1, s2 = shape
    coords = torch.stack(
        [keys // (s0 * s1 * s2), (keys // (s1 * s2)) % s0, (keys // s2) % s1, keys % s2], dim=1
    )
    return coords


def to_dense(feats, coords, shape, batch):
    """Differentiable scatter of sparse features into a dense (B, C, *shape) grid."""
    dense = feats.new_zeros((batch, *shape, feats.shape[1]))
    dense = dense.index_put((coords[:, 0], coords[:, 1], coords[:, 2], coords[:, 3]), feats)
    return dense.permute(0, 4, 1, 2, 3)


def gather(dense, coords):
    return dense.permute(0, 2, 3, 4, 1)[coords[:, 0], coords[:, 1], coords[:, 2], coords[:, 3]]


def dense_weight(layer):
    kx, ky, kz = layer.kernel_size
    return layer.weight.reshape(kx, ky, kz, layer.in_channels, layer.out_channels).permute(4, 3, 0, 1, 2)


def make(shape, batch, n, cin, seed):
    coords = random_sites(shape, batch, n, seed)
    g = torch.Generator().manual_seed(seed + 1)
    feats = torch.randn(coords.shape[0], cin, generator=g, dtype=torch.float64, requires_grad=True)
    return SparseTensor(feats, coords, shape, batch)


@pytest.mark.parametrize("kernel", [(3, 3, 3), (1, 3, 3), (3, 1, 3), (3, 3, 1), (3, 1, 1), (1, 1, 1)])
@pytest.mark.parametrize("bias", [False, True])
def test_submanifold_matches_dense(kernel, bias):
    shape, batch = (6, 5, 4), 2
    x = make(shape, batch, 70, 3, seed=sum(kernel))
    torch.manual_seed(1)
    layer = SubMConv3d(3, 4, kernel, bias=bias).double()
    y = layer(x)
    assert torch.equal(y.coords, x.coords)
    pad = tuple(k // 2 for k in kernel)
    dense_in = to_dense(x.features, x.coords, shape, batch)
    ref = gather(F.conv3d(dense_in, dense_weight(layer), layer.bias, padding=pad), x.coords)
    torch.testing.assert_close(y.features, ref, **TOL)
    # backward
    g = torch.randn_like(ref)
    gx, gw = torch.autograd.grad((y.features * g).sum(), (x.features, layer.weight))
    rx, rw = torch.autograd.grad((ref * g).sum(), (x.features, layer.weight))
    torch.testing.assert_close(gx, rx, **TOL)
    torch.testing.assert_close(gw, rw, **TOL)


@pytest.mark.parametrize("stride", [(2, 2, 2), (2, 2, 1)])
@pytest.mark.parametrize("shape", [(6, 5, 4), (7, 6, 3)])
def test_strided_and_inverse_match_dense(stride, shape):
    batch = 2
    x = make(shape, batch, 60, 3, seed=7)
    torch.manual_seed(2)
    down = SparseConv3d(3, 5, 3, stride=stride, padding=1, indice_key="d").double()
    up = SparseInverseConv3d(5, 2, 3, indice_key="d").double()
    y = down(x)
    dense_in = to_dense(x.features, x.coords, shape, batch)
    dense_out = F.conv3d(dense_in, dense_weight(down), stride=stride, padding=1)
    # active outputs are exactly the sites that some input reaches
    ind = F.conv3d(
        to_dense(torch.ones(x.coords.shape[0], 1, dtype=torch.float64), x.coords, shape, batch),
        torch.ones(1, 1, 3, 3, 3, dtype=torch.float64),
        stride=stride,
        padding=1,
    )
    expect_sites = torch.nonzero(ind[:, 0] > 0)
    assert y.shape == tuple(dense_out.shape[2:])
    assert torch.equal(y.coords, expect_sites)
    torch.testing.assert_close(y.features, gather(dense_out, y.coords), **TOL)
    assert y.level == tuple(stride)

    z = up(y)
    assert torch.equal(z.coords, x.coords) and z.shape == shape
    out_pad = tuple(n - ((o - 1) * s - 2 + 3) for n, o, s in zip(shape, y.shape, stride, strict=True))
    wt = up.weight.reshape(3, 3, 3, 5, 2).permute(3, 4, 0, 1, 2)
    dense_up = F.conv_transpose3d(dense_out, wt, stride=stride, padding=1, output_padding=out_pad)
    ref = gather(dense_up, x.coords)
    torch.testing.assert_close(z.features, ref, **TOL)

    g = torch.randn_like(ref)
    params = (x.features, down.weight, up.weight)
    got = torch.autograd.grad((z.features * g).sum(), params)
    exp = torch.autograd.grad((ref * g).sum(), params)
    for a, b in zip(got, exp, strict=True):
        torch.testing.assert_close(a, b, **TOL)


def test_empty_input():
    x = SparseTensor(
        torch.zeros(0, 3, dtype=torch.float64, requires_grad=True),
        torch.zeros(0, 4, dtype=torch.int64),
        (4, 4, 4),
        1,
    )
    sub = SubMConv3d(3, 2, (1, 3, 3)).double()
    down = SparseConv3d(3, 2, indice_key="e").double()
    up = SparseInverseConv3d(2, 2, indice_key="e").double()
    y = sub(x)
    assert y.features.shape == (0, 2)
    d = down(x)
    assert d.features.shape == (0, 2) and d.coords.shape == (0, 4)
    u = up(d)
    assert u.features.shape == (0, 2)
    (gw,) = torch.autograd.grad(y.features.sum() + u.features.sum(), (sub.weight,))
    assert torch.equal(gw, torch.zeros_like(gw))


def test_tables_cached_per_level_and_kernel():
    x = make((6, 5, 4), 1, 40, 2, seed=3)
    a, b, c = SubMConv3d(2, 2, (1, 3, 3)).double(), SubMConv3d(2, 2, (1, 3, 3)).double(), SubMConv3d(2, 2, 3)
    y = b(a(x))
    assert len(x.cache.subm) == 1 and y.cache is x.cache
    c.double()(y)
    assert len(x.cache.subm) == 2


def test_inverse_without_strided_layer_is_a_clear_error():
    x = make((4, 4, 4), 1, 10, 2, seed=4)
    with pytest.raises(KeyError, match="no strided layer 'zz'"):
        SparseInverseConv3d(2, 2, indice_key="zz").double()(x)


@pytest.mark.parametrize("cout", [4, 5])
def test_small_chunks_give_the_same_values_and_gradients(monkeypatch, cout):
    """The CPU path gathers and multiplies in cache-sized chunks; chunks of 16 rows (many per
    segment, ragged ends, the fused-row GEMM for 4 outputs) give what whole segments give."""
    from dsnet_core.model import sparse_conv as sc

    def run():
        x = make((10, 9, 8), 2, 900, 3, seed=11)
        torch.manual_seed(5)
        layers = [
            SubMConv3d(3, cout, 3).double(),
            SparseConv3d(cout, 6, 3, stride=2, padding=1, indice_key="c").double(),
            SubMConv3d(6, 6, (1, 3, 3)).double(),
            SparseInverseConv3d(6, cout, indice_key="c").double(),
        ]
        y = x
        for layer in layers:
            y = layer(y)
        params = [x.features] + [layer.weight for layer in layers]
        g = torch.randn(y.features.shape, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
        return [y.features, *torch.autograd.grad((y.features * g).sum(), params)]

    whole = run()
    monkeypatch.setattr(sc, "CHUNK_BYTES", 64)
    assert sc._chunk_rows(6) == 16
    for a, b in zip(run(), whole, strict=True):
        torch.testing.assert_close(a, b, **TOL)


def test_batched_group_path_gives_the_same_values_and_gradients(monkeypatch):
    """The CUDA layout (one gather and one batched GEMM per group) run on CPU tensors."""
    from dsnet_core.model import sparse_conv as sc

    x = make((6, 5, 4), 2, 70, 3, seed=9)
    torch.manual_seed(3)
    layers = [
        SubMConv3d(3, 4, 3).double(),
        SparseConv3d(4, 5, 3, stride=2, padding=1, indice_key="b").double(),
        SparseInverseConv3d(5, 4, indice_key="b").double(),
    ]
    g = torch.randn(x.features.shape[0], 4, dtype=torch.float64)

    def run():
        y = SparseTensor(x.features, x.coords, x.shape, x.batch_size)
        for layer in layers:
            y = layer(y)
        params = [x.features] + [layer.weight for layer in layers]
        return [y.features, *torch.autograd.grad((y.features * g).sum(), params)]

    chunked = run()
    monkeypatch.setattr(sc, "_chunked", lambda t: False)
    for a, b in zip(run(), chunked, strict=True):
        torch.testing.assert_close(a, b, **TOL)
