"""Stage ``fuse``: majority-vote fusion of semantics and instances (DS-Net), per volume.

Every instance of ``shift`` takes the most frequent predicted thing class among its points;
stuff keeps its class and instance 0. Writes per point ``sem`` (uint8 train id) and ``inst``
(int32 raw, volume-local id) and an ``instances`` table (one row per instance: class, size,
centroid, axis-aligned box, agreement and confidence = mean dequantised probability of the
winning class) for review queues. The stitcher takes the confidence as the track's score.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pyarrow as pa

from storage.contract import ArraySpec, TableSpec
from tasks.base import ItemResult, Plan, Stage, StageConfig, StageContext

INSTANCES = TableSpec(
    "instances",
    pa.schema(
        [
            ("index", pa.int32()),  # volume index
            ("id", pa.int32()),  # raw (volume-local) instance id, as in fuse's ``inst``
            ("class_id", pa.int32()),  # winning thing class (train id)
            ("n_points", pa.int64()),
            ("agreement", pa.float32()),  # fraction of the instance's points predicted as class_id
            ("confidence", pa.float32()),  # mean predicted probability of class_id over its points
            ("centroid", pa.list_(pa.float32(), 3)),  # metres, volume (reference sensor) frame
            ("box_min", pa.list_(pa.float32(), 3)),  # axis-aligned box, metres
            ("box_max", pa.list_(pa.float32(), 3)),
        ]
    ),
    roles=(
        ("id", "id"),
        ("class_id", "class_id"),
        ("points", "n_points"),
        ("item", "index"),
        ("confidence", "confidence"),
        ("agreement", "agreement"),
    ),
)
ROW_FIELDS = ("id", "class_id", "n_points", "agreement", "confidence", "centroid", "box_min", "box_max")
"""The columns of :data:`INSTANCES` after ``index``, each a field of the core's instance table."""


class FuseConfig(StageConfig):
    """No settings: the fusion rule is fixed (majority vote, ties to the smaller class id)."""


class FuseStage(Stage):
    """Fuses ``source``'s semantics (``infer``'s predictions, or ``dpls``'s prior) with shift's instances."""

    name = "fuse"
    version = "1"
    Config = FuseConfig
    item = "volume"
    arrays = (
        ArraySpec("sem", "uint8", doc="train id after the instances' majority vote"),
        ArraySpec("inst", "int32", doc="raw (volume-local) instance id, 0 for stuff"),
    )
    tables = (INSTANCES,)

    def __init__(self, source: str = "infer") -> None:
        self.source = source
        self.upstream = (source, "shift")

    def check_sources(self, pipeline) -> None:
        from tasks.shift import MODEL_ARRAYS

        self.require(pipeline, self.source, MODEL_ARRAYS)

    def reads(self, pipeline) -> dict[str, tuple[str, ...]]:
        """The volumes' points, of align (upstream of its source)."""
        return {"align": ("points",)}

    def plan(self, ctx: StageContext) -> Plan:
        infer = ctx.manifest(self.source)
        return Plan(n_items=infer.n_items, max_points=int(infer.plan["max_points"]))

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        from dsnet_core.instance.fusion import fuse
        from tasks.infer import dequantise_probs

        things = ctx.label_map.things
        align = ctx.arrays("align")
        infer = ctx.arrays(self.source)
        shift = ctx.arrays("shift")
        for item in items:
            xyz = align.read_item(item, ["points"])["points"][:, :3]
            inf = infer.read_item(item, ["sem", "probs"])
            inst = shift.read_item(item, ["instance"])["instance"]
            fused = fuse(xyz, inf["sem"], inst, things, dequantise_probs(inf["probs"]))
            t = fused.instances
            rows = [
                {"index": item, **dict(zip(ROW_FIELDS, values, strict=True))}
                for values in zip(*(getattr(t, name).tolist() for name in ROW_FIELDS), strict=True)
            ]
            n = int(xyz.shape[0])
            yield ItemResult(
                item,
                arrays={"sem": fused.semantic.astype(np.uint8), "inst": fused.instance.astype(np.int32)},
                n_points=n,
                rows={"instances": rows},
                counts={"volumes": 1, "points": n, "instances": len(t)},
            )
