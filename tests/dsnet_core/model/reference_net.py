"""A reconstruction of the released reference networks in spconv 2.x, for the importer's tests.

Written from the public description and module naming of hongfz16/DS-Net and xinge008/Cylinder3D
(facts, not their code): the module tree below has the reference's parameter names, and its state
dict is what the reference would save. Its forward follows the reference's order of operations
(convolution → LeakyReLU → BatchNorm in the blocks, BatchNorm → sigmoid in the refinement, BN →
LeakyReLU in the instance head) and its data loader's arithmetic (float32 polar coordinates,
cells and centres in float64, cell (max − min) / (n − 1)).

``spconv1=True`` reproduces how spconv 1.x, which the reference was trained with, runs it: layers
sharing an ``indice_key`` reuse the first layer's rulebook. spconv 2.x refuses that (it checks the
kernel sizes), so the forward hands such a layer to spconv as a layer with the first layer's kernel
and the flat taps of its own weight, which is what spconv 1.x computes. ``spconv1=False`` runs every
layer with its own kernel (how a network trained under spconv 2.x runs).

spconv's CPU path: forward only, one torch thread (its CPU kernels are wrong with more).
"""

from __future__ import annotations

import math

import numpy as np
import spconv.pytorch as spconv
import torch
from torch import nn

K133, K313, K333 = (1, 3, 3), (3, 1, 3), (3, 3, 3)


