"""D-PLS's prior-conditioned instance network (Steinhauser et al., VISAPP 2025).

The network is :class:`~dsnet_core.model.network.DSNet` with ``prior_channels = num_classes`` and
no semantic head: every point's input is its 9 cylinder features plus the one-hot semantic prior
(the paper's best setting, Table 1), and the output is the offset to the instance centre and the
instance feature. Its semantics are the prior's.

- :func:`dpls_config`: the architecture of a semantic model turned into D-PLS's.
- :func:`init_from_semantic`: start from a trained DS-Net's weights where shapes match, the prior's
  input columns at zero, so that the new network's offsets start exactly as the old one's.
- :class:`DplsPredictor`: a D-PLS checkpoint on one cloud and its prior.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from dsnet_core.errors import CheckpointError, ConfigError
from dsnet_core.model.checkpoint import CARD, ModelCard, load_checkpoint
from dsnet_core.model.network import DSNet
from dsnet_core.model.presets import ModelConfig

BASE_FEATURES = 9
"""Per-point features of the plain network, before the prior's channels."""


def dpls_config(base: ModelConfig) -> ModelConfig:
    """``base`` with the prior appended to the point input (one channel per class) and no semantic head."""
    return replace(base, prior_channels=base.num_classes, semantic_head=False)


def is_dpls(config: ModelConfig) -> bool:
    """Whether an architecture is a D-PLS instance network."""
    return config.prior_channels > 0 and not config.semantic_head


def one_hot(sem: np.ndarray, num_classes: int) -> torch.Tensor:
    """int ``(N,)`` train ids → float32 ``(N, C)`` one-hot prior.

    Raises:
        ConfigError: an id outside ``0..C-1``.
    """
    ids = torch.as_tensor(np.asarray(sem, np.int64))
    if ids.numel() and (int(ids.min()) < 0 or int(ids.max()) >= num_classes):
        raise ConfigError(f"prior class ids must lie in 0..{num_classes - 1}, got {int(ids.max())}")
    return torch.nn.functional.one_hot(ids, num_classes).to(torch.float32)


def init_from_semantic(model: DSNet, source: DSNet) -> list[str]:
    """Copy ``source``'s weights into D-PLS network ``model`` wherever they fit.

    The point MLP's input batch norm and first linear layer are wider by the prior's channels: the
    first 9 columns are copied and the prior's columns of the linear layer are zero, so ``model``
    computes exactly ``source``'s offsets and features until training moves them.

    Returns:
        the names of ``model``'s parameters and buffers left at their initial values.
    """
    src = source.state_dict()
    state = model.state_dict()
    fresh = []
    with torch.no_grad():
        for name, value in state.items():
            old = src.get(name)
            if old is None:
                fresh.append(name)
            elif old.shape == value.shape:
                value.copy_(old)
            elif name.startswith("point_encoder.mlp.0.") and value.dim() == 1:
                value[: old.shape[0]].copy_(old)
            elif name == "point_encoder.mlp.1.weight":
                value.zero_()
                value[:, : old.shape[1]].copy_(old)
            else:
                fresh.append(name)
    return fresh


class DplsPredictor:
    """A D-PLS instance network on point clouds with their semantic priors.

    Args:
        model: a network with ``prior_channels > 0`` (put in eval mode here).
        card: its model card.
        device: torch device.
    """

    def __init__(self, model: DSNet, card: ModelCard | None = None, device: str = "cpu") -> None:
        self.device = torch.device(device)
        self.model = model.to(self.device).eval()
        self.card = card

    @classmethod
    def from_checkpoint(cls, path: str | Path, device: str = "cpu", expect_label_map=None) -> DplsPredictor:
        """Load a D-PLS checkpoint (verified like any checkpoint).

        Raises:
            CheckpointError: not a D-PLS checkpoint (a plain DS-Net one names --method dsnet).
        """
        model, card = load_checkpoint(path, device=device, expect_label_map=expect_label_map)
        if not is_dpls(model.config):
            raise CheckpointError(
                Path(path) / CARD,
                "a DS-Net checkpoint without a semantic-prior input: label with --method dsnet, or train "
                "a D-PLS one with dsnet train dpls",
            )
        return cls(model, card, device)

    @property
    def num_classes(self) -> int:
        return self.model.config.prior_channels

    def predict(self, points: np.ndarray, prior_sem: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Offsets float32 ``(N, 3)`` (metres) and features float16 ``(N, D)`` of one cloud.

        Args:
            points: float32 ``(N, 4)`` x, y, z (metres), remission.
            prior_sem: int ``(N,)`` the prior's train id per point (fed one-hot).
        """
        n = int(points.shape[0])
        if n == 0:
            return np.zeros((0, 3), np.float32), np.zeros((0, self.model.config.ins_dim), np.float16)
        pts = torch.as_tensor(np.asarray(points)[:, :4], dtype=torch.float32, device=self.device)
        prior = one_hot(prior_sem, self.num_classes).to(self.device)
        with torch.inference_mode():
            out = self.model([pts], priors=[prior])
        return out.offsets.float().cpu().numpy(), out.features.cpu().numpy().astype(np.float16)
