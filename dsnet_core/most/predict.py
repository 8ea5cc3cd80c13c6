"""One scan through MOST: network → detections → memberships → panoptic labels of the current scan.

The current scan's points are the first ``n_current`` points of the accumulated cloud
(:func:`dsnet_core.most.data.accumulate` puts them first); only they are labelled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from dsnet_core.most.bev import sample_bev
from dsnet_core.most.inference import (
    Detections,
    Membership,
    assign_instances,
    decode_heatmap,
    distance_membership,
    roi_pairs,
)
from dsnet_core.most.network import MostNet, MostOutput
from dsnet_core.most.pointseg import PairInputs, pair_features

RULES = ("mlp", "distance")


@dataclass(frozen=True)
class InferenceSettings:
    """Knobs of MOST's post-processing.

    Attributes:
        rule: membership function, ``mlp`` (PointSegMLP) or ``distance`` (nearest centre in the RoI).
        score_threshold: minimum heatmap confidence of a detection.
        max_detections: per scan.
        roi_scale, roi_margin: RoI half-size ``scale · r̂ + margin`` (metres).
        member_threshold: PointSegMLP probability above which a point is a member.
    """

    rule: str = "mlp"
    score_threshold: float = 0.3
    max_detections: int = 200
    roi_scale: float = 1.1
    roi_margin: float = 0.2
    member_threshold: float = 0.5

    def __post_init__(self) -> None:
        if self.rule not in RULES:
            raise ValueError(f"unknown membership rule '{self.rule}' (choose {', '.join(RULES)})")


@dataclass(frozen=True)
class MostPrediction:
    """Panoptic labels of one scan.

    Attributes:
        semantic: int64 ``(n,)`` train ids of the current scan's points.
        instance: int64 ``(n,)`` instance ids 1..I (0 = none).
        detections: the detection of each instance (row ``i − 1`` for id ``i``): centre, class,
            confidence, extent, velocity — the tracker's input.
    """

    semantic: np.ndarray
    instance: np.ndarray
    detections: Detections


def mlp_membership(
    net: MostNet, out: MostOutput, xyz: torch.Tensor, det: Detections, sample: int = 0
) -> Membership:
    """PointSegMLP's membership probabilities for pairs of ``det`` and the sample's points.

    Args:
        out: the network's output on the batch; ``sample`` picks the cloud.
        xyz: float ``(n, 3)`` the points that pairs index (the first points of the cloud).
    """
    start = sum(out.sizes[:sample])
    n = xyz.shape[0]
    probs = torch.softmax(out.logits[start : start + n].float(), dim=1)
    feat = out.point_features[start : start + n]
    bev = out.bev.features[sample]
    dev = xyz.device
    centres = torch.as_tensor(det.centres, dtype=xyz.dtype, device=dev)
    classes = torch.as_tensor(det.classes, dtype=torch.int64, device=dev)
    extents = torch.as_tensor(det.extents, dtype=xyz.dtype, device=dev)
    centre_bev = (
        sample_bev(bev, centres[:, :2], net.config.bev) if len(det) else bev.new_zeros((0, bev.shape[0]))
    )

    def score(d: np.ndarray, p: np.ndarray) -> np.ndarray:
        dt, pt = torch.from_numpy(d).to(dev), torch.from_numpy(p).to(dev)
        pxyz = xyz.index_select(0, pt)
        pairs = PairInputs(
            pxyz,
            probs.index_select(0, pt),
            feat.index_select(0, pt),
            sample_bev(bev, pxyz[:, :2], net.config.bev),
            centres.index_select(0, dt),
            classes.index_select(0, dt),
            centre_bev.index_select(0, dt),
            extents.index_select(0, dt),
        )
        with torch.no_grad():
            logits = net.pointseg(pair_features(pairs, net.config.backbone.num_classes))
        return torch.sigmoid(logits).double().cpu().numpy()

    return score


def panoptic(
    xyz: np.ndarray,
    semantic: np.ndarray,
    det: Detections,
    settings: InferenceSettings,
    mlp: Membership | None = None,
) -> MostPrediction:
    """Memberships and instances of one scan given its semantics and detections.

    Args:
        xyz: float ``(n, 3)``; semantic: int ``(n,)`` train ids.
        det: detections in decreasing confidence.
        mlp: PointSegMLP's membership (required for ``rule="mlp"``).
    """
    pairs = roi_pairs(xyz, semantic, det, settings.roi_scale, settings.roi_margin)
    if settings.rule == "mlp":
        if mlp is None:
            raise ValueError("the mlp rule needs PointSegMLP's membership function")
        instance, used = assign_instances(len(xyz), pairs, mlp, settings.member_threshold)
    else:
        instance, used = assign_instances(len(xyz), pairs, distance_membership(xyz, det), 0.0)
    return MostPrediction(np.asarray(semantic, np.int64), instance, det.take(used))


def predict(
    net: MostNet, cloud: torch.Tensor, n_current: int, settings: InferenceSettings | None = None
) -> MostPrediction:
    """Label the current scan of one accumulated cloud.

    Args:
        cloud: float ``(N, 5)`` (x, y, z, remission, relative time), current scan first.
        n_current: points of the current scan.
    """
    settings = settings or InferenceSettings()
    net.eval()
    with torch.inference_mode():
        out = net([cloud])
        sem = (out.logits[:n_current, 1:].argmax(1) + 1).cpu().numpy().astype(np.int64)
        det = decode_heatmap(
            out.bev.heatmap[0],
            out.bev.regress[0],
            net.config.bev,
            net.config.things,
            settings.score_threshold,
            settings.max_detections,
        )
        xyz = cloud[:n_current, :3]
        mlp = mlp_membership(net, out, xyz, det) if settings.rule == "mlp" else None
        return panoptic(xyz.cpu().numpy().astype(np.float64), sem, det, settings, mlp)
