"""Losses: weighted cross-entropy + Lovász-softmax for semantics (class 0 ignored), and the offset
loss of DS-Net (docs/algorithm.md eq. 1) towards each instance's axis-aligned tight-box centre."""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F


def class_weights(counts: np.ndarray, power: float = 0.5, ignore: int = 0) -> torch.Tensor:
    """Cross-entropy weights ``(C,) float32`` ∝ frequency^-power, mean 1 over seen classes.

    Args:
        counts: ``(C,)`` points per train id in the training data.
        power: 0.5 gives inverse square-root frequency weighting.
        ignore: the ignore class (weight 0).
    """
    counts = np.asarray(counts, dtype=np.float64)
    freq = counts / max(counts.sum() - counts[ignore], 1.0)
    w = np.where(counts > 0, (freq + 1e-12) ** -power, 0.0)
    w[ignore] = 0.0
    seen = w > 0
    if seen.any():
        w[seen] /= w[seen].mean()
    return torch.tensor(w, dtype=torch.float32)


def lovasz_grad(gt_sorted: torch.Tensor) -> torch.Tensor:
    """Gradient of the Lovász extension of the Jaccard loss w.r.t. sorted errors."""
    gts = gt_sorted.sum()
    intersection = gts - gt_sorted.cumsum(0)
    union = gts + (1 - gt_sorted).cumsum(0)
    jaccard = 1.0 - intersection / union
    if gt_sorted.numel() > 1:
        jaccard[1:] = jaccard[1:] - jaccard[:-1]
    return jaccard


def lovasz_softmax(probs: torch.Tensor, labels: torch.Tensor, ignore: int = 0) -> torch.Tensor:
    """Lovász-softmax loss (Berman et al. 2018), averaged over classes present in ``labels``.

    Args:
        probs: float ``(N, C)`` softmax probabilities.
        labels: int64 ``(N,)``; points with ``ignore`` are dropped.
    """
    keep = labels != ignore
    probs, labels = probs[keep], labels[keep]
    if labels.numel() == 0:
        return probs.sum() * 0.0
    losses = []
    for c in torch.unique(labels).tolist():
        fg = (labels == c).to(probs.dtype)
        errors = (fg - probs[:, c]).abs()
        errors_sorted, perm = torch.sort(errors, descending=True)
        losses.append(torch.dot(errors_sorted, lovasz_grad(fg[perm])))
    return torch.stack(losses).mean()


def semantic_loss(
    logits: torch.Tensor, labels: torch.Tensor, weights: torch.Tensor | None = None, ignore: int = 0
) -> torch.Tensor:
    """Weighted cross-entropy + Lovász-softmax, both ignoring ``ignore``.

    Args:
        logits: float ``(N, C)``; labels: int64 ``(N,)`` train ids; weights: ``(C,)`` or None.
    """
    if not bool((labels != ignore).any()):
        return logits.sum() * 0.0
    ce = F.cross_entropy(logits, labels, weight=weights, ignore_index=ignore)
    return ce + lovasz_softmax(F.softmax(logits, dim=1), labels, ignore)


def instance_centres(xyz: torch.Tensor, instance_keys: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Centre of each point's instance: the middle of the instance's axis-aligned tight box.

    Pass the points of all scans of a 4D volume together (aligned to the reference frame) and
    the centre is that of the instance over all the volume's scans (docs/algorithm.md eq. 5).

    Args:
        xyz: float ``(N, 3)`` metres.
        instance_keys: int64 ``(N,)`` ids that identify an instance (e.g. class << 16 | id).
        valid: bool ``(N,)`` points that belong to a thing instance.

    Returns:
        float ``(N, 3)``; rows of invalid points are zero.
    """
    out = torch.zeros_like(xyz)
    if not bool(valid.any()):
        return out
    keys, inv = torch.unique(instance_keys[valid], return_inverse=True)
    pts = xyz[valid]
    idx = inv[:, None].expand(-1, 3)
    lo = pts.new_full((keys.numel(), 3), float("inf")).scatter_reduce(0, idx, pts, "amin")
    hi = pts.new_full((keys.numel(), 3), float("-inf")).scatter_reduce(0, idx, pts, "amax")
    out[valid] = ((lo + hi) / 2)[inv]
    return out


def offset_loss(
    offsets: torch.Tensor, xyz: torch.Tensor, centres: torch.Tensor, valid: torch.Tensor
) -> torch.Tensor:
    """docs/algorithm.md eq. 1: mean over thing points of ‖O − (C_gt − P)‖₁.

    Args:
        offsets: float ``(N, 3)`` predicted; xyz: ``(N, 3)`` points; centres: ``(N, 3)`` targets;
        valid: bool ``(N,)`` thing points.
    """
    if not bool(valid.any()):
        return offsets.sum() * 0.0
    diff = offsets[valid] - (centres[valid] - xyz[valid])
    return diff.abs().sum(dim=1).mean()


def voxel_labels(
    point_to_voxel: torch.Tensor, labels: torch.Tensor, n_voxels: int, num_classes: int, ignore: int = 0
):
    """Majority label per voxel over its labelled points (``ignore`` only where none is labelled).

    The semantic loss is taken per voxel, as in Cylinder3D (3–4× fewer rows than points).

    Args:
        point_to_voxel: int64 ``(N,)``; labels: int64 ``(N,)``.

    Returns:
        int64 ``(M,)``.
    """
    votes = torch.zeros(n_voxels * num_classes, dtype=torch.int64, device=labels.device)
    votes.index_add_(0, point_to_voxel * num_classes + labels, torch.ones_like(labels))
    votes = votes.view(n_voxels, num_classes)
    votes[:, ignore] = 0
    best = votes.argmax(dim=1)
    return torch.where(votes.gather(1, best[:, None])[:, 0] > 0, best, torch.full_like(best, ignore))
