"""MOST inference (paper Sec. III "Inference" and supplementary Alg. 1).

1. NMS on the centre heatmaps (a cell is kept when it is the maximum of its 3×3 window and its
   confidence passes a threshold) gives detections: centre (cell centre + regressed offset, regressed
   height), class, confidence, extent, velocity.
2. For each detection, the RoI is the axis-aligned box ``|p − ĉ| ≤ scale · r̂ + margin``; only points
   whose predicted class is the detection's class are candidates (Alg. 1 line 7).
3. A membership function scores every (point, detection) pair of the RoIs: PointSegMLP's
   probability (members above 0.5), or the distance rule (the paper's NN baseline: every candidate
   is a member, the nearest centre wins).
4. Overlaps: a point joins the detection with the highest membership score, ties to the more
   confident detection. Instance ids are 1, 2, … in decreasing detection confidence, over the
   detections that keep at least one point.
5. Every other point keeps its semantic prediction with instance 0 (stuff, and thing points no
   detection claimed).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from dsnet_core.most.bev import REGRESS
from dsnet_core.most.config import BevGrid
from dsnet_core.most.heatmap import cell_centre

#: scores (P,) of pairs given as (detection index (P,), point index (P,))
Membership = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Detections:
    """Modal detections of one scan, in decreasing confidence.

    Attributes:
        centres: float64 ``(D, 3)`` metres, sensor frame.
        classes: int64 ``(D,)`` train ids.
        scores: float64 ``(D,)`` confidence in [0, 1].
        extents: float64 ``(D, 3)`` half-extents, metres.
        velocity: float64 ``(D, 2)`` m/s in the sensor frame.
    """

    centres: np.ndarray
    classes: np.ndarray
    scores: np.ndarray
    extents: np.ndarray
    velocity: np.ndarray

    def __len__(self) -> int:
        return int(self.classes.size)

    def take(self, idx: np.ndarray) -> Detections:
        return Detections(
            self.centres[idx], self.classes[idx], self.scores[idx], self.extents[idx], self.velocity[idx]
        )


def decode_heatmap(
    heatmap: torch.Tensor,
    regress: torch.Tensor,
    grid: BevGrid,
    things: tuple[int, ...],
    threshold: float = 0.3,
    max_detections: int = 200,
    kernel: int = 3,
) -> Detections:
    """Detections of one sample.

    Args:
        heatmap: float ``(K, S, S)`` logits. regress: float ``(8, S, S)``.
        threshold: minimum confidence; max_detections: keep the most confident this many.
        kernel: NMS window in cells.
    """
    with torch.no_grad():
        hm = torch.sigmoid(heatmap.float())
        peak = F.max_pool2d(hm[None], kernel, stride=1, padding=kernel // 2)[0]
        scores = torch.where(hm == peak, hm, torch.zeros_like(hm)).flatten()
        k = min(max_detections, scores.numel())
        top, flat = torch.topk(scores, k)
        keep = top >= threshold
        top, flat = top[keep].double().cpu().numpy(), flat[keep].cpu().numpy()
        s = grid.size
        chan, cell = flat // (s * s), flat % (s * s)
        cells = np.stack([cell // s, cell % s], 1)
        reg = regress.reshape(regress.shape[0], -1)[:, torch.from_numpy(cell).to(regress.device)].t()
        reg = reg.double().cpu().numpy()
    centres = np.zeros((len(cell), 3))
    centres[:, :2] = cell_centre(cells, grid) + reg[:, REGRESS["offset"]]
    centres[:, 2] = reg[:, REGRESS["height"]][:, 0]
    return Detections(
        centres=centres,
        classes=np.asarray(things, np.int64)[chan],
        scores=top,
        extents=np.maximum(reg[:, REGRESS["extent"]], 0.05),
        velocity=reg[:, REGRESS["velocity"]],
    )


def roi_pairs(
    xyz: np.ndarray, semantic: np.ndarray | None, det: Detections, scale: float = 1.1, margin: float = 0.2
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate pairs: points inside a detection's RoI with the detection's predicted class.

    Args:
        xyz: float ``(N, 3)``; semantic: int ``(N,)`` predicted train ids, or None to take every
            point of the RoI (PointSegMLP's training pairs).

    Returns:
        detection indices int64 ``(P,)`` and point indices int64 ``(P,)``.
    """
    dets, pts = [], []
    for d in range(len(det)):
        cand = np.arange(len(xyz)) if semantic is None else np.flatnonzero(semantic == det.classes[d])
        half = det.extents[d] * scale + margin
        inside = (np.abs(xyz[cand] - det.centres[d]) <= half).all(1)
        sel = cand[inside]
        dets.append(np.full(sel.size, d, np.int64))
        pts.append(sel.astype(np.int64))
    if not dets:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(dets), np.concatenate(pts)


def distance_membership(xyz: np.ndarray, det: Detections) -> Membership:
    """The NN rule: score ``1 / (1 + ‖p − ĉ‖)`` (every RoI candidate is a member; use threshold 0)."""

    def score(d: np.ndarray, p: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + np.linalg.norm(xyz[p] - det.centres[d], axis=1))

    return score


def assign_instances(
    n_points: int,
    pairs: tuple[np.ndarray, np.ndarray],
    membership: Membership,
    threshold: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Instances from scored pairs (steps 3–4 above).

    Args:
        n_points: points of the scan.
        pairs: :func:`roi_pairs` output; detection indices must follow decreasing confidence.
        membership: scores of pairs; a pair is a member when its score is above ``threshold``.

    Returns:
        instance int64 ``(N,)`` (0 = none) and, per instance id ``i ≥ 1``, its detection index at
        position ``i − 1`` (int64 ``(I,)``).
    """
    d, p = pairs
    instance = np.zeros(n_points, np.int64)
    if d.size == 0:
        return instance, np.zeros(0, np.int64)
    score = np.asarray(membership(d, p), np.float64)
    member = score > threshold
    d, p, score = d[member], p[member], score[member]
    order = np.lexsort((d, -score, p))  # per point: best score first, ties to the lower index
    d, p = d[order], p[order]
    first = np.r_[True, p[1:] != p[:-1]] if p.size else np.zeros(0, bool)
    owner_d, owner_p = d[first], p[first]
    used = np.unique(owner_d)  # ascending detection index = decreasing confidence
    ids = np.zeros(int(d.max(initial=-1)) + 1, np.int64)
    ids[used] = np.arange(1, used.size + 1)
    instance[owner_p] = ids[owner_d]
    return instance, used
