"""Identity switches along ground-truth tubes: a diagnostic next to LSTQ's S_assoc.

A tube is one ground-truth thing instance (raw semantic | instance id, ``inst > 0``) over the
frames of a sequence. In every frame it is matched to the predicted instance (``pred >> 16 > 0``,
class-agnostic: an id is an id whatever class it carries) that overlaps it with point IoU > 0.5
— a unique match, as in PQ. A **switch** is a matched frame whose predicted id differs from the
id the tube was last matched to (MOT-style: gaps do not reset the memory). A tube matched in
``m`` frames can switch at most ``m - 1`` times; a tracker that hands out fresh ids every frame
switches exactly that often.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dsnet_core.labels import LabelMap


@dataclass
class SwitchCounter:
    """Streaming counter over the frames of one or more sequences (frames in time order).

    Args:
        label_map: maps raw semantic ids to train ids (thing classes come from it).
        min_iou: a ground-truth segment and a predicted instance match when IoU > this.
        min_points: smaller ground-truth segments are not counted in that frame.
    """

    label_map: LabelMap
    min_iou: float = 0.5
    min_points: int = 50
    switches: int = 0
    matches: int = 0  # (tube, frame) pairs with a match
    _last: dict[tuple[str, int], int] = field(default_factory=dict)  # (sequence, gt label) -> pred id

    def add(self, gt: np.ndarray, pred: np.ndarray, sequence: str = "") -> int:
        """Add the next frame of ``sequence``.

        Args:
            gt: ``(N,) uint32`` ground truth (raw semantic | instance << 16).
            pred: ``(N,) uint32`` prediction in the same encoding.

        Returns:
            The switches in this frame.
        """
        gt = np.asarray(gt, np.uint32).astype(np.int64)
        pred_id = np.asarray(pred, np.uint32).astype(np.int64) >> 16
        thing = self.label_map.is_thing()[self.label_map.to_train(gt & 0xFFFF)] & ((gt >> 16) > 0)
        g_ids, g_inv, g_n = np.unique(gt[thing], return_inverse=True, return_counts=True)
        p_ids, p_n = np.unique(pred_id[pred_id > 0], return_counts=True)
        if g_ids.size == 0 or p_ids.size == 0:
            return 0
        p_at = pred_id[thing]
        has = p_at > 0
        pairs = g_inv[has] * (int(p_ids.max()) + 1) + p_at[has]
        keys, inter = np.unique(pairs, return_counts=True)
        gi, pid = keys // (int(p_ids.max()) + 1), keys % (int(p_ids.max()) + 1)
        union = g_n[gi] + p_n[np.searchsorted(p_ids, pid)] - inter
        ok = (inter / union > self.min_iou) & (g_n[gi] >= self.min_points)
        n = 0
        for g, p in zip(g_ids[gi[ok]].tolist(), pid[ok].tolist(), strict=True):
            key = (sequence, g)
            if key in self._last and self._last[key] != p:
                n += 1
            self._last[key] = p
        self.matches += int(ok.sum())
        self.switches += n
        return n

    @property
    def tubes(self) -> int:
        """Ground-truth tubes matched at least once."""
        return len(self._last)
