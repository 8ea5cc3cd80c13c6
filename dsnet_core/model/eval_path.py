"""Inference shortcuts shared by the network's modules: eval-mode batch norm as an affine map, and
when a module may take them."""

from __future__ import annotations

import torch
from torch import nn


def bn_affine(bn: nn.BatchNorm1d) -> tuple[torch.Tensor, torch.Tensor]:
    """Eval-mode batch norm as ``x · scale + shift`` per channel."""
    scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
    return scale, bn.bias - bn.running_mean * scale


def needs_module_path(module: nn.Module, x: torch.Tensor) -> bool:
    """Whether a forward of ``module`` on ``x`` must run the modules themselves: in training (batch
    statistics), where it must be differentiable, or under autocast (which the folded path's
    ``out=`` GEMMs do not follow)."""
    if module.training or torch.is_autocast_enabled(x.device.type):
        return True
    return torch.is_grad_enabled() and (x.requires_grad or any(p.requires_grad for p in module.parameters()))
