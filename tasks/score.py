"""Stage ``score``: a method's final per-frame labels against the ground truth (PQ family, mIoU, LSTQ).

One item per frame that has ground truth and was not quarantined. A block scores its frames with
one :class:`~dsnet_core.metrics.PanopticEvaluator`, yields one ``frame_metrics`` row per frame and
leaves the evaluator's accumulator state in the block's bytes ``acc-<first item>.npz`` (written
before the runner writes the block's fragment, so a finished block always has its state).
Sequence- and dataset-level numbers come from merging those states (:mod:`flows.report`), never
from averaging per-frame numbers.

The stage reads whichever stage holds the method's final labels (``labels``: ``stitch`` for
DS-Net), whose ``label`` array holds ``raw semantic | instance << 16`` per frame in the scan's
original point order. The ground truth's label map is the log reader's; predictions are in the
model's label map. The scorer comes from :func:`dsnet_core.metrics.scoring.make_scorer`: the same
map on both sides scores the labels as they are; different maps go through the explicit class
mapping between the two (package data chosen by the pair of map names) in the ground truth's own
benchmark metrics, or are refused when no mapping exists. The plan records what was used
(``scoring``: metric family, min_points, the mapping's file, sha256 and classes) and the mapping's
digest is part of the fingerprint.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Literal

import numpy as np
import pyarrow as pa
from pydantic import Field

from dsnet_core.errors import ConfigError
from dsnet_core.labels import LabelMap
from dsnet_core.metrics.registry import columns, registry_digest
from dsnet_core.metrics.scoring import Scorer, describe_scorer, make_scorer, scorer_state
from dsnet_core.metrics.state import state_to_bytes
from storage.contract import TableSpec
from storage.errors import StoreError
from tasks.base import ItemResult, Plan, Stage, StageConfig, StageContext

_FRAME_FIXED = [
    ("index", pa.int32()),  # frame index in the sequence (ingest's)
    ("frame_id", pa.string()),
    ("n_points", pa.int64()),  # points of the scan
    ("n_valid", pa.int64()),  # points whose ground truth is not ignored
]
_FRAME_COUNTS = [
    ("tp", pa.int64()),  # matched segments, all classes
    ("fp", pa.int64()),
    ("fn", pa.int64()),
]


def column_type(kind: str) -> pa.DataType:
    """The table type of a metric column's kind (``score``: float64, NaN where undefined;
    ``count``: int64)."""
    return pa.int64() if kind == "count" else pa.float64()


def frame_metrics_spec() -> TableSpec:
    """The ``frame_metrics`` table: the frame, then every registered metric's per-frame columns
    (:func:`dsnet_core.metrics.registry.columns` ``("frame")``: PQ, SQ, RQ over the classes seen
    in the frame, mIoU over those with a union, the present-class means, ...), then the segment
    counts. Built from the registry when asked, so a metric registered later has its columns."""
    metric = [(c.key, column_type(c.kind)) for c in columns("frame")]
    return TableSpec("frame_metrics", pa.schema([*_FRAME_FIXED, *metric, *_FRAME_COUNTS]))


def __getattr__(name: str):
    if name == "FRAME_METRICS":  # the table of the registry as it is now
        return frame_metrics_spec()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class ScoreConfig(StageConfig):
    """Scoring settings.

    Attributes:
        mode: ``official`` (benchmark-exact, quirks included) or ``corrected``.
        min_points: minimum segment size (default: the ground truth's label map's).
    """

    mode: Literal["official", "corrected"] = "official"
    min_points: int | None = Field(None, ge=0)


def make_evaluator(config: ScoreConfig, gt_map: LabelMap, model_map: LabelMap | None = None) -> Scorer:
    """The scorer of a run: ground truth in ``gt_map``, predictions in ``model_map`` (default: the same).

    Raises:
        ConfigError: the maps differ and there is no class mapping (or scorer) between them.
    """
    return make_scorer(gt_map, model_map or gt_map, config.mode, config.min_points)


def block_state_name(first_item: int) -> str:
    """The name of the accumulator state of the block starting at ``first_item``."""
    return f"acc-{first_item:06d}.npz"


class ScoreStage(Stage):
    """Scores the per-frame ``label`` array of the stage named ``labels``."""

    name = "score"
    version = "2"  # 2: block states of the metric registry's layout (1's are refused, not misread)
    Config = ScoreConfig
    item = "frame"

    @property
    def tables(self) -> tuple[TableSpec, ...]:  # type: ignore[override]
        return (frame_metrics_spec(),)

    def __init__(self, labels: str) -> None:
        self.upstream = (labels,)

    @property
    def labels(self) -> str:
        return self.upstream[0]

    def inputs(self, ctx: StageContext) -> str:
        """The ground truth's label map (the reader's) and the class mapping from the model's map
        (its file's sha256, when the maps differ) decide the scores as much as the config, and so do
        the registered metrics (a metric registered since rescores)."""
        gt = ctx.reader.label_map
        if gt is None:
            return ""
        try:
            scoring = describe_scorer(make_evaluator(ctx.config, gt, ctx.label_map))
        except (ConfigError, StoreError):  # no model map yet, or no mapping: plan() says so
            scoring = {}
        mapping = scoring.get("mapping") or {}
        return (
            f"gt-labels:{gt.name}:{gt.source}:mapping:{mapping.get('sha256', '')}:metrics:{registry_digest()}"
        )

    def plan(self, ctx: StageContext) -> Plan:
        table = ctx.frames.to_pydict()
        n_frames = len(table["index"])
        arrays = ctx.arrays(self.labels)
        if arrays.n_items != n_frames:
            raise StoreError(
                arrays.where,
                f"{self.labels} has {arrays.n_items} frames but ingest has {n_frames}; rerun {self.labels}",
            )
        done = arrays.done()
        scored = [
            int(i)
            for i, ok, gt in zip(table["index"], table["status"], table["has_labels"], strict=True)
            if ok == "ok" and gt and done[int(i)]
        ]
        meta = {"frames": scored}
        if scored:  # no mapping between the model's and the ground truth's maps fails here
            meta["scoring"] = describe_scorer(self.scorer(ctx))
        ids = dict(zip(table["index"], table["frame_id"], strict=True))
        meta["frame_ids"] = [ids[i] for i in scored]
        return Plan(n_items=len(scored), meta=meta)

    @staticmethod
    def scorer(ctx: StageContext) -> Scorer:
        """A fresh scorer of the model's labels against the log's ground truth.

        Raises:
            ConfigError: the log has no label map, or the model predicts in another map and no
                class mapping between the two exists.
        """
        gt = ctx.reader.label_map
        if gt is None:
            raise ConfigError(f"{ctx.run.data}: the log's format has no label map to score against")
        try:
            return make_evaluator(ctx.config, gt, ctx.label_map)
        except ConfigError as exc:
            raise ConfigError(f"{ctx.run.data}: {exc}") from None

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        reader = ctx.reader
        refs = reader.frames(ctx.sequence)
        arrays = ctx.arrays(self.labels)
        ev = self.scorer(ctx)
        for item in items:
            index = ctx.plan["frames"][item]
            frame_id = ctx.plan["frame_ids"][item]
            pred = arrays.read_item(index, ["label"])["label"]
            gt = reader.labels(refs[index])
            if gt.shape != pred.shape:
                raise StoreError(
                    arrays.where,
                    f"frame {frame_id}: {self.labels} label has {pred.shape[0]} points, "
                    f"{refs[index].label_path} has {gt.shape[0]}",
                )
            row = ev.add(gt, np.asarray(pred, dtype=np.uint32), frame=frame_id, sequence=ctx.sequence)
            yield ItemResult(
                item,
                rows={"frame_metrics": [frame_row(index, row)]},
                counts={"frames": 1, "points": row.n_points},
            )
        if items:
            data = state_to_bytes(scorer_state(ev))
            ctx.store.write_block_bytes(ctx.sequence, self.name, block_state_name(items[0]), data)


def frame_row(index: int, row) -> dict:
    """A ``frame_metrics`` row from a :class:`~dsnet_core.metrics.FrameRow` (NaN stays NaN)."""
    out = row.to_dict()
    out.pop("sequence")
    frame = out.pop("frame")
    return {"index": int(index), "frame_id": frame, **out}
