"""Shared by the rotation tests (test-time augmentation, equivariance): clouds kept away from
cell boundaries, float64 yaw rotations, random-weight networks with realistic activations, and the
comparison of rotated logits that survives float rounding."""

from __future__ import annotations

import math

import numpy as np
import torch

from dsnet_core.model.cylinder import CylinderGrid
from dsnet_core.model.network import DSNet
from dsnet_core.model.presets import ModelConfig

# 36 azimuth cells: a yaw of 2π/n is an exact shift for n = 2, 3, 4, 6, ...
GRID = CylinderGrid(size=(24, 36, 8), min_bound=(1.0, -math.pi, -2.0), max_bound=(25.0, math.pi, 2.0))
CFG = ModelConfig(width=2, point_mlp=(8, 8), compress=4, ins_dim=6, grid=GRID)


def away_from_cell_boundaries(
    n: int, seed: int, grid: CylinderGrid = GRID, margin_rad: float = 1e-6, margin_m: float = 1e-4
) -> np.ndarray:
    """float32 ``(n, 4)`` points whose (ρ, φ, z) lie at least a margin from every cell boundary
    (float32 rounding of a rotated point then cannot move it to another cell)."""
    rng = np.random.default_rng(seed)
    lo, hi = grid.min_bound, grid.max_bound
    m = 3 * n
    rho = rng.uniform(lo[0] + 0.5, hi[0] - 0.5, m)
    phi = rng.uniform(-math.pi, math.pi, m)
    z = rng.uniform(lo[2] + 0.1, hi[2] - 0.1, m)
    ok = np.ones(m, bool)
    for v, low, step, margin in (
        (rho, lo[0], grid.interval[0], margin_m),
        (phi, lo[1], grid.interval[1], margin_rad),
        (z, lo[2], grid.interval[2], margin_m),
    ):
        frac = (v - low) / step
        ok &= np.abs(frac - np.round(frac)) * step > margin
    pts = np.stack([rho * np.cos(phi), rho * np.sin(phi), z, rng.random(m)], 1)[ok][:n]
    return pts.astype(np.float32)


def rotate64(points: np.ndarray, angle: float, dtype=np.float32) -> np.ndarray:
    """Rotate ``(N, ≥3)`` points by ``angle`` about z in float64; ``dtype`` out."""
    c, s = math.cos(angle), math.sin(angle)
    out = points.astype(np.float64).copy()
    out[:, :2] = points[:, :2].astype(np.float64) @ np.array([[c, -s], [s, c]]).T
    return out.astype(dtype)


def rotate_vectors(v: torch.Tensor, angle: float) -> torch.Tensor:
    """Rotate float ``(N, 3)`` vectors by ``angle`` about z (float64 arithmetic)."""
    c, s = math.cos(angle), math.sin(angle)
    rot = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    return (v.to(torch.float64) @ rot.T).to(v.dtype)


def calibrated(net: DSNet, clouds: list[torch.Tensor], **kwargs) -> DSNet:
    """Set the batch-norm statistics of a random-weight network from ``clouds`` (so its outputs
    have realistic magnitudes rather than ~1e-6), then put it in eval mode."""
    net.train()
    with torch.no_grad():
        for mod in net.modules():
            if isinstance(mod, torch.nn.BatchNorm1d):
                mod.reset_running_stats()
                mod.momentum = None
        net(clouds, **kwargs)
    return net.eval()


def assert_same_classes(
    logits: torch.Tensor, ref: torch.Tensor, atol: float, min_clear: float = 0.98
) -> None:
    """``logits`` within ``atol`` of ``ref`` (both ``(N, C)``), and the same class wherever ``ref``'s
    two best logits lie more than ``2 · atol`` apart.

    Closer pairs are near-ties that rounding may swap: a rotated input reaches the network as other
    float32 numbers, and how sums round differs between CPUs' vector kernels (AVX2 vs AVX-512), so
    their argmax is not a property of the network. At least ``min_clear`` of the points must be
    clear of ties, so the class check covers nearly all of them.
    """
    torch.testing.assert_close(logits, ref, atol=atol, rtol=0)
    best = ref.topk(2, dim=1).values
    clear = best[:, 0] - best[:, 1] > 2 * atol
    share = float(clear.float().mean())
    assert share >= min_clear, f"only {share:.1%} of the points are clear of near-ties"
    assert torch.equal(logits.argmax(1)[clear], ref.argmax(1)[clear])
