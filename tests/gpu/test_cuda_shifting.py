"""Dynamic shifting on CUDA equals the CPU path (marker ``gpu``; see tests/gpu/device.py).

On CUDA the flat kernel runs as the dense all-pairs kernel, on CPU as the neighbour (radius-sum)
kernel; both compute the same means. Inputs lie on a 1/64 m grid, so every squared distance near a
bandwidth is exact in float32 and none ties with a radius (no point is in one device's
neighbourhood and out of the other's). Later iterations start from means, off the grid: there a
near-tie may move a seed, so they are held to 1e-4 m for 99.5 % of the seeds. Tolerances: kernel
targets and the first iteration 1e-5 m (float32 sums in another order); the clusterer's converged
seeds 1e-3 m and its partition of well separated objects exactly.
"""

from __future__ import annotations

import numpy as np
import torch

from dsnet_core.instance.clustering import DynamicShiftClusterer
from dsnet_core.instance.shifting import (
    BANDWIDTHS_3D,
    DynamicShift,
    flat_kernel_targets_dense,
    flat_kernel_targets_neighbors,
)
from tests.gpu.device import DEVICE, MARKS

pytestmark = MARKS


def _on_grid(x: np.ndarray) -> np.ndarray:
    return (np.round(x * 64) / 64).astype(np.float32)


def _objects(seed: int, m: int, spread: float = 0.7) -> tuple[np.ndarray, np.ndarray]:
    """float32 ``(m, 3)`` points (on the 1/64 m grid) around 30 centres 9 m apart on a plane, and
    each point's centre."""
    rng = np.random.default_rng(seed)
    grid = np.stack(np.meshgrid(np.arange(6), np.arange(5)), -1).reshape(-1, 2) * 9.0 - 22.0
    centres = np.concatenate([grid, np.zeros((30, 1))], 1)[rng.integers(0, 30, m)]
    return _on_grid(centres + rng.normal(size=(m, 3)) * spread), centres.astype(np.float32)


def test_dense_kernel_on_cuda_matches_cpu_neighbours():
    x = torch.from_numpy(_objects(4, 3000)[0])
    cpu = flat_kernel_targets_neighbors(x, BANDWIDTHS_3D)
    gpu = flat_kernel_targets_dense(x.to(DEVICE), BANDWIDTHS_3D)
    torch.testing.assert_close(gpu.cpu(), cpu, atol=1e-5, rtol=0)


def test_learned_shifting_on_cuda_equals_cpu():
    """The module with random MLPs: every iteration's positions and bandwidth weights."""
    torch.manual_seed(0)
    module = DynamicShift().eval()
    x = torch.from_numpy(_objects(5, 2000)[0])
    feats = torch.randn(2000, 32)
    with torch.no_grad():
        cpu = module(x, feats)
        module.kernel = "dense"
        gpu = module.to(DEVICE)(x.to(DEVICE), feats.to(DEVICE))
    torch.testing.assert_close(gpu.weights[0].cpu(), cpu.weights[0], atol=1e-5, rtol=0)
    torch.testing.assert_close(gpu.positions[0].cpu(), cpu.positions[0], atol=1e-5, rtol=0)
    near = (gpu.positions.cpu() - cpu.positions).abs().amax(-1) <= 1e-4  # (iterations, seeds)
    assert near.float().mean(1).min() >= 0.995, near.float().mean(1)


def test_clusterer_on_cuda_gives_the_cpu_partition():
    """Seeds, convergence and the final mean shift: the same objects, id for id."""
    xyz, truth = _objects(6, 4000, spread=0.5)
    centres = _on_grid(truth + 0.2 * (xyz - truth))  # regressed: most of the way to the objects' centres
    feats = np.random.default_rng(7).normal(size=(4000, 32)).astype(np.float32)
    torch.manual_seed(0)
    module = DynamicShift()
    cpu = DynamicShiftClusterer(module, n_seeds=1500, device="cpu").run(xyz, centres, feats)
    module.kernel = "dense"
    gpu = DynamicShiftClusterer(module, n_seeds=1500, device=DEVICE).run(xyz, centres, feats)
    assert np.array_equal(gpu.seeds, cpu.seeds)
    np.testing.assert_allclose(gpu.converged, cpu.converged, atol=1e-3)
    assert np.array_equal(gpu.ids, cpu.ids)
    assert len(np.unique(cpu.ids)) == 30  # one instance per object
