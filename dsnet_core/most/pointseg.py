"""PointSegMLP: the membership of a point in a detected centre's instance (paper Sec. III, eq. 3).

A pair (point p, centre ĉ) is described by
- the point: its position, its predicted class distribution ``O^point``, its backbone feature
  ``F^point`` and the BEV feature ``F^bev_p`` interpolated at its (x, y);
- the centre: its position, its class (one-hot), the BEV feature ``F^bev_ĉ`` interpolated at its
  projection, and its extent;
- their relation: ``p − ĉ`` and ``(p − ĉ) / r̂`` (the paper's MLP sees both positions; the
  differences are the same information, given explicitly so a small MLP needs not learn them).

A 4-layer MLP (Linear-BN-ReLU ×3, Linear) gives one logit; BCE on membership trains it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

POSITION_SCALE = 50.0  # metres: absolute positions enter divided by this


def pair_dim(num_classes: int, point_dim: int, bev_channels: int) -> int:
    """Width of :func:`pair_features`' rows."""
    return 3 + 3 + 3 + num_classes + point_dim + bev_channels + 3 + num_classes + bev_channels + 3


@dataclass
class PairInputs:
    """Per pair inputs (P pairs; a point appears once per centre whose RoI holds it).

    Attributes:
        xyz: float ``(P, 3)`` point positions, metres.
        sem_probs: float ``(P, C)`` predicted class probabilities of the point.
        point_feat: float ``(P, F)`` backbone features of the point.
        point_bev: float ``(P, B)`` BEV features at the point.
        centre: float ``(P, 3)`` centre positions, metres.
        centre_cls: int64 ``(P,)`` centre train ids.
        centre_bev: float ``(P, B)`` BEV features at the centre.
        extent: float ``(P, 3)`` the centre's half-extents, metres.
    """

    xyz: torch.Tensor
    sem_probs: torch.Tensor
    point_feat: torch.Tensor
    point_bev: torch.Tensor
    centre: torch.Tensor
    centre_cls: torch.Tensor
    centre_bev: torch.Tensor
    extent: torch.Tensor


def pair_features(p: PairInputs, num_classes: int) -> torch.Tensor:
    """float32 ``(P, pair_dim)`` rows of point–centre pairs."""
    d = p.xyz - p.centre
    ext = torch.clamp(p.extent, min=0.05)
    onehot = F.one_hot(p.centre_cls, num_classes).to(p.xyz.dtype)
    return torch.cat(
        [
            d,
            d / ext,
            p.xyz / POSITION_SCALE,
            p.sem_probs,
            p.point_feat,
            p.point_bev,
            p.centre / POSITION_SCALE,
            onehot,
            p.centre_bev,
            ext,
        ],
        dim=1,
    )


class PointSegMLP(nn.Module):
    """Membership logits of point–centre pairs.

    Args:
        in_dim: :func:`pair_dim`. widths: hidden widths (the paper's MLPs have 4 layers: 3 + output).
    """

    def __init__(self, in_dim: int, widths: tuple[int, ...] = (64, 64, 32)) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        prev = in_dim
        for w in widths:
            layers += [nn.Linear(prev, w), nn.BatchNorm1d(w), nn.ReLU()]
            prev = w
        layers.append(nn.Linear(prev, 1))
        self.mlp = nn.Sequential(*layers)

    def forward(self, pairs: torch.Tensor) -> torch.Tensor:
        """``(P, in_dim)`` → ``(P,)`` logits."""
        return self.mlp(pairs)[:, 0]
