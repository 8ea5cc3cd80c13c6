"""The student's loss on a batch of (mixed) clouds: DS-Net's semantic loss with per-point weights,
plus the offset loss towards centres computed before mixing.

With every weight 1 both terms equal the supervised trainer's (:func:`~dsnet_core.model.losses.semantic_loss`
and :func:`~dsnet_core.model.losses.offset_loss`): corrected frames weigh more by their weight,
pseudo-labels and source scans as given, ignored points not at all.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from dsnet_core.adapt.mixing import Cloud
from dsnet_core.model.losses import lovasz_softmax, voxel_labels
from dsnet_core.model.network import NetOutput


def weighted_semantic_loss(
    out: NetOutput, sem: torch.Tensor, weight: torch.Tensor, class_weights: torch.Tensor | None
) -> torch.Tensor:
    """Cross-entropy per voxel (its points' majority label; its weight the largest of its labelled
    points') weighted by class and voxel, normalised by the weights' sum, plus Lovász-softmax.

    Args:
        out: the network's output (``voxel_logits``, ``point_to_voxel``).
        sem: ``(N,) int64`` train ids (0 ignored); weight: ``(N,) float32``; class_weights: ``(C,)``.
    """
    logits = out.voxel_logits
    n_vox, n_cls = logits.shape
    vsem = voxel_labels(out.point_to_voxel, sem, n_vox, n_cls)
    labelled = vsem != 0
    if not bool(labelled.any()):
        return logits.sum() * 0.0
    w = torch.where(sem > 0, weight, torch.zeros_like(weight))
    vw = torch.zeros(n_vox, dtype=w.dtype, device=w.device).scatter_reduce(
        0, out.point_to_voxel, w, "amax", include_self=True
    )
    ce = F.cross_entropy(logits.float(), vsem, reduction="none")
    cw = class_weights[vsem] if class_weights is not None else torch.ones_like(ce)
    total = (cw * vw)[labelled]
    ce_mean = (total * ce[labelled]).sum() / total.sum().clamp_min(1e-12)
    return ce_mean + lovasz_softmax(F.softmax(logits.float(), dim=1), vsem)


def weighted_offset_loss(out: NetOutput, xyz: torch.Tensor, clouds: list[Cloud], device) -> torch.Tensor:
    """docs/algorithm.md eq. 1 with per-point weights: ``Σ w ‖O − (C − P)‖₁ / Σ w`` over points with
    an instance target (0 without any)."""
    inst = torch.from_numpy(np.concatenate([c.inst for c in clouds])).to(device)
    valid = inst > 0
    if not bool(valid.any()):
        return out.offsets.sum() * 0.0
    centre = torch.from_numpy(np.concatenate([c.centre for c in clouds])).to(device)
    weight = torch.from_numpy(np.concatenate([c.weight for c in clouds])).to(device)
    diff = (out.offsets[valid] - (centre[valid] - xyz[valid])).abs().sum(dim=1)
    w = weight[valid]
    return (w * diff).sum() / w.sum().clamp_min(1e-12)


def adapt_loss(model, clouds: list[Cloud], class_weights: torch.Tensor | None, device) -> torch.Tensor:
    """Semantic plus offset loss of ``model`` on ``clouds`` (one forward pass)."""
    pts = [torch.from_numpy(np.ascontiguousarray(c.points)).to(device) for c in clouds]
    out = model(pts, instance=True)
    sem = torch.from_numpy(np.concatenate([c.sem for c in clouds])).to(device)
    weight = torch.from_numpy(np.concatenate([c.weight for c in clouds])).to(device)
    xyz = torch.cat([p[:, :3] for p in pts])
    return weighted_semantic_loss(out, sem, weight, class_weights) + weighted_offset_loss(
        out, xyz, clouds, device
    )
