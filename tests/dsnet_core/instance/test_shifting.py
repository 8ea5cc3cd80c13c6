import numpy as np
import pytest
import torch

from dsnet_core.instance.shifting import (
    BANDWIDTHS_3D,
    DynamicShift,
    flat_kernel_targets_dense,
    flat_kernel_targets_neighbors,
    shift_loss,
)

torch.set_num_threads(1)  # the machines behave like one core; extra threads only spin


def _seeds(seed: int, m: int = 1500, dtype=torch.float32) -> torch.Tensor:
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-40, 40, size=(30, 3)) * [1.0, 1.0, 0.05]
    x = centres[rng.integers(0, 30, m)] + rng.normal(size=(m, 3)) * 0.7
    return torch.tensor(x, dtype=dtype)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dense_and_neighbour_kernels_agree(dtype):
    x = _seeds(0, dtype=dtype)
    dense = flat_kernel_targets_dense(x, BANDWIDTHS_3D, block=256)
    nbr = flat_kernel_targets_neighbors(x, BANDWIDTHS_3D)
    assert nbr.shape == (3, x.shape[0], 3) and nbr.dtype == dtype
    torch.testing.assert_close(nbr, dense, atol=1e-5, rtol=0)


def test_flat_kernel_is_the_mean_within_the_radius_boundary_included():
    x = torch.tensor([[0.0, 0, 0], [1.7, 0, 0], [3.0, 0, 0]], dtype=torch.float64)
    t = flat_kernel_targets_neighbors(x, (0.2, 1.7))
    assert t[0].tolist() == x.tolist()
    assert t[1, :, 0].tolist() == pytest.approx([0.85, (1.7 + 3.0 + 0.0) / 3, 2.35])


def test_module_kernels_agree_and_gradients_reach_every_mlp():
    torch.manual_seed(0)
    x = _seeds(1, m=800)
    feats = torch.randn(800, 32)
    gt = x.round()
    results = {}
    for kernel in ("dense", "neighbors"):
        torch.manual_seed(0)
        module = DynamicShift(kernel=kernel)
        out = module(x, feats)
        assert out.positions.shape == (4, 800, 3) and out.weights.shape == (4, 800, 3)
        loss = shift_loss(out.positions, gt)
        loss.backward()
        grads = [m[0].weight.grad for m in module.mlps] + [m[-1].weight.grad for m in module.mlps]
        assert all(g is not None and g.abs().sum() > 0 for g in grads)
        results[kernel] = (out.positions.detach(), [g.clone() for g in grads])
    torch.testing.assert_close(results["dense"][0], results["neighbors"][0], atol=1e-5, rtol=0)
    for gd, gn in zip(results["dense"][1], results["neighbors"][1], strict=True):
        torch.testing.assert_close(gd, gn, atol=1e-4, rtol=1e-4)


def test_neighbour_kernel_gradient_matches_dense_on_positions():
    x = _seeds(2, m=400, dtype=torch.float64).requires_grad_(True)
    g = torch.randn(3, 400, 3, dtype=torch.float64)
    (gd,) = torch.autograd.grad((flat_kernel_targets_dense(x, BANDWIDTHS_3D) * g).sum(), x)
    (gn,) = torch.autograd.grad((flat_kernel_targets_neighbors(x, BANDWIDTHS_3D) * g).sum(), x)
    torch.testing.assert_close(gn, gd, atol=1e-10, rtol=0)


def test_fixed_weights_module_is_plain_blurring_mean_shift():
    x = _seeds(3, m=500)
    module = DynamicShift.with_fixed_weights([0.0, 1.0, 0.0])
    with torch.no_grad():
        out = module(x, torch.randn(500, 32))
    assert torch.allclose(out.weights[:, :, 1], torch.ones(4, 500))
    ref = x
    for _ in range(4):
        ref = flat_kernel_targets_dense(ref, BANDWIDTHS_3D)[1]
    torch.testing.assert_close(out.positions[-1], ref, atol=1e-5, rtol=0)


def test_shift_loss_is_summed_mean_l1():
    pos = torch.zeros(2, 2, 3)
    gt = torch.tensor([[1.0, 0, 0], [0, 2.0, 1.0]])
    assert shift_loss(pos, gt).item() == pytest.approx(2 * (1 + 3) / 2)


def test_unknown_kernel_is_rejected():
    with pytest.raises(ValueError, match="unknown shifting kernel 'sparse'"):
        DynamicShift(kernel="sparse")
