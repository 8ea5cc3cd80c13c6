"""Bird's-eye-view pictures of a run's worst frames (prediction beside ground truth)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from dsnet_core.labels import LabelMap
from storage.run import RunStore
from tasks.base import labels_contract
from tasks.pipeline import Pipeline
from tasks.run_config import RunConfig


def worst_frames(frames: dict[str, dict[str, list]], n: int) -> list[tuple[str, int, str, float, int]]:
    """The ``n`` frames of lowest PQ (frames without a PQ are skipped): (seq, index, id, pq, points)."""
    cands = []
    for seq, t in frames.items():
        for i, fid, pq, npts in zip(t["index"], t["frame_id"], t["pq"], t["n_points"], strict=True):
            if pq is not None and math.isfinite(pq):
                cands.append((pq, seq, int(i), fid, int(npts)))
    cands.sort()
    return [(seq, i, fid, pq, npts) for pq, seq, i, fid, npts in cands[:n]]


def bev_rows(
    store: RunStore,
    pipeline: Pipeline,
    run: RunConfig,
    frames: dict[str, dict[str, list]],
    label_map: LabelMap,
    n: int,
    pred_to_gt: Callable[[np.ndarray], np.ndarray] | None = None,
) -> list[dict[str, Any]]:
    """PNG pictures (prediction and ground truth) of the ``n`` worst frames.

    Args:
        frames: ``frame_metrics`` columns by sequence.
        label_map: the ground truth's label map (colours of both pictures).
        pred_to_gt: the class mapping of predictions into the ground truth's raw ids, when the
            model's label map is another (:meth:`dsnet_core.label_mapping.ClassMapping.map_labels`).
    """
    from dsnet_core.viz.bev import label_colours, render_bev
    from dsnet_core.viz.png import encode_png

    if n <= 0:
        return []
    reader = run.open_log()
    labels = labels_contract(pipeline.labels)
    rows = []
    for rank, (seq, index, fid, pq, npts) in enumerate(worst_frames(frames, n)):
        ref = reader.frames(seq)[index]
        scan = reader.scan(ref)
        gt = reader.labels(ref)
        pred = store.arrays(seq, labels).read_item(index, ["label"])["label"]
        if pred_to_gt is not None:
            pred = pred_to_gt(pred)
        extent = float(min(60.0, max(20.0, np.percentile(np.abs(scan[:, :2]), 95))))
        pics = {}
        for key, lab in (("png_pred", pred), ("png_gt", gt)):
            lab = np.asarray(lab, dtype=np.uint32)
            img = render_bev(
                scan[:, :2], label_colours(lab, label_map), extent, 240, draw_last=(lab >> 16) > 0
            )
            pics[key] = encode_png(img)
        rows.append(
            {
                "rank": rank,
                "sequence": seq,
                "index": index,
                "frame_id": fid,
                "pq": pq,
                "n_points": npts,
                "extent_m": extent,
                **pics,
            }
        )
    return rows
