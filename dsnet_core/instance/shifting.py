"""Dynamic shifting (DS-Net Algorithm 1): learned per-seed weights over flat-kernel bandwidths.

Per iteration ``i`` a small MLP on the seeds' 32-d instance features gives softmax weights
``W`` over the bandwidth candidates; candidate ``j`` moves each seed to the mean of the seeds
within ``bandwidths[j]`` of it (flat kernel, boundary included); the new positions are
``Σ_j W[:, j] ⊙ target_j``. Two kernels compute the targets with the same arithmetic:

- ``"dense"``: the M×M formulation of the paper, in torch on any device (row blocks keep the
  memory at ``block × M``); the test oracle.
- ``"neighbors"``: fixed-radius neighbour sums on a cell grid (numba, CPU); the default. Its
  backward uses the symmetry of the kernel: ``∂L/∂x_b = Σ_a K_ab g_a / D_a``, i.e. the same
  neighbour sum applied to ``g / D``.

Neighbourhoods are not differentiated (the kernel is piecewise constant); the means are.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, NamedTuple

import numpy as np
import torch
from torch import nn

from dsnet_core.instance.clustering_config import BANDWIDTHS_3D, BANDWIDTHS_4D  # noqa: F401  (re-exported)
from dsnet_core.instance.radius import radius_sums

Kernel = Literal["dense", "neighbors"]


class ShiftResult(NamedTuple):
    """Output of :class:`DynamicShift`.

    Attributes:
        positions: (I, M, 3) seed positions after each iteration, metres, dtype of the seeds.
        weights: (I, M, L) softmax weights over the bandwidth candidates, float32.
    """

    positions: torch.Tensor
    weights: torch.Tensor


def flat_kernel_targets_dense(
    x: torch.Tensor, bandwidths: Sequence[float], block: int = 2048
) -> torch.Tensor:
    """Flat-kernel mean of every seed's neighbourhood, dense M×M formulation.

    Args:
        x: (M, 3) float32/float64 seed positions in metres, any device.
        bandwidths: L radii in metres.
        block: rows of the M×M kernel built at once.

    Returns:
        (L, M, 3) targets, dtype and device of ``x``.
    """
    out = []
    xd = x.detach()
    x64 = x.to(torch.float64)
    for r0 in range(0, x.shape[0], block):
        rows = xd[r0 : r0 + block]
        d2 = (rows[:, None, 0] - xd[None, :, 0]) * (rows[:, None, 0] - xd[None, :, 0])
        d2 = d2 + (rows[:, None, 1] - xd[None, :, 1]) * (rows[:, None, 1] - xd[None, :, 1])
        d2 = d2 + (rows[:, None, 2] - xd[None, :, 2]) * (rows[:, None, 2] - xd[None, :, 2])
        per_bw = []
        for r in bandwidths:
            k = (d2 <= r * r).to(torch.float64)  # sums in float64, like the neighbour kernel
            per_bw.append((k @ x64) / k.sum(dim=1, keepdim=True))
        out.append(torch.stack(per_bw))
    return torch.cat(out, dim=1).to(x.dtype)


class _NeighbourMeans(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x: torch.Tensor, radii: np.ndarray) -> torch.Tensor:
        xn = x.detach().cpu().numpy()
        m = xn.shape[0]
        vals = np.broadcast_to(np.concatenate([xn, np.ones((m, 1))], axis=1), (radii.size, m, 4))
        sums = radius_sums(xn, xn, radii, vals)
        counts = sums[..., 3:]
        ctx.save_for_backward(x)
        ctx.radii = radii
        ctx.counts = counts
        return torch.from_numpy(sums[..., :3] / counts).to(dtype=x.dtype, device=x.device)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        (x,) = ctx.saved_tensors
        xn = x.detach().cpu().numpy()
        g = grad.detach().cpu().numpy().astype(np.float64) / ctx.counts
        grad_x = radius_sums(xn, xn, ctx.radii, g).sum(axis=0)
        return torch.from_numpy(grad_x).to(dtype=x.dtype, device=x.device), None


def flat_kernel_targets_neighbors(x: torch.Tensor, bandwidths: Sequence[float]) -> torch.Tensor:
    """Same as :func:`flat_kernel_targets_dense`, via radius-neighbour sums on the CPU.

    Args:
        x: (M, 3) float32/float64 seed positions in metres (moved to the CPU for the sums).
        bandwidths: L radii in metres.

    Returns:
        (L, M, 3) targets, dtype and device of ``x``; differentiable with respect to ``x``.
    """
    radii = np.asarray(bandwidths, dtype=np.float64)
    order = np.argsort(radii, kind="stable")
    out = _NeighbourMeans.apply(x, radii[order])
    inverse = torch.from_numpy(np.argsort(order)).to(x.device)
    return out.index_select(0, inverse)


_KERNELS = {"dense": flat_kernel_targets_dense, "neighbors": flat_kernel_targets_neighbors}


class DynamicShift(nn.Module):
    """The dynamic shifting module: one bandwidth-weighting MLP per iteration.

    Args:
        bandwidths: L flat-kernel radii in metres (3D: ``BANDWIDTHS_3D``, 4D: ``BANDWIDTHS_4D``).
        iterations: number of shifting iterations I (4 in the paper).
        feature_dim: width D of the per-seed instance feature (32).
        kernel: ``"neighbors"`` (CPU default) or ``"dense"`` (M×M, any device).
    """

    def __init__(
        self,
        bandwidths: Sequence[float] = BANDWIDTHS_3D,
        iterations: int = 4,
        feature_dim: int = 32,
        kernel: Kernel = "neighbors",
    ) -> None:
        super().__init__()
        if kernel not in _KERNELS:
            raise ValueError(f"unknown shifting kernel {kernel!r}; choose one of {sorted(_KERNELS)}")
        self.bandwidths = tuple(float(b) for b in bandwidths)
        self.kernel = kernel
        self.mlps = nn.ModuleList(
            nn.Sequential(
                nn.Linear(feature_dim, feature_dim),
                nn.BatchNorm1d(feature_dim),
                nn.ReLU(),
                nn.Linear(feature_dim, len(self.bandwidths)),
            )
            for _ in range(iterations)
        )

    @property
    def iterations(self) -> int:
        return len(self.mlps)

    def forward(self, seeds: torch.Tensor, features: torch.Tensor) -> ShiftResult:
        """Shift the seeds.

        Args:
            seeds: (M, 3) float32/float64 regressed centres of the seeds, metres.
            features: (M, D) float32/float16 instance features of the seeds.

        Returns:
            :class:`ShiftResult` with the positions after every iteration and the weights used.
        """
        if self.training and seeds.shape[0] < 2:
            raise ValueError("training the shifting MLPs needs at least 2 seeds (batch norm)")
        feats = features.to(torch.float32)
        targets_fn = _KERNELS[self.kernel]
        x = seeds
        positions, weights = [], []
        for mlp in self.mlps:
            w = torch.softmax(mlp(feats), dim=1)
            targets = targets_fn(x, self.bandwidths)  # (L, M, 3)
            x = (w.T.to(x.dtype)[:, :, None] * targets).sum(dim=0)
            positions.append(x)
            weights.append(w)
        if not positions:
            return ShiftResult(seeds[None], feats.new_zeros((0, seeds.shape[0], len(self.bandwidths))))
        return ShiftResult(torch.stack(positions), torch.stack(weights))

    @classmethod
    def with_fixed_weights(
        cls, weights: Sequence[float], bandwidths: Sequence[float] = BANDWIDTHS_3D, **kwargs
    ) -> DynamicShift:
        """A module whose MLPs ignore the features and output the same ``weights`` for every seed.

        The non-learned baseline (and the oracle pipeline without a network): last layer
        weight 0, bias ``log(weights)``. Zero weights become a large negative bias.
        """
        module = cls(bandwidths=bandwidths, **kwargs)
        w = torch.as_tensor(weights, dtype=torch.float32)
        if w.shape != (len(module.bandwidths),) or (w < 0).any() or w.sum() <= 0:
            raise ValueError(f"need {len(module.bandwidths)} non-negative weights, got {list(weights)}")
        with torch.no_grad():
            for mlp in module.mlps:
                mlp[-1].weight.zero_()
                mlp[-1].bias.copy_(torch.log(torch.clamp(w / w.sum(), min=1e-30)))
        return module.eval()


def shift_loss(positions: torch.Tensor, gt_centres: torch.Tensor) -> torch.Tensor:
    """DS-Net eq. 4: per iteration the mean over seeds of the L1 distance to the gt centre, summed.

    Args:
        positions: (I, M, 3) positions after each iteration (``ShiftResult.positions``).
        gt_centres: (M, 3) ground-truth instance centres of the seeds (axis-aligned box centres).

    Returns:
        Scalar loss (metres).
    """
    m = max(positions.shape[1], 1)
    return (positions - gt_centres[None].to(positions.dtype)).abs().sum(dim=(1, 2)).div(m).sum()