def subm(cin: int, cout: int, kernel, bias: bool = False) -> spconv.SubMConv3d:
    kernel = (kernel,) * 3 if isinstance(kernel, int) else kernel
    return spconv.SubMConv3d(cin, cout, kernel, padding=tuple(k // 2 for k in kernel), bias=bias)


class Run:
    """State of one forward: which kernel each ``indice_key`` was first built with."""

    def __init__(self, spconv1: bool) -> None:
        self.spconv1 = spconv1
        self.first: dict[str, tuple] = {}

    def conv(self, layer: spconv.SubMConv3d, x: spconv.SparseConvTensor, key: str) -> spconv.SparseConvTensor:
        """Run submanifold ``layer`` as the chosen spconv would; its bias is added here (spconv's
        CPU path refuses a bias)."""
        kernel = tuple(layer.kernel_size)
        first = self.first.setdefault(key, kernel) if self.spconv1 else kernel
        w = layer.weight  # (out, *kernel, in)
        flat = w.permute(1, 2, 3, 4, 0).reshape(-1, w.shape[-1], w.shape[0])[: math.prod(first)]
        run = spconv.SubMConv3d(
            layer.in_channels,
            layer.out_channels,
            first,
            padding=tuple(k // 2 for k in first),
            bias=False,
            indice_key=key if self.spconv1 else None,
        )
        run.weight.data = flat.reshape(*first, w.shape[-1], w.shape[0]).permute(4, 0, 1, 2, 3).contiguous()
        out = run(x)
        return out.replace_feature(out.features + layer.bias) if layer.bias is not None else out


def act_bn(x: spconv.SparseConvTensor, bn: nn.BatchNorm1d) -> spconv.SparseConvTensor:
    return x.replace_feature(bn(nn.functional.leaky_relu(x.features)))


class ContextBlock(nn.Module):
    """``downCntx`` (first 1×3×3) or the residual part of ``resBlockN`` (first 3×1×3)."""

    def __init__(self, cin: int, cout: int, first, second, key: str, pool_stride=None, pool_key=None):
        super().__init__()
        self.key = key
        self.conv1, self.bn0 = subm(cin, cout, first), nn.BatchNorm1d(cout)
        self.conv1_2, self.bn0_2 = subm(cout, cout, second), nn.BatchNorm1d(cout)
        self.conv2, self.bn1 = subm(cin, cout, second), nn.BatchNorm1d(cout)
        self.conv3, self.bn2 = subm(cout, cout, first), nn.BatchNorm1d(cout)
        if pool_stride is not None:
            self.pool = spconv.SparseConv3d(
                cout, cout, 3, stride=pool_stride, padding=1, bias=False, indice_key=pool_key
            )

    def forward(self, x, run: Run):
        k = self.key
        a = act_bn(run.conv(self.conv1_2, act_bn(run.conv(self.conv1, x, k), self.bn0), k), self.bn0_2)
        b = act_bn(run.conv(self.conv3, act_bn(run.conv(self.conv2, x, k), self.bn1), k), self.bn2)
        res = b.replace_feature(b.features + a.features)
        return (self.pool(res), res) if hasattr(self, "pool") else res


class Up(nn.Module):
    def __init__(self, cin: int, cout: int, key: str, up_key: str):
        super().__init__()
        self.key = key
        self.trans_dilao, self.trans_bn = subm(cin, cout, 3), nn.BatchNorm1d(cout)
        self.conv1, self.bn1 = subm(cout, cout, K133), nn.BatchNorm1d(cout)
        self.conv2, self.bn2 = subm(cout, cout, K313), nn.BatchNorm1d(cout)
        self.conv3, self.bn3 = subm(cout, cout, K333), nn.BatchNorm1d(cout)
        self.up_subm = spconv.SparseInverseConv3d(cout, cout, 3, bias=False, indice_key=up_key)

    def forward(self, x, skip, run: Run):
        up = self.up_subm(act_bn(run.conv(self.trans_dilao, x, self.key + "new_up"), self.trans_bn))
        up = up.replace_feature(up.features + skip.features)
        for conv, bn in ((self.conv1, self.bn1), (self.conv2, self.bn2), (self.conv3, self.bn3)):
            up = act_bn(run.conv(conv, up, self.key), bn)
        return up


class Recon(nn.Module):
    def __init__(self, c: int):
        super().__init__()
        self.conv1, self.bn0 = subm(c, c, (3, 1, 1)), nn.BatchNorm1d(c)
        self.conv1_2, self.bn0_2 = subm(c, c, (1, 3, 1)), nn.BatchNorm1d(c)
        self.conv1_3, self.bn0_3 = subm(c, c, (1, 1, 3)), nn.BatchNorm1d(c)

    def forward(self, x, run: Run):
        gate = sum(
            torch.sigmoid(bn(run.conv(conv, x, "reconbef").features))
            for conv, bn in ((self.conv1, self.bn0), (self.conv1_2, self.bn0_2), (self.conv1_3, self.bn0_3))
        )
        return x.replace_feature(gate * x.features)


class Backbone(nn.Module):
    def __init__(self, w: int, cin: int = 16, classes: int | None = None):
        super().__init__()
        self.downCntx = ContextBlock(cin, w, K133, K313, "prebef")
        chans = ((w, 2 * w, 2), (2 * w, 4 * w, 2), (4 * w, 8 * w, (2, 2, 1)), (8 * w, 16 * w, (2, 2, 1)))
        for i, (a, b, s) in enumerate(chans):
            setattr(
                self, f"resBlock{i + 2}", ContextBlock(a, b, K313, K133, f"down{i + 2}bef", s, f"down{i + 2}")
            )
        ups = ((16 * w, 16 * w), (16 * w, 8 * w), (8 * w, 4 * w), (4 * w, 2 * w))
        for i, (a, b) in enumerate(ups):
            setattr(self, f"upBlock{i}", Up(a, b, f"up{i}", f"down{5 - i}"))
        self.ReconNet = Recon(2 * w)
        if classes is not None:  # Cylinder3D keeps the logits inside the segmentation network
            self.logits = subm(4 * w, classes, 3, bias=True)

    def forward(self, x, run: Run):
        x = self.downCntx(x, run)
        skips = []
        for i in range(2, 6):
            x, skip = getattr(self, f"resBlock{i}")(x, run)
            skips.append(skip)
        for i in range(4):
            x = getattr(self, f"upBlock{i}")(x, skips[3 - i], run)
        return x.replace_feature(torch.cat([self.ReconNet(x, run).features, x.features], dim=1))


def pp_model(widths) -> nn.Sequential:
    layers: list[nn.Module] = [nn.BatchNorm1d(9)]
    prev = 9
    for d in widths[:-1]:
        layers += [nn.Linear(prev, d), nn.BatchNorm1d(d), nn.ReLU()]
        prev = d
    return nn.Sequential(*layers, nn.Linear(prev, widths[-1]))


class InsHead(nn.Module):
    def __init__(self, w: int):
        super().__init__()
        self.conv1, self.bn1 = subm(4 * w, 4 * w, 3), nn.BatchNorm1d(4 * w)
        self.conv2, self.bn2 = subm(4 * w, 2 * w, 3), nn.BatchNorm1d(2 * w)
        self.conv3, self.bn3 = subm(2 * w, w, 3), nn.BatchNorm1d(w)
        self.offset = nn.Sequential(nn.Linear(w + 3, w), nn.BatchNorm1d(w), nn.ReLU())
        self.offset_linear = nn.Linear(w, 3)


class SemHead(nn.Module):
    def __init__(self, w: int, classes: int):
        super().__init__()
        self.logits = subm(4 * w, classes, 3, bias=True)


class Meanshift(nn.Module):
    def __init__(self, w: int, iterations: int = 4, n_bw: int = 3):
        super().__init__()
        self.learnable_bandwidth_weights_layer_list = nn.ModuleList(
            nn.Sequential(nn.Linear(w, w), nn.BatchNorm1d(w), nn.ReLU(), nn.Linear(w, n_bw))
            for _ in range(iterations)
        )


class DSNetReference(nn.Module):
    """DS-Net's ``PolarOffsetSpconvPytorchMeanshift`` names: ``fea_compression``, ``backbone``,
    ``sem_head``, ``ins_head``, ``vfe_model.PPmodel``, ``pytorch_meanshift``, and its semantic loss
    registered as a submodule (``sem_loss``, a class-weighted cross entropy: a training-only buffer
    in every file it saves). ``meanshift=False``: ``PolarOffsetSpconv`` (the offset-pretrained
    step, no shifting MLPs)."""

    def __init__(
        self,
        w: int = 32,
        classes: int = 20,
        point_mlp=(64, 128, 256, 64),
        compress: int = 16,
        meanshift: bool = True,
    ):
        super().__init__()
        self.fea_compression = nn.Sequential(nn.Linear(point_mlp[-1], compress), nn.ReLU())
        self.backbone = Backbone(w, compress)
        self.sem_head = SemHead(w, classes)
        self.ins_head = InsHead(w)
        self.vfe_model = nn.Module()
        self.vfe_model.PPmodel = pp_model(point_mlp)
        self.sem_loss = nn.CrossEntropyLoss(weight=torch.ones(classes), ignore_index=0)
        if meanshift:
            self.pytorch_meanshift = Meanshift(w)

    def forward(self, points: np.ndarray, grid, run: Run):
        """One scan ``(N, 4)`` float32 → per-point logits ``(N, C)`` and offsets ``(N, 3)``."""
        cells, feats = reference_features(points, grid)
        fea, p2v = _voxel_net(
            self.vfe_model.PPmodel, self.fea_compression, self.backbone, cells, feats, grid, run
        )
        logits = run.conv(self.sem_head.logits, fea, "logit").features
        h = self.ins_head
        x = fea
        for j, (conv, bn) in enumerate(((h.conv1, h.bn1), (h.conv2, h.bn2), (h.conv3, h.bn3))):
            x = run.conv(conv, x, f"offset_head_conv{j + 1}")
            x = x.replace_feature(nn.functional.leaky_relu(bn(x.features)))
        xyz = torch.from_numpy(points[:, :3].astype(np.float32))
        offsets = h.offset_linear(h.offset(torch.cat([x.features[p2v], xyz], dim=1)))
        return logits[p2v], offsets


class Cylinder3DReference(nn.Module):
    """Cylinder3D's ``cylinder_asym`` names: ``cylinder_3d_generator`` (``PPmodel``,
    ``fea_compression``) and ``cylinder_3d_spconv_seg`` (backbone and ``logits``)."""

    def __init__(self, w: int = 32, classes: int = 20, point_mlp=(64, 128, 256, 256), compress: int = 16):
        super().__init__()
        self.cylinder_3d_generator = nn.Module()
        self.cylinder_3d_generator.PPmodel = pp_model(point_mlp)
        self.cylinder_3d_generator.fea_compression = nn.Sequential(
            nn.Linear(point_mlp[-1], compress), nn.ReLU()
        )
        self.cylinder_3d_spconv_seg = Backbone(w, compress, classes)

    def forward(self, points: np.ndarray, grid, run: Run):
        gen, seg = self.cylinder_3d_generator, self.cylinder_3d_spconv_seg
        cells, feats = reference_features(points, grid)
        fea, p2v = _voxel_net(gen.PPmodel, gen.fea_compression, seg, cells, feats, grid, run)
        return run.conv(seg.logits, fea, "logit").features[p2v], None


def reference_features(points: np.ndarray, grid) -> tuple[np.ndarray, np.ndarray]:
    """The reference loader's cells and 9 features of one float32 scan (numpy, like the loader);
    ``grid.convention == "ours"`` swaps in cell (max − min) / n and the clamp to n − 1."""
    xyz, sig = points[:, :3], points[:, 3]
    pol = np.stack(
        (np.sqrt(xyz[:, 0] ** 2 + xyz[:, 1] ** 2), np.arctan2(xyz[:, 1], xyz[:, 0]), xyz[:, 2]), axis=1
    )
    lo, hi, size = np.asarray(grid.min_bound), np.asarray(grid.max_bound), np.asarray(grid.size)
    cut = 1 if grid.convention == "reference" else 0
    intervals = (hi - lo) / (size - cut)
    cells = np.floor((np.clip(pol, lo, hi) - lo) / intervals).astype(np.int64)
    cells = np.minimum(cells, size - 1)
    centres = (cells.astype(np.float32) + 0.5) * intervals + lo
    feats = np.concatenate((pol - centres, pol, xyz[:, :2], sig[:, None]), axis=1)
    return cells, feats.astype(np.float32)


def _voxel_net(mlp, compression, backbone, cells, feats, grid, run):
    unique, p2v = np.unique(cells, axis=0, return_inverse=True)
    p2v = torch.from_numpy(p2v.reshape(-1))
    pt = mlp(torch.from_numpy(feats))
    pooled = pt.new_full((len(unique), pt.shape[1]), -torch.inf).scatter_reduce(
        0, p2v[:, None].expand(-1, pt.shape[1]), pt, "amax"
    )
    coords = torch.from_numpy(np.concatenate([np.zeros((len(unique), 1), np.int64), unique], 1)).int()
    x = spconv.SparseConvTensor(compression(pooled), coords, list(grid.size), 1)
    return backbone(x, run), p2v


def randomize(module: nn.Module, seed: int = 0) -> nn.Module:
    """Random weights and BatchNorm statistics (so that every BN does something), eval mode."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, t in module.state_dict().items():
            if name.endswith("num_batches_tracked"):
                t.fill_(7)
            elif name.endswith("running_var"):
                t.copy_(0.5 + torch.rand(t.shape, generator=g))
            elif name.endswith(("running_mean", "bias")):
                t.copy_(0.1 * torch.randn(t.shape, generator=g))
            elif t.dim() == 1:  # BN weight
                t.copy_(0.5 + torch.rand(t.shape, generator=g))
            else:
                fan_in = t[0].numel() if t.dim() == 2 else t.shape[-1] * math.prod(t.shape[1:4])
                t.copy_(torch.randn(t.shape, generator=g) / math.sqrt(fan_in))
    return module.eval()


def spconv1_state(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The same weights in spconv 1.x layout: every 5-d weight (out, *k, in) → (*k, in, out)."""
    return {k: v.permute(1, 2, 3, 4, 0).contiguous() if v.dim() == 5 else v for k, v in state.items()}
