"""Training samples from any :class:`LogReader`: single scans or k-scan 4D volumes, with train
ids, instance keys and the augmentation of the paper (yaw, flips, scale, translation)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from dsnet_core.errors import PoseFormatError
from dsnet_core.io.reader import FrameRef, LogReader
from dsnet_core.labels import LabelMap
from dsnet_core.temporal.align import to_reference


@dataclass(frozen=True)
class Sample:
    """One training/validation input.

    Attributes:
        points: float32 ``(N, 4)`` x, y, z (metres, reference-scan frame), remission.
        sem: int64 ``(N,)`` train ids (0 = ignore).
        inst: int64 ``(N,)`` instance keys (train id << 32 | instance id), 0 for stuff/unlabelled.
        thing: bool ``(N,)`` points of thing instances (instance id > 0 and a thing class).
        frame_index: int64 ``(N,)`` position of each point's scan in the volume (0 = oldest).
        name: "sequence/frame_id" of the reference scan.
        centre: float32 ``(N, 3)`` each thing point's instance centre when fixed before the sample
            was cut (a mixed sample, :mod:`dsnet_core.train.real`); None: taken on ``points``.
    """

    points: np.ndarray
    sem: np.ndarray
    inst: np.ndarray
    thing: np.ndarray
    frame_index: np.ndarray
    name: str
    centre: np.ndarray | None = None


def volume_refs(reader: LogReader, sequences: list[str], scans: int = 1) -> list[list[FrameRef]]:
    """Per reference frame, the ``scans`` consecutive frames ending at it (frames without enough
    history reuse the earliest available ones, so every labelled frame is a reference)."""
    out = []
    for seq in sequences:
        frames = reader.frames(seq)
        for i, ref in enumerate(frames):
            if ref.label_path is None:
                continue
            out.append([frames[max(0, j)] for j in range(i - scans + 1, i + 1)] if scans > 1 else [ref])
    return out


def load_sample(reader: LogReader, refs: list[FrameRef], label_map: LabelMap) -> Sample:
    """Read the scans of ``refs`` (for k > 1 aligned into the last scan's frame, docs/algorithm.md eq. 7)."""
    target = refs[-1]
    is_thing = label_map.is_thing()
    pose_t = reader.pose(target) if len(refs) > 1 else None
    if len(refs) > 1 and pose_t is None:
        raise PoseFormatError(reader.root / "sequences" / target.sequence, "4D volumes need poses")
    pts_l, sem_l, inst_l, fidx_l = [], [], [], []
    seen: set[str] = set()
    for k, ref in enumerate(refs):
        if ref.frame_id in seen:
            continue
        seen.add(ref.frame_id)
        pts = reader.scan(ref).copy()
        label = reader.labels(ref)
        if label is None:
            label = np.zeros(len(pts), np.uint32)
        if pose_t is not None and ref is not target:
            pts[:, :3] = to_reference(pts[:, :3], reader.pose(ref), pose_t).astype(np.float32)
        sem = label_map.to_train(label & 0xFFFF).astype(np.int64)
        ids = (label >> 16).astype(np.int64)
        pts_l.append(pts)
        sem_l.append(sem)
        inst_l.append(np.where((ids > 0) & is_thing[sem], (sem << 32) | ids, 0))
        fidx_l.append(np.full(len(pts), k, np.int64))
    inst = np.concatenate(inst_l)
    return Sample(
        points=np.concatenate(pts_l),
        sem=np.concatenate(sem_l),
        inst=inst,
        thing=inst > 0,
        frame_index=np.concatenate(fidx_l),
        name=f"{target.sequence}/{target.frame_id}",
    )


def augment(points: np.ndarray, rng: np.random.Generator, translate_std: float = 0.1) -> np.ndarray:
    """Random yaw rotation, x/y flips, scale in [0.95, 1.05] and a small translation (metres).

    Args:
        points: float32 ``(N, 4)``; a new array is returned.
    """
    out = points.copy()
    theta = rng.uniform(0.0, 2 * np.pi)
    c, s = np.cos(theta), np.sin(theta)
    rot = np.array([[c, -s], [s, c]], dtype=np.float64)
    xy = out[:, :2].astype(np.float64) @ rot.T
    if rng.random() < 0.5:
        xy[:, 0] = -xy[:, 0]
    if rng.random() < 0.5:
        xy[:, 1] = -xy[:, 1]
    scale = rng.uniform(0.95, 1.05)
    shift = rng.normal(0.0, translate_std, 3)
    out[:, :2] = (xy * scale + shift[:2]).astype(np.float32)
    out[:, 2] = (out[:, 2] * scale + shift[2]).astype(np.float32)
    return out


def class_counts(reader: LogReader, volumes: list[list[FrameRef]], label_map: LabelMap) -> np.ndarray:
    """Points per train id ``(C,) int64`` over the reference scans of ``volumes``."""
    counts = np.zeros(label_map.num_classes, np.int64)
    for refs in volumes:
        _count(counts, reader.labels(refs[-1]), label_map)
    return counts


def _count(counts: np.ndarray, label: np.ndarray | None, label_map: LabelMap) -> None:
    """Add one scan's points per train id (``label``: raw uint32 ``(N,)`` or None) to ``counts``."""
    if label is not None:
        counts += np.bincount(label_map.to_train(label & 0xFFFF), minlength=label_map.num_classes)


REFERENCE_SCANS = 32
"""At most this many training scans (evenly spaced over the volumes) make a card's sensor reference."""


def probe_statistics(
    reader: LogReader, volumes: list[list[FrameRef]], label_map: LabelMap
) -> tuple[np.ndarray, dict | None]:
    """What a new card records of its training scans, in one pass over them (a stream renders each
    sample once: its labels and its scan are read together): :func:`class_counts` ``(C,) int64`` and
    the ``sensor_reference`` (:func:`dsnet_core.model.sensor_match.reference_of`) over the reference
    scans of at most :data:`REFERENCE_SCANS` of ``volumes`` evenly spaced (None when they have no
    ground near the sensor)."""
    from dsnet_core.model.sensor_match import reference_of

    pick = set(
        np.linspace(0, len(volumes) - 1, min(REFERENCE_SCANS, len(volumes))).round().astype(int).tolist()
    )
    counts = np.zeros(label_map.num_classes, np.int64)
    scans = []
    for i, refs in enumerate(volumes):
        _count(counts, reader.labels(refs[-1]), label_map)
        if i in pick:
            scans.append(reader.scan(refs[-1]))
    try:
        reference = reference_of(scans).to_dict() if scans else None
    except ValueError:
        reference = None
    return counts, reference


def data_fingerprint(reader: LogReader, volumes: list[list[FrameRef]]) -> str:
    """sha256 over the names, sizes and first 64 KiB of every scan and label file used."""
    h = hashlib.sha256()
    files = sorted(
        {p for refs in volumes for r in refs for p in (r.scan_path, r.label_path) if p is not None}
    )
    for p in files:
        h.update(str(p.relative_to(reader.root)).encode())
        h.update(str(p.stat().st_size).encode())
        with open(p, "rb") as f:
            h.update(f.read(1 << 16))
    return h.hexdigest()
