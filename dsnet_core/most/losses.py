"""MOST's losses: the CenterPoint focal loss on centre heatmaps and L1 regression at centre cells
(eq. 2, eq. 4), BCE on point–centre memberships (eq. 3). The semantic loss is the project's
(:func:`dsnet_core.model.losses.semantic_loss`, eq. 1 taken on the current scan's voxels only).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from dsnet_core.most.bev import REGRESS

#: weights of the regression terms (CenterPoint weighs its box regression 0.25 and velocity 0.2
#: of that; our velocities are m/s at 10 Hz, an order above the metre-sized terms)
REGRESS_WEIGHTS = {"offset": 1.0, "height": 1.0, "extent": 1.0, "velocity": 0.2}


def focal_loss(
    logits: torch.Tensor, target: torch.Tensor, alpha: float = 2.0, beta: float = 4.0
) -> torch.Tensor:
    """CenterNet/CenterPoint focal loss, summed and divided by the number of peaks (at least 1).

    ``−(1 − p)^α log p`` at cells where the target is 1, ``−(1 − y)^β p^α log(1 − p)`` elsewhere.

    Args:
        logits: float ``(B, K, S, S)``; target: float ``(B, K, S, S)`` Gaussian heatmaps in [0, 1].
    """
    p = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    pos = target.eq(1.0)
    pos_loss = -(torch.log(p) * (1 - p) ** alpha)[pos].sum()
    neg_loss = -(torch.log(1 - p) * p**alpha * (1 - target) ** beta)[~pos].sum()
    return (pos_loss + neg_loss) / pos.sum().clamp(min=1)


def regression_losses(
    regress: torch.Tensor, index: torch.Tensor, targets: dict[str, torch.Tensor], vel_mask: torch.Tensor
) -> dict[str, torch.Tensor]:
    """Mean L1 of each regression map at the objects' centre cells.

    Args:
        regress: float ``(8, S, S)`` one sample's regression maps.
        index: int64 ``(M,)`` flat centre cells ``ix · S + iy``.
        targets: ``offset (M, 2)``, ``height (M, 1)``, ``extent (M, 3)``, ``velocity (M, 2)``.
        vel_mask: bool ``(M,)`` objects with a velocity target.

    Returns:
        one scalar per term (0 without objects).
    """
    flat = regress.reshape(regress.shape[0], -1).index_select(1, index).t()  # (M, 8)
    out = {}
    for name, sl in REGRESS.items():
        pred, tgt = flat[:, sl], targets[name]
        mask = (
            vel_mask
            if name == "velocity"
            else torch.ones(index.shape[0], dtype=torch.bool, device=flat.device)
        )
        if not bool(mask.any()):
            out[name] = regress.sum() * 0.0
            continue
        out[name] = (pred[mask] - tgt[mask]).abs().sum(1).mean()
    return out


def membership_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Eq. 3: BCE between membership logits ``(P,)`` and 0/1 targets ``(P,)`` (0 without pairs)."""
    if logits.numel() == 0:
        return logits.sum() * 0.0
    return F.binary_cross_entropy_with_logits(logits, target.to(logits.dtype))
