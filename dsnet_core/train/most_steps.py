"""The two MOST training losses and their validation, one sample at a time.

- ``detect`` (stage 1, eq. 1 + 2 + 4): semantic loss on the current scan's voxels, focal loss on
  the centre heatmaps, L1 on offset/height/extent/velocity at the centre cells.
- ``member`` (stage 2, eq. 3): BCE of PointSegMLP on point–centre pairs of ground-truth modal
  centres (jittered) with their MAX extents, inside the RoIs, everything else frozen.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from dsnet_core.model.losses import semantic_loss, voxel_labels
from dsnet_core.most.bev import sample_bev
from dsnet_core.most.data import MostSample
from dsnet_core.most.heatmap import bev_targets
from dsnet_core.most.inference import Detections, decode_heatmap, roi_pairs
from dsnet_core.most.losses import REGRESS_WEIGHTS, focal_loss, regression_losses
from dsnet_core.most.network import MostNet, MostOutput
from dsnet_core.most.pointseg import PairInputs, pair_features
from dsnet_core.most.targets import ObjectTargets, transform_targets


@dataclass(frozen=True)
class Augmentation:
    """A yaw rotation, flips and scale (``linear``), a translation ``shift`` (m) and ``z_scale``."""

    linear: np.ndarray
    shift: np.ndarray
    z_scale: float

    @classmethod
    def draw(cls, rng: np.random.Generator, translate_std: float = 0.1) -> Augmentation:
        theta = rng.uniform(0.0, 2 * np.pi)
        c, s = np.cos(theta), np.sin(theta)
        a = np.array([[c, -s], [s, c]])
        flip = np.diag([-1.0 if rng.random() < 0.5 else 1.0, -1.0 if rng.random() < 0.5 else 1.0])
        scale = rng.uniform(0.95, 1.05)
        return cls(flip @ a * scale, rng.normal(0.0, translate_std, 3), float(scale))

    def apply(self, sample: MostSample) -> MostSample:
        pts = sample.points.copy()
        pts[:, :2] = (pts[:, :2].astype(np.float64) @ self.linear.T + self.shift[:2]).astype(np.float32)
        pts[:, 2] = (pts[:, 2] * self.z_scale + self.shift[2]).astype(np.float32)
        tg = transform_targets(sample.targets, self.linear, self.shift, self.z_scale)
        return MostSample(pts, sample.n_current, sample.sem, sample.keys, tg, sample.name)


def detect_loss(
    net: MostNet, samples: list[MostSample], weights: torch.Tensor, device: torch.device
) -> tuple[torch.Tensor, dict[str, float]]:
    """Stage 1 loss of a batch and its terms; ``net`` may be the model's DDP wrapper."""
    clouds = [torch.from_numpy(s.points).to(device) for s in samples]
    out = net(clouds)
    sem = np.concatenate([np.r_[s.sem, np.zeros(len(s.points) - s.n_current, np.int64)] for s in samples])
    sem_t = torch.from_numpy(sem).to(device)
    n_vox, n_cls = out.voxel_logits.shape
    terms = {
        "semantic": semantic_loss(
            out.voxel_logits, voxel_labels(out.point_to_voxel, sem_t, n_vox, n_cls), weights
        )
    }
    cfg = getattr(net, "module", net).config  # a DDP wrapper's model
    heat, regs = [], {k: [] for k in REGRESS_WEIGHTS}
    for b, s in enumerate(samples):
        tg = bev_targets(s.targets, cfg.bev, cfg.things)
        heat.append(torch.from_numpy(tg.heatmap))
        targets = {
            "offset": torch.from_numpy(tg.offset).to(device),
            "height": torch.from_numpy(tg.height[:, None]).to(device),
            "extent": torch.from_numpy(tg.extent).to(device),
            "velocity": torch.from_numpy(tg.velocity).to(device),
        }
        idx = torch.from_numpy(tg.index).to(device)
        for k, v in regression_losses(
            out.bev.regress[b], idx, targets, torch.from_numpy(tg.vel_mask).to(device)
        ).items():
            regs[k].append(v)
    terms["heatmap"] = focal_loss(out.bev.heatmap, torch.stack(heat).to(device))
    for k, vals in regs.items():
        terms[k] = torch.stack(vals).mean()
    total = terms["semantic"] + terms["heatmap"] + sum(REGRESS_WEIGHTS[k] * terms[k] for k in REGRESS_WEIGHTS)
    return total, {k: float(v.detach()) for k, v in terms.items()}


