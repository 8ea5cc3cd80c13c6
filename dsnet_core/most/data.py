"""MOST's input and training samples: the current scan plus k − 1 past scans aligned into its frame
(4D-DS-Net eq. 7, :mod:`dsnet_core.temporal.align`) with the relative time as a fifth column;
labels and object targets for the current scan only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dsnet_core.errors import PoseFormatError
from dsnet_core.io.reader import FrameRef, LogReader
from dsnet_core.labels import LabelMap
from dsnet_core.most.targets import FrameObjects, ObjectTargets, frame_objects, sequence_targets
from dsnet_core.temporal.align import to_reference

FRAME_PERIOD = 0.1  # seconds between scans when a log has no timestamps (10 Hz spin)


def accumulate(
    scans: list[np.ndarray], poses: list[np.ndarray] | None, times: list[float]
) -> tuple[np.ndarray, int]:
    """Concatenate scans in the frame of the last one, current scan first.

    Args:
        scans: float32 ``(N_i, 4)`` per scan (sensor frame), oldest first; the last is current.
        poses: float64 ``(4, 4)`` LiDAR-frame poses per scan (None only for a single scan).
        times: seconds per scan.

    Returns:
        float32 ``(N, 5)``: x, y, z (metres, current frame), remission, ``t_current − t_scan``
        (seconds, ≥ 0); and the number of current-scan points (the first rows).
    """
    cur = len(scans) - 1
    parts = []
    for i in [cur, *range(cur - 1, -1, -1)]:
        pts = np.empty((scans[i].shape[0], 5), np.float32)
        pts[:, :4] = scans[i][:, :4]
        if i != cur:
            pts[:, :3] = to_reference(scans[i][:, :3], poses[i], poses[cur])  # type: ignore[index]
        pts[:, 4] = times[cur] - times[i]
        parts.append(pts)
    return np.concatenate(parts), scans[cur].shape[0]


def window(frames: list[FrameRef], position: int, scans: int) -> list[FrameRef]:
    """The ``scans`` frames ending at ``position`` (fewer at the start of a sequence), oldest first."""
    return frames[max(0, position - scans + 1) : position + 1]


def frame_times(reader: LogReader, frames: list[FrameRef]) -> list[float]:
    """Seconds per frame: the log's timestamps, else ``index · 0.1``."""
    ts = [reader.timestamp(f) for f in frames]
    if any(t is None for t in ts):
        return [f.index * FRAME_PERIOD for f in frames]
    return [float(t) for t in ts]  # type: ignore[arg-type]


def read_window(reader: LogReader, refs: list[FrameRef], times: list[float]) -> tuple[np.ndarray, int]:
    """:func:`accumulate` over ``refs`` read from ``reader``.

    Raises:
        PoseFormatError: more than one scan and the log has no poses.
    """
    poses = None
    if len(refs) > 1:
        poses = [reader.pose(r) for r in refs]
        if any(p is None for p in poses):
            raise PoseFormatError(
                reader.root / "sequences" / refs[-1].sequence, "accumulating past scans needs poses"
            )
    return accumulate([reader.scan(r) for r in refs], poses, times)  # type: ignore[arg-type]


def instance_keys(label: np.ndarray, label_map: LabelMap) -> tuple[np.ndarray, np.ndarray]:
    """Train ids ``(N,) int64`` and instance keys ``train id << 32 | id`` (0 off thing instances)."""
    sem = label_map.to_train(label & 0xFFFF).astype(np.int64)
    ids = (label >> 16).astype(np.int64)
    return sem, np.where((ids > 0) & label_map.is_thing()[sem], (sem << 32) | ids, 0)


@dataclass(frozen=True)
class MostSample:
    """A training/validation input.

    Attributes:
        points: float32 ``(N, 5)`` accumulated cloud, current scan first.
        n_current: points of the current scan.
        sem: int64 ``(n,)`` train ids of the current scan.
        keys: int64 ``(n,)`` instance keys of the current scan.
        targets: the current scan's objects (MAX extents, velocities).
        name: "sequence/frame_id".
    """

    points: np.ndarray
    n_current: int
    sem: np.ndarray
    keys: np.ndarray
    targets: ObjectTargets
    name: str


class SequenceTargets:
    """Object targets of every labelled frame of a log's sequences (computed once: MAX and the
    velocities need the whole sequence).

    Args:
        min_points: instances with fewer points in a scan are no detection target there.
    """

    def __init__(
        self, reader: LogReader, sequences: list[str], label_map: LabelMap, min_points: int = 5
    ) -> None:
        self.reader, self.label_map = reader, label_map
        self.targets: dict[tuple[str, str], ObjectTargets] = {}
        for seq in sequences:
            frames = [f for f in reader.frames(seq) if f.label_path is not None]
            objs: list[FrameObjects] = []
            for f in frames:
                _, keys = instance_keys(reader.labels(f), label_map)  # type: ignore[arg-type]
                objs.append(frame_objects(reader.scan(f)[:, :3], keys, min_points))
            poses = reader.poses(seq)
            if poses is not None:
                poses = poses[[f.index for f in frames]]
            for f, t in zip(frames, sequence_targets(objs, poses, frame_times(reader, frames)), strict=True):
                self.targets[(seq, f.frame_id)] = t

    def sample(self, frames: list[FrameRef], position: int, scans: int) -> MostSample:
        """The sample whose current scan is ``frames[position]``."""
        refs = window(frames, position, scans)
        points, n = read_window(self.reader, refs, frame_times(self.reader, refs))
        ref = refs[-1]
        sem, keys = instance_keys(self.reader.labels(ref), self.label_map)  # type: ignore[arg-type]
        return MostSample(
            points, n, sem, keys, self.targets[(ref.sequence, ref.frame_id)], f"{ref.sequence}/{ref.frame_id}"
        )
