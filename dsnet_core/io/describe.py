"""Summaries of a log: its format, per sequence the frames, points, sensor fields, intensity
convention and pose source, and the class histogram (used by ``dsnet describe``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dsnet_core.io.reader import LogReader


@dataclass
class LogSummary:
    """Counts over the sequences of a log.

    Attributes:
        format: the log's format name.
        frames: sequence -> number of frames.
        points: sequence -> total points.
        class_points: train class name -> points (labelled logs only).
        class_instances: thing class name -> distinct instance ids (labelled logs only).
        has_poses: sequence -> whether LiDAR poses are available.
        pose_source: sequence -> where the poses come from (None: no poses).
        fields: sequence -> the source's per-point fields, as the reader describes them.
        intensity: sequence -> the source's intensity convention
            (:data:`dsnet_core.io.intensity.CONVENTIONS`; every reader hands the model 0–1).
        no_return: sequence -> source points without a return (NaN), dropped by the reader and
            not counted in ``points``.
        largest: sequence -> (frame id, points) of its frame with the most points.
    """

    format: str = ""
    frames: dict[str, int] = field(default_factory=dict)
    points: dict[str, int] = field(default_factory=dict)
    class_points: dict[str, int] = field(default_factory=dict)
    class_instances: dict[str, int] = field(default_factory=dict)
    has_poses: dict[str, bool] = field(default_factory=dict)
    pose_source: dict[str, str | None] = field(default_factory=dict)
    fields: dict[str, str] = field(default_factory=dict)
    intensity: dict[str, str] = field(default_factory=dict)
    no_return: dict[str, int] = field(default_factory=dict)
    largest: dict[str, tuple[str, int]] = field(default_factory=dict)


def summarize(reader: LogReader, sequences: list[str] | None = None) -> LogSummary:
    """Read every frame of ``sequences`` (all by default) and count points per class."""
    lm = reader.label_map
    summary = LogSummary(format=reader.format)
    hist = np.zeros(lm.num_classes if lm is not None else 0, dtype=np.int64)
    instances: dict[int, set[int]] = {c: set() for c in lm.things} if lm is not None else {}
    for seq in sequences or reader.sequences():
        frames = reader.frames(seq)
        summary.frames[seq] = len(frames)
        summary.has_poses[seq] = reader.poses(seq) is not None
        source = getattr(reader, "pose_source", None)
        summary.pose_source[seq] = source(seq) if source else ("log" if summary.has_poses[seq] else None)
        fields = getattr(reader, "sensor_fields", None)
        summary.fields[seq] = fields(seq) if fields and frames else ""
        summary.intensity[seq] = reader.intensity_convention(seq) if frames else ""
        total = 0
        dropped = getattr(reader, "dropped_points", None)
        summary.no_return[seq] = 0
        for ref in frames:
            scan = reader.scan(ref)
            total += scan.shape[0]
            if seq not in summary.largest or scan.shape[0] > summary.largest[seq][1]:
                summary.largest[seq] = (str(ref.frame_id), int(scan.shape[0]))
            summary.no_return[seq] += int(dropped(ref)) if dropped else 0
            label = reader.labels(ref)
            if label is None or lm is None:
                continue
            train = lm.to_train(label & 0xFFFF)
            hist += np.bincount(train, minlength=lm.num_classes)
            inst = label >> 16
            for c in lm.things:
                ids = np.unique(inst[(train == c) & (inst > 0)])
                instances[c].update(f"{seq}/{i}" for i in ids.tolist())  # type: ignore[misc]
        summary.points[seq] = total
    if lm is not None and hist.sum():
        summary.class_points = {lm.class_names[c]: int(hist[c]) for c in range(lm.num_classes)}
        summary.class_instances = {lm.class_names[c]: len(instances[c]) for c in lm.things}
    return summary