def jittered_detections(t: ObjectTargets, rng: np.random.Generator, jitter: float) -> Detections:
    """Ground-truth objects as detections: centres moved by N(0, jitter) (z by half), extents
    scaled by U(0.9, 1.3), all with confidence 1 (in key order)."""
    n = len(t)
    c = t.centres + rng.normal(0.0, jitter, (n, 3)) * [1.0, 1.0, 0.5]
    r = t.extents * rng.uniform(0.9, 1.3, (n, 1))
    return Detections(c, t.classes.copy(), np.ones(n), r, t.velocity.copy())


def member_pairs(
    net: MostNet,
    out: MostOutput,
    sample: MostSample,
    det: Detections,
    rng: np.random.Generator,
    cap: int,
    b: int = 0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pair features ``(P, D)`` and membership targets ``(P,)`` of one sample's RoIs (at most
    ``cap`` random pairs per detection). Every point of a RoI is a candidate, whatever its
    predicted class: inference keeps only those of the detection's class, a subset, and the MLP
    sees the predicted class distribution of each point."""
    start = sum(out.sizes[:b])
    n = sample.n_current
    logits = out.logits[start : start + n]
    d, p = roi_pairs(sample.points[:n, :3].astype(np.float64), None, det)
    if cap and d.size:
        keep = np.zeros(d.size, bool)
        for j in np.unique(d):
            idx = np.flatnonzero(d == j)
            keep[rng.choice(idx, min(cap, idx.size), replace=False)] = True
        d, p = d[keep], p[keep]
    dev = logits.device
    xyz = torch.from_numpy(sample.points[:n, :3]).to(dev)
    bev = out.bev.features[b]
    dt, pt = torch.from_numpy(d).to(dev), torch.from_numpy(p).to(dev)
    centres = torch.as_tensor(det.centres, dtype=xyz.dtype, device=dev)
    pxyz = xyz.index_select(0, pt)
    pairs = PairInputs(
        pxyz,
        torch.softmax(logits, 1).index_select(0, pt),
        out.point_features[start : start + n].index_select(0, pt),
        sample_bev(bev, pxyz[:, :2], net.config.bev),
        centres.index_select(0, dt),
        torch.as_tensor(det.classes, device=dev).index_select(0, dt),
        sample_bev(bev, centres[:, :2], net.config.bev).index_select(0, dt)
        if len(det)
        else bev.new_zeros((0, bev.shape[0])),
        torch.as_tensor(det.extents, dtype=xyz.dtype, device=dev).index_select(0, dt),
    )
    target = torch.from_numpy(sample.keys[p] == sample.targets.keys[d]).to(dev)
    return pair_features(pairs, net.config.backbone.num_classes), target


def match_detections(det: Detections, t: ObjectTargets, radius: float = 1.0) -> list[tuple[int, int]]:
    """Greedy matches (detection, object) of one class within ``radius`` metres in (x, y), most
    confident detection first."""
    used: set[int] = set()
    out = []
    for d in range(len(det)):
        dist = np.linalg.norm(t.centres[:, :2] - det.centres[d, :2], axis=1) if len(t) else np.zeros(0)
        dist[t.classes != det.classes[d]] = np.inf
        for m in np.argsort(dist).tolist():
            if dist[m] > radius:
                break
            if m not in used:
                used.add(m)
                out.append((d, m))
                break
    return out


def detection_stats(det: Detections, t: ObjectTargets) -> dict[str, float]:
    """Counts and error sums of one scan: matches, detections, objects, centre/extent/velocity L1."""
    matches = match_detections(det, t)
    d = np.array([a for a, _ in matches], np.int64)
    m = np.array([b for _, b in matches], np.int64)
    vm = t.has_velocity[m] if m.size else np.zeros(0, bool)
    return {
        "tp": float(len(matches)),
        "det": float(len(det)),
        "obj": float(len(t)),
        "centre_err": float(np.linalg.norm(det.centres[d] - t.centres[m], axis=1).sum()) if m.size else 0.0,
        "extent_err": float(np.abs(det.extents[d] - t.extents[m]).sum(1).sum()) if m.size else 0.0,
        "vel_err": float(np.abs(det.velocity[d][vm] - t.velocity[m][vm]).sum(1).sum()) if vm.any() else 0.0,
        "vel_n": float(vm.sum()),
    }


def decode_sample(net: MostNet, out: MostOutput, b: int = 0, threshold: float = 0.3) -> Detections:
    return decode_heatmap(
        out.bev.heatmap[b], out.bev.regress[b], net.config.bev, net.config.things, threshold
    )
