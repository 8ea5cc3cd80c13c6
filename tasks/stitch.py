"""Stage ``stitch``: sequence-wide instance ids and each frame's final label.

Reads ``fuse`` (per volume: train ids, raw instance ids, instance confidences) and ``align``
(each point's source frame and source index) and streams the volumes of a sequence through
:class:`dsnet_core.temporal.stitching.Stitcher`: on the frames two consecutive volumes share, the new
volume's raw ids inherit the tracked ids they overlap with point IoU > 0.5 (one-to-one); every
other raw id takes a fresh id from one counter per sequence. For k = 1 volumes share no frame, so
this is exactly "hand out sequence-wide ids from one counter".

A label holds 65 535 ids. A sequence that needs more (the bundled model opens ~60 per frame, so
beyond ~1 100 frames) reuses ids: an id unused for more than ``id_reuse_after`` frames, least
recently used first (:mod:`dsnet_core.temporal.ids`), with a warning once per sequence and the
number of reused ids in the manifest's counts (``ids_reused``). The ``tracks`` table then has one
row per hand-out of an id (``generation`` 0, 1, ...; their frames never overlap).

**Ownership rule: a frame's label comes from the first volume (in sequence order) that
contains it**; later volumes only use their predictions on that frame to match ids. It is
written once and never changes.

Output per frame (item = frame, the ingest frame table's ``index``): ``label`` uint32 in the
ORIGINAL point order of the frame's scan (points put back through align's ``source_frame`` /
``source_index``), ``learning_map_inv[train id] | id << 16`` in the model's label map;
quarantined frames get no label (``done`` stays 0). Table ``tracks``: one row per track (id,
generation, class, first/last frame, points per frame, confidence = point-weighted mean of fuse's
instance confidence, lowest linking IoU).

Stitching is sequential, so a sequence is one block. It is resumable inside the block: after
each volume's frames are written, the stitcher's state is saved as the stage's state
(:meth:`storage.run.RunStore.write_stage_state`, tagged with the stage's fingerprint and the
volume); a rerun of the block continues after the last saved volume whose owned frames are all
``done`` (without a valid state it restarts from the first volume) and yields only the frames
the runner asks for (those not ``done``; the runner keeps the finished frames' counts and
rows). The track table rides on the last frame. A killed stitch therefore resumes to identical
labels and tables.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator

import numpy as np
import pyarrow as pa
from pydantic import Field

from dsnet_core.temporal.ids import REUSE_AFTER
from storage.contract import TableSpec
from tasks.align import sequential_frames_plan
from tasks.base import FRAME_LABEL, ItemResult, Plan, Stage, StageConfig, StageContext, StateThrottle
from tasks.track_ids import warn_reuse

log = logging.getLogger(__name__)


class StitchConfig(StageConfig):
    """Matching settings.

    Attributes:
        min_iou: a tracked id carries over when the point IoU on the shared frames is above this.
        id_reuse_after: once the 65 535 ids of a label are used up, an id is handed out again only
            after this many frames without it (keep it above refine's ``join_gap``).
    """

    min_iou: float = 0.5
    id_reuse_after: int = Field(REUSE_AFTER, ge=1)


TRACKS = TableSpec(
    "tracks",
    pa.schema(
        [
            ("id", pa.int32()),  # sequence-wide instance id (upper 16 bits of the label)
            ("generation", pa.int32()),  # which hand-out of the id (0; 1, 2, ... once ids are reused)
            ("class_id", pa.int32()),  # majority train id over the track's points
            ("raw_class", pa.int32()),  # the same through learning_map_inv
            ("first_frame", pa.int32()),  # frame indices (the ingest frame table's ``index``)
            ("last_frame", pa.int32()),
            ("n_points", pa.int64()),
            ("n_frames", pa.int32()),
            ("confidence", pa.float64()),  # point-weighted mean of fuse's instance confidence
            ("min_link_iou", pa.float64()),  # lowest IoU that carried the id across volumes (NaN: none)
            ("frames", pa.list_(pa.int32())),  # frames the track has points in
            ("frame_points", pa.list_(pa.int64())),  # its points in each of those frames
        ]
    ),
    roles=(
        ("id", "id"),
        ("generation", "generation"),
        ("class_id", "class_id"),
        ("points", "n_points"),
        ("item", "first_frame"),
        ("confidence", "confidence"),
        ("frames", "frames"),
        ("link_iou", "min_link_iou"),
    ),
)


class StitchStage(Stage):
    name = "stitch"
    upstream = ("fuse", "align")
    version = "2"  # 2: ids reused beyond 65 535, the tracks table's generation
    Config = StitchConfig
    item = "frame"
    arrays = (FRAME_LABEL,)
    tables = (TRACKS,)

    def plan(self, ctx: StageContext) -> Plan:
        return sequential_frames_plan(ctx)

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        from dsnet_core.temporal.stitching import Stitcher, VolumeLabels

        todo = set(items)  # the runner passes only the frames not yet done
        if not todo:
            return
        label_map = ctx.label_map
        windows = [list(w) for w in ctx.plan["windows"]]
        frame_points = np.asarray(ctx.plan["frame_points"], np.int64)
        # the stitcher wants contiguous frame numbers: use ranks among the frames in any window
        absolute = np.array(sorted({f for w in windows for f in w}), np.int64)
        lut = np.zeros(int(absolute.max(initial=0)) + 1, np.int64)
        lut[absolute] = np.arange(absolute.size)
        fingerprint = ctx.manifest(self.name).fingerprint
        out = ctx.arrays(self.name)
        stitcher, start = self._resume(ctx, fingerprint, windows, out.done(), label_map)
        if stitcher is None:
            stitcher = Stitcher(label_map, min_iou=ctx.config.min_iou, reuse_after=ctx.config.id_reuse_after)
        else:
            log.info("stitch %s resumes after volume %d from its saved state", ctx.sequence, start - 1)
        scores = self._scores(ctx)
        throttle = StateThrottle()
        warned = False
        align = ctx.arrays("align")
        fuse = ctx.arrays("fuse")
        for v in range(start, len(windows)):
            w = windows[v]
            src = align.read_item(v, ["source_frame", "source_index"])
            fused = fuse.read_item(v, ["sem", "inst"])
            volume = VolumeLabels(
                frames=lut[np.asarray(w, np.int64)],
                source_frame=lut[src["source_frame"]],
                source_index=src["source_index"],
                semantic=fused["sem"].astype(np.int64),
                instance=fused["inst"].astype(np.int64),
                frame_sizes=frame_points[w],
                scores=scores.get(v),
            )
            finished = stitcher.add_volume(volume)
            warned = warn_reuse(ctx.sequence, self.name, stitcher.ids, int(w[0]), warned)
            for j, ff in enumerate(finished):
                f = int(absolute[ff.frame])
                if f not in todo:  # written (and counted) by an interrupted run of this block
                    continue
                rows, counts = {}, {}
                if v == len(windows) - 1 and j == len(finished) - 1:
                    rows = {"tracks": self._track_rows(stitcher, label_map, absolute)}
                    counts = {"tracks": len(rows["tracks"]), "ids_reused": stitcher.ids.reused}
                n = int(ff.label.shape[0])
                yield ItemResult(
                    f,
                    arrays={"label": ff.label},
                    n_points=n,
                    rows=rows,
                    counts={"frames": 1, "points": n, "tracks": 0, "ids_reused": 0} | counts,
                )
            # runs once the runner has written every frame of this volume (done flags set)
            if v < len(windows) - 1 and throttle.due():
                with throttle:
                    state = {"fingerprint": fingerprint, "volume": v, "state": stitcher.state_dict()}
                    ctx.store.write_stage_state(ctx.sequence, self.name, state)
        ctx.store.write_stage_state(ctx.sequence, self.name, None)

    def _resume(self, ctx: StageContext, fingerprint: str, windows, done: np.ndarray, label_map):
        """(stitcher, first volume to compute) from a saved state that is still valid, else (None, 0)."""
        from dsnet_core.temporal.stitching import Stitcher

        saved = ctx.store.read_stage_state(ctx.sequence, self.name)
        if saved is None or saved.get("fingerprint") != fingerprint:
            return None, 0
        v = int(saved["volume"])
        owned = sorted({f for w in windows[: v + 1] for f in w})
        if v >= len(windows) - 1 or not done[owned].all():
            return None, 0
        return Stitcher.from_state(saved["state"], label_map), v + 1

    @staticmethod
    def _scores(ctx: StageContext) -> dict[int, dict[int, float]]:
        t = ctx.table("fuse", "instances").to_pydict()
        out: dict[int, dict[int, float]] = {}
        for v, i, c in zip(t["index"], t["id"], t["confidence"], strict=True):
            if c is not None and not math.isnan(c):
                out.setdefault(int(v), {})[int(i)] = float(c)
        return out

    @staticmethod
    def _track_rows(stitcher, label_map, absolute: np.ndarray) -> list[dict]:
        """The ``tracks`` rows: the track table's columns, its frame ranks put back to frame indices."""
        cols = stitcher.track_table().columns(label_map)
        rows = [dict(zip(cols, values, strict=True)) for values in zip(*cols.values(), strict=True)]
        for row in rows:
            row["first_frame"] = int(absolute[row["first_frame"]])
            row["last_frame"] = int(absolute[row["last_frame"]])
            row["frames"] = absolute[np.asarray(row["frames"], np.int64)].tolist()
        return rows
