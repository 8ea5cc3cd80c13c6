"""The review queue: the least confident instances of a run, from every stage table that declares
the ``confidence`` role (see :class:`storage.contract.TableSpec`).

A table takes part by declaring roles for its columns: ``confidence`` (required), and ``id``,
``class_id``, ``points`` and ``item`` where it has them; nothing is guessed from column names.
Instances under :data:`~dsnet_core.review.confidence.MIN_INSTANCE_POINTS` points (fragments, 1-point
clusters: the least confident by far, and nothing a person can check) are left out; the frame
confidence's ``size`` term counts them.
"""

from __future__ import annotations

import math
from typing import Any

from dsnet_core.labels import LabelMap
from dsnet_core.review.confidence import MIN_INSTANCE_POINTS
from storage.run import RunStore
from tasks.pipeline import Pipeline


def _volume_frames(store: RunStore, pipeline: Pipeline, seq: str) -> dict[int, list[int]]:
    """Volume index -> its frame indices (the ``volumes`` table of the stage that builds volumes;
    empty where there is none, or it is not done)."""
    for stage in pipeline:
        for spec in stage.tables:
            if spec.name != "volumes":
                continue
            m = store.read_manifest(seq, stage.name)
            if m is None or m.status != "done":
                return {}
            t = store.read_table(seq, spec).to_pydict()
            return dict(zip(t["index"], t["frames"], strict=True))
    return {}


def _frames_text(item: int | None, unit: str, volumes: dict[int, list[int]]) -> str:
    """The frame numbers of a queue entry: a volume's ``3–4``, a frame's ``3``, ``""`` unknown."""
    if item is None:
        return ""
    if unit != "volume":
        return str(item)
    frames = volumes.get(item)
    if not frames:
        return ""
    return str(frames[0]) if min(frames) == max(frames) else f"{min(frames)}–{max(frames)}"


def review_queue(
    store: RunStore,
    pipeline: Pipeline,
    sequences: list[str],
    label_map: LabelMap | None,
    n: int,
    min_points: int = MIN_INSTANCE_POINTS,
) -> list[dict[str, Any]]:
    """The ``n`` least confident instances of at least ``min_points`` points (where the table
    declares a ``points`` role) across sequences and declaring tables.

    Args:
        label_map: the model's label map, for class names (None: class ids as text).
    """
    names = label_map.class_names if label_map is not None else ()
    cands = []
    for stage in pipeline:
        for spec in stage.tables:
            conf_col = spec.role("confidence")
            if conf_col is None:
                continue
            id_col, cls_col, pts_col, item_col = (spec.role(r) for r in ("id", "class_id", "points", "item"))
            for seq in sequences:
                m = store.read_manifest(seq, stage.name)
                if m is None or m.status != "done":
                    continue
                t = store.read_table(seq, spec).to_pydict()
                volumes = _volume_frames(store, pipeline, seq) if stage.item == "volume" else {}
                for r, conf in enumerate(t[conf_col]):
                    if conf is None or not math.isfinite(conf):
                        continue
                    if pts_col is not None and (t[pts_col][r] or 0) < min_points:
                        continue
                    cls = None if cls_col is None else t[cls_col][r]
                    if cls is not None and 0 <= cls < len(names):
                        cls = names[cls]
                    cands.append(
                        {
                            "source": f"{stage.name}/{spec.name}",
                            "sequence": seq,
                            "item": None if item_col is None else t[item_col][r],
                            "frames": _frames_text(
                                None if item_col is None else t[item_col][r], stage.item, volumes
                            ),
                            "instance": int(t[id_col][r]) if id_col else r,
                            "class": "" if cls is None else str(cls),
                            "points": None if pts_col is None else int(t[pts_col][r]),
                            "confidence": float(conf),
                        }
                    )
    cands.sort(key=lambda r: (r["confidence"], r["source"], r["sequence"], r["instance"]))
    return [{"rank": i, **r} for i, r in enumerate(cands[:n])]
