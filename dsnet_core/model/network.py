"""The whole DS-Net network: voxelise → point MLP → cylinder U-Net → semantic and instance heads."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from dsnet_core.model.backbone import AsymmetricUNet
from dsnet_core.model.cylinder import voxelize
from dsnet_core.model.heads import InstanceHead, PointEncoder, SemanticHead
from dsnet_core.model.presets import ModelConfig
from dsnet_core.model.sparse_conv import SparseTensor


@dataclass
class NetOutput:
    """Per-point outputs of a batch (points concatenated in input order).

    Attributes:
        logits: float ``(N, num_classes)``, each point takes its voxel's logits.
        offsets: float ``(N, 3)`` metres, predicted point → instance centre (None if skipped).
        features: float ``(N, ins_dim)`` instance features (None if skipped).
        voxel_logits: float ``(M, num_classes)``.
        point_to_voxel: int64 ``(N,)``.
        sizes: points per cloud.
    """

    logits: torch.Tensor
    offsets: torch.Tensor | None
    features: torch.Tensor | None
    voxel_logits: torch.Tensor
    point_to_voxel: torch.Tensor
    sizes: list[int]


class DSNet(nn.Module):
    """DS-Net's network without the shifting module (which lives in ``dsnet_core.instance.shifting``)."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        self.point_encoder = PointEncoder(9, config.point_mlp, config.compress)
        self.backbone = AsymmetricUNet(config.compress, config.width)
        self.sem_head = SemanticHead(self.backbone.out_channels, config.num_classes)
        self.ins_head = InstanceHead(self.backbone.out_channels, config.ins_dim)

    def forward(self, clouds: list[torch.Tensor], instance: bool = True) -> NetOutput:
        """Run the network.

        Args:
            clouds: float ``(N_b, 4)`` per cloud (x, y, z metres, remission), on the model's device.
            instance: also run the instance head.
        """
        vox = voxelize(clouds, self.config.grid)
        n_vox = vox.coords.shape[0]
        feats = self.point_encoder(vox.features, vox.point_to_voxel, n_vox)
        x = SparseTensor(feats, vox.coords, self.config.grid.size, vox.batch_size)
        fea = self.backbone(x)
        vlogits = self.sem_head(fea)
        logits = vlogits.index_select(0, vox.point_to_voxel)
        offsets = features = None
        if instance:
            xyz = torch.cat([c[:, :3] for c in clouds]).to(feats.dtype)
            offsets, features = self.ins_head(fea, vox.point_to_voxel, xyz)
        return NetOutput(logits, offsets, features, vlogits, vox.point_to_voxel, [len(c) for c in clouds])


def count_parameters(module: nn.Module) -> int:
    """Number of trainable and frozen parameters."""
    return sum(p.numel() for p in module.parameters())
