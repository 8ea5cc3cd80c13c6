"""Oracle MOST: ground-truth semantics, modal centres, MAX extents and velocities stand in for the
network's predictions; everything after them is the real inference path — RoIs, memberships
(PointSegMLP of a trained network, or the distance rule), overlap resolution, then the tracker
with the (ground-truth) velocities.

With perfect detections the remaining errors are the membership function's and the tracker's, so
PQ^Th and LSTQ close to 1 show that the post-processing does not lose what the network gives it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from dsnet_core.labels import LabelMap
from dsnet_core.most.data import accumulate, instance_keys
from dsnet_core.most.inference import Detections
from dsnet_core.most.network import MostNet
from dsnet_core.most.predict import InferenceSettings, mlp_membership, panoptic
from dsnet_core.most.targets import ObjectTargets, frame_objects, sequence_targets
from dsnet_core.temporal.tracking import Tracker, relabel


def oracle_detections(targets: ObjectTargets) -> Detections:
    """Ground-truth objects as detections (confidence 1, in key order)."""
    n = len(targets)
    return Detections(targets.centres, targets.classes, np.ones(n), targets.extents, targets.velocity)


def oracle_most(
    scans: Sequence[np.ndarray],
    labels: Sequence[np.ndarray],
    poses: np.ndarray,
    label_map: LabelMap,
    rule: str = "distance",
    net: MostNet | None = None,
    k: int = 3,
    times: Sequence[float] | None = None,
    min_points: int = 1,
    learned_velocity: bool = True,
    **tracker_kwargs,
) -> list[np.ndarray]:
    """Per-frame uint32 labels (raw semantic | track id << 16) of a sequence.

    Args:
        scans: per frame float32 ``(N_f, 4)``; labels: per frame uint32 ``(N_f,)``.
        poses: ``(F, 4, 4)`` LiDAR-frame poses. times: seconds (default 0.1 s per frame).
        rule: ``distance`` or ``mlp`` (then ``net`` runs on each frame's ``k``-scan input for the
            features PointSegMLP reads).
        min_points: instances with fewer points are not detected.
        learned_velocity: hand the (ground-truth) velocities to the tracker; else it predicts with
            its constant-velocity model.
    """
    times = list(np.arange(len(scans)) * 0.1 if times is None else times)
    sem_keys = [instance_keys(lab, label_map) for lab in labels]
    objs = [frame_objects(s[:, :3], keys, min_points) for s, (_, keys) in zip(scans, sem_keys, strict=True)]
    targets = sequence_targets(objs, poses, times)
    settings = InferenceSettings(rule=rule)
    tracker = Tracker(label_map, **tracker_kwargs)
    out = []
    for f, (scan, (sem, _)) in enumerate(zip(scans, sem_keys, strict=True)):
        det = oracle_detections(targets[f])
        mlp = None
        if rule == "mlp":
            if net is None:
                raise ValueError("the mlp rule needs a trained MOST network")
            first = max(0, f - k + 1)
            cloud, n = accumulate(
                list(scans[first : f + 1]), list(poses[first : f + 1]), times[first : f + 1]
            )
            net.eval()
            with torch.inference_mode():
                xyz = torch.from_numpy(cloud[:n, :3])
                mlp = mlp_membership(net, net([torch.from_numpy(cloud)]), xyz, det)
        pred = panoptic(scan[:, :3].astype(np.float64), sem, det, settings, mlp)
        ids = np.arange(1, len(pred.detections) + 1)
        d = pred.detections
        vel = d.velocity if learned_velocity else None
        tid = tracker.add_detections(d.centres, d.classes, poses[f], times[f], vel)
        out.append(relabel(label_map, pred.semantic, pred.instance, ids, tid))
    return out
