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

from tasks.base import ItemResult, Plan, Stage, StageConfig, StageContext


class FuseConfig(StageConfig):
    """No settings: the fusion rule is fixed (majority vote, ties to the smaller class id)."""


class FuseStage(Stage):
    name = "fuse"
    upstream = ("infer", "shift")
    version = "1"
    Config = FuseConfig

    def plan(self, ctx: StageContext) -> Plan:
        infer = ctx.store.read_manifest(ctx.sequence, "infer")
        return Plan(n_items=infer.n_items, max_points=int(infer.plan["max_points"]))

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        from dsnet_core.instance.fusion import fuse
        from dsnet_core.labels import load_label_map
        from tasks.infer import dequantise_probs

        things = load_label_map("semantic-kitti").things
        align = ctx.store.arrays(ctx.sequence, "align")
        infer = ctx.store.arrays(ctx.sequence, "infer")
        shift = ctx.store.arrays(ctx.sequence, "shift")
        for item in items:
            xyz = align.read_item(item, ["points"])["points"][:, :3]
            inf = infer.read_item(item, ["sem", "probs"])
            inst = shift.read_item(item, ["instance"])["instance"]
            fused = fuse(xyz, inf["sem"], inst, things, dequantise_probs(inf["probs"]))
            t = fused.instances
            rows = [
                {
                    "index": item,
                    "id": int(t.id[k]),
                    "class_id": int(t.class_id[k]),
                    "n_points": int(t.n_points[k]),
                    "agreement": float(t.agreement[k]),
                    "confidence": float(t.confidence[k]),
                    "centroid": t.centroid[k].tolist(),
                    "box_min": t.box_min[k].tolist(),
                    "box_max": t.box_max[k].tolist(),
                }
                for k in range(len(t))
            ]
            n = int(xyz.shape[0])
            yield ItemResult(
                item,
                arrays={"sem": fused.semantic.astype(np.uint8), "inst": fused.instance.astype(np.int32)},
                n_points=n,
                rows={"instances": rows},
                counts={"volumes": 1, "points": n, "instances": len(t)},
            )
