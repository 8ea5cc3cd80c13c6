"""Stage ``most``: MOST (detection-centric panoptic segmentation) on every frame of ``align``.

MOST accumulates its own input: each frame's scan plus the k − 1 scans before it (``scans``), taken
into the current scan's frame with the ingest poses and given the relative time as a fifth column
(:func:`dsnet_core.most.data.accumulate`). ``align`` therefore runs with ``scans = 1`` (one volume
per frame, shared with DS-Net at k = 1); only the current scan is labelled. Inference is
:func:`dsnet_core.most.predict.predict`: BEV heatmap NMS → detections with modal extents and
velocities → PointSegMLP (or distance) memberships → instances; stuff keeps its semantic class.

Per point (volume = frame): ``sem`` (uint8 train id) and ``inst`` (int32 frame-local instance id,
0 = none) — the same names as ``fuse``, so ``track`` reads either. Table ``detections``: one row per
instance with its modal centre, extent, velocity and confidence (the tracker's input).

The fingerprint holds the checkpoint's content digest, so a new model reprocesses ``most`` and
``track``; ``ingest`` and ``align`` are shared with DS-Net and are not recomputed by a switch.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Literal

import numpy as np
import pyarrow as pa
from pydantic import Field

from storage.contract import ArraySpec, TableSpec
from tasks.align import volume_scans
from tasks.base import CLASS_MAP, ItemResult, Plan, Stage, StageConfig, StageContext
from tasks.infer import _check_device, model_meta

log = logging.getLogger(__name__)

FRAME_PERIOD = 0.1  # seconds between scans of a log without timestamps (10 Hz)


class MostStageConfig(StageConfig):
    """MOST's input and post-processing.

    Attributes:
        checkpoint: MOST checkpoint folder; None = the bundled MOST model.
        scans: k, the current scan plus k − 1 past scans (stride 1).
        device: torch device.
        rule: membership function, ``mlp`` (PointSegMLP) or ``distance`` (nearest centre in the RoI).
        score_threshold: minimum heatmap confidence of a detection.
    """

    checkpoint: str | None = None
    scans: int = Field(3, ge=1, le=16)
    device: str = "cpu"
    rule: Literal["mlp", "distance"] = "mlp"
    score_threshold: float = Field(0.3, gt=0, lt=1)


DETECTIONS = TableSpec(
    "detections",
    pa.schema(
        [
            ("index", pa.int32()),  # volume (= frame) index of align
            ("id", pa.int32()),  # frame-local instance id, as in ``inst``
            ("class_id", pa.int32()),  # detected thing class (train id)
            ("n_points", pa.int64()),
            ("confidence", pa.float32()),  # heatmap peak
            ("centre", pa.list_(pa.float32(), 3)),  # modal centre, metres, sensor frame
            ("extent", pa.list_(pa.float32(), 3)),  # modal half-extent, metres
            ("velocity", pa.list_(pa.float32(), 2)),  # (x, y) m/s, sensor frame
        ]
    ),
    roles=(
        ("id", "id"),
        ("class_id", "class_id"),
        ("points", "n_points"),
        ("item", "index"),
        ("confidence", "confidence"),
    ),
)


class MostStage(Stage):
    name = "most"
    upstream = ("align",)
    version = "1"
    Config = MostStageConfig
    item = "volume"
    arrays = (
        ArraySpec("sem", "uint8", doc="predicted train id"),
        ArraySpec("inst", "int32", doc="frame-local instance id (row id - 1 of the detections), 0 = none"),
    )
    tables = (DETECTIONS,)

    @staticmethod
    def checkpoint(ctx: StageContext):
        from dsnet_core.checkpoints import MOST

        return MOST.resolve(ctx.config.checkpoint, ctx.config.scans)

    def inputs(self, ctx: StageContext) -> str:
        from dsnet_core.checkpoints import checkpoint_digest

        return "checkpoint:" + checkpoint_digest(self.checkpoint(ctx))

    def plan(self, ctx: StageContext) -> Plan:
        from dsnet_core.checkpoints import MOST
        from dsnet_core.errors import ConfigError

        _check_device(ctx.config.device)
        if volume_scans(ctx) != 1:
            raise ConfigError(
                f"most accumulates its own past scans: align must run with scans 1, not {volume_scans(ctx)} "
                "(dsnet label --method most --scans k sets it)"
            )
        align = ctx.manifest("align")
        path = self.checkpoint(ctx).resolve()
        card = MOST.read_card(path)
        return Plan(
            n_items=align.n_items,
            max_points=int(align.plan["max_points"]),
            meta=model_meta(path, card),
        )

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        import torch

        from dsnet_core.labels import label_map_from_class_map
        from dsnet_core.most.checkpoint import load_most_checkpoint
        from dsnet_core.most.data import accumulate
        from dsnet_core.most.predict import InferenceSettings, predict

        label_map = label_map_from_class_map(ctx.plan[CLASS_MAP])
        device = torch.device(ctx.config.device)
        net, _ = load_most_checkpoint(ctx.plan["checkpoint"], device, expect_label_map=label_map)
        settings = InferenceSettings(rule=ctx.config.rule, score_threshold=ctx.config.score_threshold)
        scans = ctx.config.scans
        ref = _ref_frames(ctx)
        frames = ctx.frames.to_pydict()
        pose = dict(zip(frames["index"], frames["pose"], strict=True))
        stamp = dict(zip(frames["index"], frames["timestamp"], strict=True))
        align = ctx.arrays("align")
        cache: dict[int, np.ndarray] = {}
        for item in items:
            window = list(range(max(0, item - scans + 1), item + 1))
            for v in list(cache):
                if v not in window:
                    del cache[v]
            for v in window:
                if v not in cache:
                    cache[v] = align.read_item(v, ["points"])["points"]
            refs = [ref[v] for v in window]
            poses = _window_poses(ctx, refs, pose)
            times = _window_times(refs, stamp)
            cloud, n_current = accumulate([cache[v] for v in window], poses, times)
            pred = predict(net, torch.from_numpy(cloud).to(device), n_current, settings)
            inst = pred.instance.astype(np.int32)
            det = pred.detections
            counts = np.bincount(inst, minlength=len(det) + 1)
            rows = [
                {
                    "index": item,
                    "id": i + 1,
                    "class_id": int(det.classes[i]),
                    "n_points": int(counts[i + 1]),
                    "confidence": float(det.scores[i]),
                    "centre": [float(x) for x in det.centres[i]],
                    "extent": [float(x) for x in det.extents[i]],
                    "velocity": [float(x) for x in det.velocity[i]],
                }
                for i in range(len(det))
            ]
            yield ItemResult(
                item,
                arrays={"sem": pred.semantic.astype(np.uint8), "inst": inst},
                n_points=n_current,
                rows={"detections": rows},
                counts={"volumes": 1, "points": n_current, "instances": len(det)},
            )


def _ref_frames(ctx: StageContext) -> dict[int, int]:
    """Volume index → the frame whose sensor frame its points are in."""
    t = ctx.table("align", "volumes").to_pydict()
    return {int(i): int(r) for i, r in zip(t["index"], t["ref_frame"], strict=True)}


def _window_poses(ctx: StageContext, refs: list[int], pose: dict) -> list[np.ndarray] | None:
    """LiDAR-frame poses of the window's frames (None for a single scan).

    Raises:
        PoseFormatError: more than one scan and a frame has no pose.
    """
    if len(refs) == 1:
        return None
    if any(pose.get(f) is None for f in refs):
        from dsnet_core.errors import PoseFormatError

        raise PoseFormatError(
            Path(str(ctx.run.data)),
            f"most with scans={ctx.config.scans} accumulates past scans and needs poses; the log has none "
            "for sequence " + ctx.sequence + " (estimate them: dsnet label --estimate-poses, or --scans 1)",
        )
    return [np.asarray(pose[f], np.float64).reshape(4, 4) for f in refs]


def _window_times(refs: list[int], stamp: dict) -> list[float]:
    """Seconds per frame: the log's timestamps, else the frame index at 10 Hz."""
    if any(stamp.get(f) is None for f in refs):
        return [f * FRAME_PERIOD for f in refs]
    return [float(stamp[f]) for f in refs]
