"""Test-time augmentation: average a model's outputs over yaw rotations (and mirror images).

Each pass sees the cloud rotated by ``2π·j/N`` about the vertical axis (``j = 0..N-1``), and with
``flip`` also its mirror image ``y → -y``; the semantic logits of the passes are averaged per
point, and each pass's offsets are mapped back into the input frame before they are averaged.
The instance features (and every other per-pass output) are the identity pass's, so the shifting
MLPs see the features they were trained on. With one rotation and no flip this is the plain
forward pass, unchanged.

This is the no-training counterpart of the equivariant mode (:mod:`dsnet_core.model.equivariant`):
averaging an ordinary network over rotations makes its semantics approximately invariant, while
an equivariant network is invariant by construction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from dsnet_core.errors import ConfigError


@dataclass(frozen=True)
class TTAConfig:
    """Which augmented copies are averaged.

    Attributes:
        rotations: number of yaw rotations ``N`` (angles ``2π·j/N``); 1 = no rotation.
        flip: also average the mirror image (``y → -y``) of every rotation (2N passes).
    """

    rotations: int = 1
    flip: bool = False

    def __post_init__(self) -> None:
        if int(self.rotations) != self.rotations or self.rotations < 1:
            raise ConfigError(f"--tta needs a positive number of rotations, got {self.rotations!r}")

    @property
    def passes(self) -> int:
        """Forward passes per cloud."""
        return self.rotations * (2 if self.flip else 1)

    @property
    def is_identity(self) -> bool:
        return self.rotations == 1 and not self.flip

    def transforms(self) -> list[tuple[float, bool]]:
        """``(angle radians, mirrored)`` of every pass; the identity comes first."""
        angles = [2.0 * math.pi * j / self.rotations for j in range(self.rotations)]
        return [(a, m) for m in ((False, True) if self.flip else (False,)) for a in angles]


def _rotation(angle: float, device: torch.device) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, -s], [s, c]], dtype=torch.float64, device=device)


def transform_points(points: torch.Tensor, angle: float, mirrored: bool) -> torch.Tensor:
    """Mirror (``y → -y``, if ``mirrored``) then rotate by ``angle`` about z, in float64.

    Args:
        points: float ``(N, D)`` with x, y (metres) in the first two columns; the rest is kept.

    Returns:
        A new tensor of the same dtype.
    """
    if angle == 0.0 and not mirrored:
        return points
    xy = points[:, :2].to(torch.float64)
    if mirrored:
        xy = xy * torch.tensor([1.0, -1.0], dtype=torch.float64, device=xy.device)
    out = points.clone()
    out[:, :2] = (xy @ _rotation(angle, xy.device).T).to(points.dtype)
    return out


def untransform_vectors(vectors: torch.Tensor, angle: float, mirrored: bool) -> torch.Tensor:
    """Map vectors predicted in a transformed frame back to the input frame (the inverse of
    :func:`transform_points`' linear part). ``vectors``: float ``(N, 3)`` metres."""
    if angle == 0.0 and not mirrored:
        return vectors
    xy = vectors[:, :2].to(torch.float64) @ _rotation(-angle, vectors.device).T
    if mirrored:
        xy = xy * torch.tensor([1.0, -1.0], dtype=torch.float64, device=xy.device)
    return torch.cat([xy.to(vectors.dtype), vectors[:, 2:]], dim=1)


def tta_forward(model: torch.nn.Module, clouds: list[torch.Tensor], config: TTAConfig, **forward_kwargs):
    """The model's :class:`~dsnet_core.model.network.NetOutput` averaged over ``config``'s passes.

    Args:
        model: a :class:`~dsnet_core.model.network.DSNet` (plain, prior-conditioned or equivariant).
        clouds: float ``(N_b, 4)`` per cloud (x, y, z metres, remission).
        config: the passes.
        forward_kwargs: passed to every forward call (e.g. ``instance``, ``priors``; per-point
            inputs such as priors do not change under a rotation).

    Returns:
        The identity pass's output with ``logits`` replaced by the mean over passes (when the model
        has a semantic head) and ``offsets`` by the mean of the back-transformed offsets.
    """
    if config.is_identity:
        return model(clouds, **forward_kwargs)
    base = None
    logit_sum = offset_sum = None
    for angle, mirrored in config.transforms():
        out = model([transform_points(c, angle, mirrored) for c in clouds], **forward_kwargs)
        if base is None:
            base = out
        if out.logits is not None:
            logit_sum = out.logits.float() if logit_sum is None else logit_sum + out.logits.float()
        if out.offsets is not None:
            back = untransform_vectors(out.offsets.float(), angle, mirrored)
            offset_sum = back if offset_sum is None else offset_sum + back
    n = config.passes
    return replace(
        base,
        logits=None if logit_sum is None else (logit_sum / n).to(base.logits.dtype),
        offsets=None if offset_sum is None else (offset_sum / n).to(base.offsets.dtype),
    )
