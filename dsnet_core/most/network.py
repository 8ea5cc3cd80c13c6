"""The MOST network on the project's backbone: point MLP (with the relative time as a 10th input)
→ cylinder U-Net → shared semantic head; one decoder level flattened to BEV → detection branch;
PointSegMLP on point–centre pairs.

Parameter names of the point encoder, backbone and semantic head are those of
:class:`~dsnet_core.model.network.DSNet`, so a DS-Net checkpoint's backbone loads into it
(:func:`load_backbone_from`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from dsnet_core.model.backbone import AsymmetricUNet
from dsnet_core.model.cylinder import voxelize
from dsnet_core.model.heads import PointEncoder, SemanticHead
from dsnet_core.model.sparse_conv import SparseTensor
from dsnet_core.most.bev import BevHead, BevOutput, flatten_height, level_shape, polar_sampling_grid
from dsnet_core.most.config import MostConfig
from dsnet_core.most.pointseg import PointSegMLP, pair_dim


@dataclass
class MostOutput:
    """Outputs of a batch (points concatenated in input order).

    Attributes:
        logits: float ``(N, C)`` per point (its voxel's semantic logits).
        voxel_logits: float ``(M, C)``.
        point_to_voxel: int64 ``(N,)``.
        point_features: float ``(N, 4w)`` backbone features ``F^point`` of each point's voxel.
        bev: the detection branch's :class:`BevOutput`.
        sizes: points per cloud.
    """

    logits: torch.Tensor
    voxel_logits: torch.Tensor
    point_to_voxel: torch.Tensor
    point_features: torch.Tensor
    bev: BevOutput
    sizes: list[int]


def level_channels(width: int, level: int) -> int:
    """Channels of the U-Net's decoder output at ``level`` (4 = the bottleneck)."""
    return {0: 2 * width, 1: 4 * width, 2: 8 * width, 3: 16 * width, 4: 16 * width}[level]


def unet_with_level(unet: AsymmetricUNet, x: SparseTensor, level: int) -> tuple[SparseTensor, SparseTensor]:
    """:meth:`AsymmetricUNet.forward` that also returns the decoder's output at ``level`` (the
    bottleneck itself for 4)."""
    x = unet.context(x)
    skips = []
    for block in unet.down:
        x, skip = block(x)
        skips.append(skip)
    picked = x
    for i, (block, skip) in enumerate(zip(unet.up, reversed(skips), strict=True)):
        x = block(x, skip)
        if 3 - i == level:
            picked = x
    refined = unet.recon(x)
    return x.with_features(torch.cat([refined.features, x.features], dim=1)), picked


class MostNet(nn.Module):
    """MOST (without the inference post-processing, in :mod:`dsnet_core.most.inference`)."""

    def __init__(self, config: MostConfig) -> None:
        super().__init__()
        self.config = config
        bb = config.backbone
        self.point_encoder = PointEncoder(config.in_features, bb.point_mlp, bb.compress)
        self.backbone = AsymmetricUNet(bb.compress, bb.width)
        self.sem_head = SemanticHead(self.backbone.out_channels, bb.num_classes)
        nz = level_shape(bb.grid.size, config.bev_level)[2]
        self.bev_head = BevHead(
            level_channels(bb.width, config.bev_level) * nz,
            config.bev_channels,
            config.num_things,
            polar_sampling_grid(bb.grid, config.bev_level, config.bev),
        )
        self.pointseg = PointSegMLP(
            pair_dim(bb.num_classes, self.backbone.out_channels, config.bev_channels), config.mem_widths
        )

    @property
    def point_dim(self) -> int:
        return self.backbone.out_channels

    def forward(self, clouds: list[torch.Tensor]) -> MostOutput:
        """Run backbone, semantic head and detection branch.

        Args:
            clouds: float ``(N_b, 5)`` per cloud: x, y, z (metres, current scan's frame),
                remission, relative time (seconds before the current scan; 0 for its points).
        """
        vox = voxelize([c[:, :4] for c in clouds], self.config.backbone.grid)
        feats = vox.features
        if self.config.time_feature:
            feats = torch.cat([feats, torch.cat([c[:, 4:5] for c in clouds]).to(feats.dtype)], dim=1)
        n_vox = vox.coords.shape[0]
        vfeat = self.point_encoder(feats, vox.point_to_voxel, n_vox)
        x = SparseTensor(vfeat, vox.coords, self.config.backbone.grid.size, vox.batch_size)
        fea, level = unet_with_level(self.backbone, x, self.config.bev_level)
        vlogits = self.sem_head(fea)
        bev = self.bev_head(flatten_height(level))
        return MostOutput(
            logits=vlogits.index_select(0, vox.point_to_voxel),
            voxel_logits=vlogits,
            point_to_voxel=vox.point_to_voxel,
            point_features=fea.features.index_select(0, vox.point_to_voxel),
            bev=bev,
            sizes=[len(c) for c in clouds],
        )


def load_backbone_from(model: MostNet, dsnet_state: dict[str, torch.Tensor]) -> list[str]:
    """Copy a DS-Net state dict's point encoder, backbone and semantic head into ``model``.

    The point encoder's first layers take 9 inputs in DS-Net and 10 here: the extra (time) input
    starts at weight 0 and BN statistics (mean 0, variance 1), so the copied network computes
    exactly what DS-Net did on the current scan's points.

    Returns:
        the names that were copied.
    """
    own = model.state_dict()
    copied = []
    for name, value in dsnet_state.items():
        if not name.startswith(("point_encoder.", "backbone.", "sem_head.")) or name not in own:
            continue
        target = own[name]
        if target.shape == value.shape:
            target.copy_(value)
        elif value.dim() >= 1 and target.shape[0] == value.shape[0] + 1 and value.dim() == 1:
            target[: value.shape[0]].copy_(value)  # input BatchNorm over 9 → 10 features
        elif value.dim() == 2 and target.shape[1] == value.shape[1] + 1:
            target.zero_()
            target[:, : value.shape[1]].copy_(value)  # first Linear: 9 → 10 inputs
        else:
            continue
        copied.append(name)
    model.load_state_dict(own)
    return copied
