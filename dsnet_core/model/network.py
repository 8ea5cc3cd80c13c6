"""The whole DS-Net network: voxelise → point MLP → cylinder U-Net → semantic and instance heads.

Two variants share it: the D-PLS instance network (``prior_channels > 0``: a semantic prior is
appended to every point's input, and without a semantic head its semantics are the prior's), and
the C_n-equivariant network (``equivariant = n > 1``, :mod:`dsnet_core.model.equivariant`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import nn

from dsnet_core.errors import ConfigError
from dsnet_core.model.backbone import AsymmetricUNet
from dsnet_core.model.cylinder import voxelize
from dsnet_core.model.equivariant import check_equivariant_grid, lift, pool, select_anchor
from dsnet_core.model.heads import InstanceHead, PointEncoder, SemanticHead
from dsnet_core.model.inputs import build_inputs
from dsnet_core.model.presets import ModelConfig
from dsnet_core.model.sparse_conv import SparseTensor


@dataclass
class NetOutput:
    """Per-point outputs of a batch (points concatenated in input order).

    Attributes:
        logits: float ``(N, num_classes)``, each point takes its voxel's logits (pooled over the
            rotations in the equivariant network); None without a semantic head.
        offsets: float ``(N, 3)`` metres, predicted point → instance centre (None if skipped).
        features: float ``(N, ins_dim)`` instance features (None if skipped).
        voxel_logits: float ``(M, num_classes)`` (None without a semantic head).
        point_to_voxel: int64 ``(N,)``.
        sizes: points per cloud.
        anchor_scores: float ``(N, n)`` the equivariant network's per-anchor scores (else None).
        anchor_offsets: float ``(N, n, 3)`` each anchor's offset in its own frame (else None).
    """

    logits: torch.Tensor | None
    offsets: torch.Tensor | None
    features: torch.Tensor | None
    voxel_logits: torch.Tensor | None
    point_to_voxel: torch.Tensor
    sizes: list[int]
    anchor_scores: torch.Tensor | None = None
    anchor_offsets: torch.Tensor | None = None


class DSNet(nn.Module):
    """DS-Net's network without the shifting module (which lives in ``dsnet_core.instance.shifting``)."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        check_equivariant_grid(config.grid, config.equivariant)
        self.config = config
        self.inputs = config.input_spec
        n_in = 9 + self.inputs.extra_channels + config.prior_channels
        self.point_encoder = PointEncoder(n_in, config.point_mlp, config.compress)
        self.backbone = AsymmetricUNet(
            config.compress, config.width, shared_rulebooks=config.rulebooks == "spconv1-shared"
        )
        self.sem_head = (
            SemanticHead(self.backbone.out_channels, config.num_classes) if config.semantic_head else None
        )
        self.ins_head = InstanceHead(self.backbone.out_channels, config.ins_dim)
        if config.equivariant > 1:  # eq. 9's scoring function φ on each copy's feature and position
            d = config.ins_dim
            self.anchor_head = nn.Sequential(nn.Linear(d + 3, d), nn.ReLU(), nn.Linear(d, 1))

    def forward(
        self, clouds: list[torch.Tensor], instance: bool = True, priors: list[torch.Tensor] | None = None
    ) -> NetOutput:
        """Run the network.

        Args:
            clouds: float ``(N_b, 4)`` per cloud (x, y, z metres, remission), on the model's device;
                the network builds its input channels from them (``config.inputs``,
                :func:`~dsnet_core.model.inputs.build_inputs`; remission dropout in training mode).
            instance: also run the instance head.
            priors: float ``(N_b, prior_channels)`` per cloud, the semantic prior (one-hot or class
                confidences) of a prior-conditioned network; None otherwise.
        """
        cfg = self.config
        clouds = build_inputs(clouds, self.inputs, cfg.remission_dropout, self.training)
        n, sizes = cfg.equivariant, [len(c) for c in clouds]
        total = sum(sizes)
        if n == 1:
            vox = voxelize(clouds, cfg.grid)
            xyz = torch.cat([c[:, :3] for c in clouds]).to(torch.float32)
        else:
            lifted = lift(clouds, cfg.grid, n)
            vox, xyz = lifted.vox, lifted.xyz
        point_in = vox.features
        if cfg.prior_channels:
            prior = self._prior(priors, sizes).to(point_in)
            point_in = torch.cat([point_in, prior.repeat(n, 1)], dim=1)
        elif priors is not None:
            raise ConfigError("this network takes no semantic prior (its card has prior_channels = 0)")
        n_vox = vox.coords.shape[0]
        feats = self.point_encoder(point_in, vox.point_to_voxel, n_vox)
        x = SparseTensor(feats, vox.coords, cfg.grid.size, vox.batch_size)
        fea = self.backbone(x)
        ptv0 = vox.point_to_voxel[:total]
        logits = vlogits = None
        if self.sem_head is not None:
            vlogits = self.sem_head(fea)
            if n == 1:
                logits = vlogits.index_select(0, ptv0)
            else:
                per_copy = vlogits.index_select(0, vox.point_to_voxel).view(n, total, -1)
                logits = pool(per_copy, cfg.pooling)
                vlogits = _copy0_voxels(logits, ptv0)
        out = NetOutput(logits, None, None, vlogits, ptv0, sizes)
        if instance:
            offsets, features = self.ins_head(fea, vox.point_to_voxel, xyz.to(feats.dtype))
            if n == 1:
                out.offsets, out.features = offsets, features
            else:
                per_xyz = xyz.to(feats.dtype).view(n, total, 3).transpose(0, 1)
                offsets = offsets.view(n, total, 3).transpose(0, 1)
                features = features.view(n, total, -1).transpose(0, 1)
                scores = self.anchor_head(torch.cat([features, per_xyz], dim=2))[..., 0]
                out.offsets, out.features, _ = select_anchor(scores, offsets, features)
                out.anchor_scores, out.anchor_offsets = scores, offsets
        return out

    def _prior(self, priors: list[torch.Tensor] | None, sizes: list[int]) -> torch.Tensor:
        want = self.config.prior_channels
        if priors is None or len(priors) != len(sizes):
            raise ConfigError(
                f"this prior-conditioned network needs one (N, {want}) semantic prior per cloud "
                f"({len(sizes)} clouds, {0 if priors is None else len(priors)} priors)"
            )
        for i, (p, n) in enumerate(zip(priors, sizes, strict=True)):
            if tuple(p.shape) != (n, want):
                raise ConfigError(f"prior of cloud {i} has shape {tuple(p.shape)}, expected ({n}, {want})")
        return torch.cat(list(priors))


