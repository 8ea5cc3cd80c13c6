"""Stage ``align``: 4D volumes of k consecutive scans in the reference scan's frame (eq. 7).

Windows of ``scans`` ok frames with step ``stride`` (default ``scans - 1`` so consecutive volumes
share a frame for stitching; 1 for 3D). Quarantined frames are left out of every window.
Ground-truth labels, when every frame has them, travel with the points.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pyarrow as pa
from pydantic import Field, model_validator

from dsnet_core.errors import PoseFormatError
from dsnet_core.temporal.align import build_volume, plan_windows
from storage.contract import ArraySpec, TableSpec
from tasks.base import ItemResult, Plan, Stage, StageConfig, StageContext
from tasks.frames import SOURCE
from tasks.ingest import frame_checksum

VOLUMES = TableSpec(
    "volumes",
    pa.schema(
        [
            ("index", pa.int32()),
            ("ref_frame", pa.int32()),  # frame index whose sensor frame the volume is expressed in
            ("frames", pa.list_(pa.int32())),  # frame indices in the volume, in order
            ("n_points", pa.int64()),
        ]
    ),
)


class AlignConfig(StageConfig):
    """Window settings.

    Attributes:
        scans: k, scans per volume (1 = 3D).
        stride: step between windows' first scans; default ``max(scans - 1, 1)``.
    """

    scans: int = Field(1, ge=1, le=16)
    stride: int | None = Field(None, ge=1)

    @model_validator(mode="after")
    def _resolve_stride(self) -> AlignConfig:
        if self.stride is None:
            object.__setattr__(self, "stride", max(self.scans - 1, 1))
        if self.stride > self.scans:
            raise ValueError(f"stride {self.stride} > scans {self.scans} would skip frames")
        return self


def volume_scans(ctx: StageContext) -> int:
    """k, the scans per volume of the sequence's ``align`` stage (from its manifest's config)."""
    return int(ctx.manifest("align").config.get("scans", 1))


def sequential_frames_plan(ctx: StageContext) -> Plan:
    """The plan of a stage that labels every frame of a sequence from align's volumes in one
    sequential block (``stitch``, ``track``): an item per frame, the windows and frame sizes."""
    t = ctx.frames.to_pydict()
    align = ctx.manifest("align")
    ok = [i for i, s in zip(t["index"], t["status"], strict=True) if s == "ok"]
    sizes = dict(zip(t["index"], t["n_points"], strict=True))
    return Plan(
        n_items=len(t["index"]),
        max_points=max((int(sizes[i]) for i in ok), default=0),
        meta={"windows": align.plan["windows"], "frame_points": [int(sizes[i]) for i in t["index"]]},
        blocks=[list(range(len(t["index"])))],
    )


class AlignStage(Stage):
    name = "align"
    upstream = ("ingest",)
    version = "1"
    Config = AlignConfig
    item = "volume"
    arrays = (
        ArraySpec(
            "points",
            "float32",
            trailing=(4,),
            doc="x, y, z (m, reference sensor frame), remission",
            codec="shuffle-lz4",
        ),
        *SOURCE,
        ArraySpec("labels", "uint32", optional=True, doc="raw semantic | instance << 16 (ground truth)"),
    )
    tables = (VOLUMES,)

    def plan(self, ctx: StageContext) -> Plan:
        table = ctx.frames
        ok = np.asarray(table["status"].to_pylist()) == "ok"
        index = np.asarray(table["index"].to_numpy())[ok]
        n_points = np.asarray(table["n_points"].to_numpy())[ok]
        has_labels = bool(ok.any()) and all(np.asarray(table["has_labels"].to_pylist())[ok])
        windows = [
            [int(index[p]) for p in w] for w in plan_windows(len(index), ctx.config.scans, ctx.config.stride)
        ]
        by_frame = dict(zip(index.tolist(), n_points.tolist(), strict=True))
        sizes = [int(sum(by_frame[f] for f in w)) for w in windows]
        return Plan(
            n_items=len(windows),
            max_points=max(sizes, default=0),
            omit=() if has_labels else ("labels",),
            meta={"windows": windows, "n_points": sizes, "labels": has_labels},
        )

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        reader = ctx.reader
        refs = reader.frames(ctx.sequence)
        table = ctx.frames.to_pydict()
        rows = {idx: {k: table[k][r] for k in table} for r, idx in enumerate(table["index"])}
        with_labels = ctx.plan["labels"]
        cache: dict[int, tuple] = {}

        def load(f: int):
            if f not in cache:
                scan = reader.scan(refs[f])
                # ingest's checksum covers a frame's labels whenever it has them, even where the
                # volumes carry none (not every frame of the sequence has labels)
                labels = reader.labels(refs[f]) if rows[f]["has_labels"] else None
                if frame_checksum(scan, labels) != rows[f]["checksum"]:
                    raise PoseFormatError(refs[f].scan_path, "frame changed since ingest; rerun ingest")
                cache[f] = (scan, labels if with_labels else None)
            return cache[f]

        for item in items:
            window = ctx.plan["windows"][item]
            poses = [rows[f]["pose"] for f in window]
            if len(window) > 1 and any(p is None for p in poses):
                raise PoseFormatError(
                    refs[window[-1]].scan_path.parent.parent,
                    f"align with scans={len(window)} needs poses; the log has none (estimate them with"
                    " KISS-ICP: dsnet label --estimate-poses, or ingest's estimate_poses setting)",
                )
            poses = [np.eye(4) if p is None else np.asarray(p, np.float64).reshape(4, 4) for p in poses]
            data = [load(f) for f in window]
            vol = build_volume(
                [d[0] for d in data], poses, window, [d[1] for d in data] if with_labels else None
            )
            for f in list(cache):  # keep only the frames the next window may share
                if f < window[0] + ctx.config.stride:
                    del cache[f]
            arrays = {
                "points": vol.points,
                "source_frame": vol.source_frame,
                "source_index": vol.source_index,
            }
            if with_labels:
                arrays["labels"] = vol.labels
            n = int(vol.points.shape[0])
            yield ItemResult(
                item,
                arrays=arrays,
                n_points=n,
                rows={"volumes": [{"index": item, "ref_frame": window[-1], "frames": window, "n_points": n}]},
                counts={"volumes": 1, "points": n},
            )
