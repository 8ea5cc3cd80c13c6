"""Bird's-eye-view pictures: a scored run's worst frames (prediction beside ground truth), any run's
least confident frames (by class and by instance), and the class legend of both."""

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


def _hex(rgb) -> str:
    return "#" + "".join(f"{int(v):02x}" for v in rgb)


def legend_rows(label_map: LabelMap, which: str = "model") -> list[dict[str, Any]]:
    """``class_legend`` rows: every class of a label map with its picture colours.

    Args:
        which: ``model`` (the final labels' map) or ``truth`` (the ground truth's, of the scored
            pictures).
    """
    from dsnet_core.viz.bev import DIM, class_colours

    colours = class_colours(label_map)
    things, ignored = set(label_map.things), set(label_map.ignore)
    return [
        {
            "map": which,
            "class_id": c,
            "class": name,
            "kind": "ignored" if c in ignored else "thing" if c in things else "stuff",
            "colour": _hex(colours[c]),
            "colour_dim": _hex((colours[c].astype(np.float64) * DIM).astype(np.uint8)),
        }
        for c, name in enumerate(label_map.class_names)
    ]


def confidence_bev_rows(
    store: RunStore,
    pipeline: Pipeline,
    run: RunConfig,
    confidence: list[dict[str, Any]],
    label_map: LabelMap,
    n: int,
) -> list[dict[str, Any]]:
    """PNG pictures of the final labels of the ``n`` least confident frames: by class (the
    legend's colours) and by instance.

    Args:
        confidence: ``frame_confidence`` rows, lowest score first.
        label_map: the model's label map (the final labels' encoding).
    """
    from dsnet_core.viz.bev import class_point_colours, label_colours, render_bev
    from dsnet_core.viz.png import encode_png

    if n <= 0 or not confidence:
        return []
    reader = run.open_log()
    labels = labels_contract(pipeline.labels)
    rows = []
    for rank, c in enumerate(confidence[:n]):
        ref = reader.frames(c["sequence"])[c["index"]]
        scan = reader.scan(ref)
        lab = np.asarray(
            store.arrays(c["sequence"], labels).read_item(c["index"], ["label"])["label"], np.uint32
        )
        extent = float(min(60.0, max(20.0, np.percentile(np.abs(scan[:, :2]), 95))))
        on_top = (lab >> 16) > 0
        by_class = render_bev(scan[:, :2], class_point_colours(lab, label_map), extent, 240, draw_last=on_top)
        by_instance = render_bev(scan[:, :2], label_colours(lab, label_map), extent, 240, draw_last=on_top)
        rows.append(
            {
                "rank": rank,
                "sequence": c["sequence"],
                "index": c["index"],
                "frame_id": c["frame_id"],
                "score": c["score"],
                "n_points": int(lab.size),
                "extent_m": extent,
                "png_class": encode_png(by_class),
                "png_instance": encode_png(by_instance),
            }
        )
    return rows