def _copy0_voxels(point_values: torch.Tensor, ptv0: torch.Tensor) -> torch.Tensor:
    """Per-point values that are constant within each copy-0 voxel → ``(M0, C)`` per voxel."""
    m0 = int(ptv0.max()) + 1 if ptv0.numel() else 0
    rep = torch.zeros(m0, dtype=torch.int64, device=ptv0.device)
    rep.scatter_(0, ptv0, torch.arange(ptv0.numel(), device=ptv0.device))
    return point_values.index_select(0, rep)


def count_parameters(module: nn.Module) -> int:
    """Number of trainable and frozen parameters."""
    return sum(p.numel() for p in module.parameters())


def lift_model(model: torch.nn.Module, n: int, pooling: str = "mean") -> torch.nn.Module:
    """A plain trained DS-Net lifted to C_n: the same weights shared by the n rotated copies (its
    semantics start as the mean (or max) over n rotations, i.e. ``--tta n`` without flips), and a
    fresh anchor scorer (eq. 9) for the offsets, to be fine-tuned (``dsnet train dsnet --init-from PLAIN
    --equivariant n``).

    Raises:
        ConfigError: ``model`` is already equivariant, or its grid does not allow n.
    """
    if model.config.equivariant != 1:
        raise ConfigError(f"--equivariant {n}: the --init-from model is already C_{model.config.equivariant}")
    lifted = DSNet(replace(model.config, equivariant=n, pooling=pooling)).to(next(model.parameters()).device)
    missing, unexpected = lifted.load_state_dict(model.state_dict(), strict=False)
    fresh = [k for k in missing if not k.startswith("anchor_head.")]
    if fresh or unexpected:  # only the anchor scorer is new
        raise ConfigError(f"cannot lift this model to C_{n}: missing {fresh}, unexpected {unexpected}")
    return lifted
