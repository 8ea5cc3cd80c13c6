"""Stage ``score``: the stitched per-frame labels against the ground truth (PQ family, mIoU, LSTQ).

One item per frame that has ground truth and was not quarantined. A block scores its frames with
one :class:`~dsnet_core.metrics.PanopticEvaluator`, yields one ``frame_metrics`` row per frame and
leaves the evaluator's accumulator state in ``blocks/acc-<first item>.npz`` (before the runner
writes the block's fragment, so a finished block always has its state). Sequence- and
dataset-level numbers come from merging those states (:mod:`tasks.score_report`), never from
averaging per-frame numbers.

The stitch stage's items are frames, indexed like ingest's frame table; its ``label`` array holds
``sem | inst << 16`` in the scan's original point order.
"""

from __future__ import annotations

import posixpath
from collections.abc import Iterator
from typing import Literal

import numpy as np
from pydantic import Field

from dsnet_core.labels import load_label_map
from dsnet_core.metrics import PanopticEvaluator
from dsnet_core.metrics.state import evaluator_state, state_to_bytes
from storage.errors import StoreError
from storage.run import RunStore
from tasks.base import ItemResult, Plan, Stage, StageConfig, StageContext

PRED_STAGE = "stitch"
PRED_ARRAY = "label"


class ScoreConfig(StageConfig):
    """Scoring settings.

    Attributes:
        mode: ``official`` (benchmark-exact, quirks included) or ``corrected``.
        min_points: minimum segment size (default: the label map's, 50 for SemanticKITTI).
        label_map: bundled label map name.
    """

    mode: Literal["official", "corrected"] = "official"
    min_points: int | None = Field(None, ge=0)
    label_map: str = "semantic-kitti"


def make_evaluator(config: ScoreConfig) -> PanopticEvaluator:
    return PanopticEvaluator(
        load_label_map(config.label_map), min_points=config.min_points, mode=config.mode, keep_rows=False
    )


def state_rel(store: RunStore, sequence: str, first_item: int) -> str:
    """Where the block starting at ``first_item`` keeps its accumulator state."""
    return posixpath.join(store.stage_rel(sequence, "score"), "blocks", f"acc-{first_item:06d}.npz")


class ScoreStage(Stage):
    name = "score"
    upstream = (PRED_STAGE,)
    version = "1"
    Config = ScoreConfig

    def plan(self, ctx: StageContext) -> Plan:
        table = ctx.frames.to_pydict()
        n_frames = len(table["index"])
        arrays = ctx.store.arrays(ctx.sequence, PRED_STAGE)
        if arrays.n_items != n_frames:
            raise StoreError(
                arrays.where, f"stitch has {arrays.n_items} frames but ingest has {n_frames}; rerun stitch"
            )
        done = arrays.done()
        scored = [
            int(i)
            for i, ok, gt in zip(table["index"], table["status"], table["has_labels"], strict=True)
            if ok == "ok" and gt and done[int(i)]
        ]
        ids = dict(zip(table["index"], table["frame_id"], strict=True))
        frame_ids = [ids[i] for i in scored]
        return Plan(n_items=len(scored), meta={"frames": scored, "frame_ids": frame_ids})

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        reader = ctx.reader
        refs = reader.frames(ctx.sequence)
        arrays = ctx.store.arrays(ctx.sequence, PRED_STAGE)
        ev = make_evaluator(ctx.config)
        for item in items:
            index = ctx.plan["frames"][item]
            frame_id = ctx.plan["frame_ids"][item]
            pred = arrays.read_item(index, [PRED_ARRAY])[PRED_ARRAY]
            gt = reader.labels(refs[index])
            if gt.shape != pred.shape:
                raise StoreError(
                    arrays.where,
                    f"frame {frame_id}: stitch label has {pred.shape[0]} points, {refs[index].label_path} "
                    f"has {gt.shape[0]}",
                )
            row = ev.add(gt, np.asarray(pred, dtype=np.uint32), frame=frame_id, sequence=ctx.sequence)
            yield ItemResult(
                item,
                rows={"frame_metrics": [frame_row(index, row)]},
                counts={"frames": 1, "points": row.n_points},
            )
        if items:
            rel = state_rel(ctx.store, ctx.sequence, items[0])
            ctx.store.root.write_bytes(rel, state_to_bytes(evaluator_state(ev)))


def frame_row(index: int, row) -> dict:
    """A ``frame_metrics`` row from a :class:`~dsnet_core.metrics.FrameRow` (NaN stays NaN)."""
    out = row.to_dict()
    out.pop("sequence")
    frame = out.pop("frame")
    return {"index": int(index), "frame_id": frame, **out}
