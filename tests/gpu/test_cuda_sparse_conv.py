"""The sparse convolution on CUDA equals the CPU path (marker ``gpu``; see tests/gpu/device.py).

The two devices build their neighbour tables differently (numba loops on CPU, whole-array torch on
CUDA) and multiply in another layout (chunked per segment on CPU, one batched GEMM per group on
CUDA). Tolerances, relative to each tensor's largest magnitude (sums of ~20 k products in another
order): float64 1e-10 (values and gradients of a down-up stack on 700 sites), float32 1e-4 (the
same on ~20 k sites).
"""

from __future__ import annotations

import pytest
import torch

from dsnet_core.model.sparse_conv import SparseConv3d, SparseInverseConv3d, SparseTensor, SubMConv3d
from tests.dsnet_core.model.test_sparse_conv import random_sites
from tests.gpu.device import DEVICE, MARKS

pytestmark = MARKS


def _stack(cin: int, dtype: torch.dtype) -> list[torch.nn.Module]:
    torch.manual_seed(3)
    layers = [
        SubMConv3d(cin, 8, 3),
        SubMConv3d(8, 8, (1, 3, 3)),
        SparseConv3d(8, 16, 3, stride=2, padding=1, indice_key="g1"),
        SubMConv3d(16, 16, (3, 1, 3)),
        SparseConv3d(16, 16, 3, stride=(2, 2, 1), padding=1, indice_key="g2"),
        SubMConv3d(16, 16, 3),
        SparseInverseConv3d(16, 16, indice_key="g2"),
        SparseInverseConv3d(16, 8, indice_key="g1"),
    ]
    return [layer.to(dtype) for layer in layers]


def _run(layers, feats, coords, shape, batch, device):
    layers = [layer.to(device) for layer in layers]
    x = feats.detach().to(device).requires_grad_(True)
    y = SparseTensor(x, coords.to(device), shape, batch)
    for layer in layers:
        y = layer(y)
    g = torch.randn(y.features.shape, generator=torch.Generator().manual_seed(2), dtype=feats.dtype)
    params = [x, *(layer.weight for layer in layers)]
    grads = torch.autograd.grad((y.features * g.to(device)).sum(), params)
    return [t.detach().cpu() for t in (y.coords, y.features, *grads)]


@pytest.mark.parametrize(
    ("dtype", "shape", "sites", "tol"),
    [(torch.float64, (12, 10, 8), 700, 1e-10), (torch.float32, (120, 90, 16), 20_000, 1e-4)],
    ids=["float64", "float32-20k-sites"],
)
def test_sparse_stack_on_cuda_equals_cpu(dtype, shape, sites, tol):
    batch = 2
    coords = random_sites(shape, batch, sites, seed=5)
    feats = torch.randn(coords.shape[0], 4, generator=torch.Generator().manual_seed(6), dtype=dtype)
    cpu = _run(_stack(4, dtype), feats, coords, shape, batch, "cpu")
    gpu = _run(_stack(4, dtype), feats, coords, shape, batch, DEVICE)
    assert torch.equal(gpu[0], cpu[0])  # the same active sites in the same order
    for a, b in zip(gpu[1:], cpu[1:], strict=True):
        torch.testing.assert_close(a, b, atol=tol * float(b.abs().max()), rtol=tol)
