"""Stage ``ingest``: read a log through the reader protocol and write the frame table.

Per frame: id, source path, point count, LiDAR-frame pose, timestamp, checksum (blake2b of the
scan's and labels' bytes), status. With ``on_error="skip"`` a bad frame is quarantined with the
reader's message and the rest proceeds; by default the reader's error fails the sequence.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterator

import numpy as np

from dsnet_core.errors import DataFormatError
from tasks.base import ItemResult, Plan, Stage, StageConfig, StageContext


def frame_checksum(scan: np.ndarray, labels: np.ndarray | None) -> str:
    """blake2b-128 of the scan's float32 bytes followed by the labels' uint32 bytes."""
    h = hashlib.blake2b(np.ascontiguousarray(scan, np.float32).tobytes(), digest_size=16)
    if labels is not None:
        h.update(np.ascontiguousarray(labels, np.uint32).tobytes())
    return h.hexdigest()


def _stat(path) -> list:
    if path is None:
        return [None]
    try:
        st = os.stat(path)
    except OSError:
        return [str(path), None]
    return [os.path.basename(path), st.st_size, st.st_mtime_ns]


class IngestConfig(StageConfig):
    """No settings yet; the version and the source listing decide the fingerprint."""


class IngestStage(Stage):
    name = "ingest"
    upstream = ()
    version = "1"
    Config = IngestConfig

    def inputs(self, ctx: StageContext) -> str:
        """Names, sizes and mtimes of every scan and label file, plus the poses and times values."""
        reader = ctx.reader
        h = hashlib.blake2b(digest_size=16)
        frames = reader.frames(ctx.sequence)
        h.update(repr([(_stat(f.scan_path), _stat(f.label_path)) for f in frames]).encode())
        try:
            for frame in (frames[0], frames[-1]):  # force the (cached) parse of poses and times
                reader.pose(frame), reader.timestamp(frame)
            poses = [reader.pose(f) for f in frames]
            times = [reader.timestamp(f) for f in frames]
        except DataFormatError as exc:  # bad poses: the digest must still differ from a good log's
            h.update(str(exc).encode())
        else:
            h.update(np.asarray([p if p is not None else np.full((4, 4), np.nan) for p in poses]).tobytes())
            h.update(repr(times).encode())
        return h.hexdigest()

    def plan(self, ctx: StageContext) -> Plan:
        return Plan(n_items=len(ctx.reader.frames(ctx.sequence)))

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        reader = ctx.reader
        frames = reader.frames(ctx.sequence)
        for i in items:
            frame = frames[i]
            row = {
                "index": i,
                "frame_id": frame.frame_id,
                "source_path": str(frame.scan_path),
                "label_path": None if frame.label_path is None else str(frame.label_path),
                "n_points": 0,
                "pose": None,
                "timestamp": None,
                "checksum": "",
                "has_labels": frame.label_path is not None,
                "status": "ok",
                "reason": None,
            }
            try:
                scan = reader.scan(frame)
                labels = reader.labels(frame)
                pose = reader.pose(frame)
                row["timestamp"] = reader.timestamp(frame)
            except DataFormatError as exc:
                if ctx.options.on_error != "skip":
                    raise
                row.update(status="quarantined", reason=str(exc))
                yield ItemResult(i, rows={"frames": [row]}, counts={"frames": 1, "quarantined": 1})
                continue
            row.update(
                n_points=int(scan.shape[0]),
                pose=None if pose is None else [float(v) for v in np.asarray(pose).reshape(-1)],
                checksum=frame_checksum(scan, labels),
            )
            yield ItemResult(
                i,
                rows={"frames": [row]},
                counts={"frames": 1, "points": int(scan.shape[0]), "quarantined": 0},
            )
