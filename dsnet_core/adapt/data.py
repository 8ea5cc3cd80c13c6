"""What adaptation trains on: scans of any log with labels from elsewhere (pseudo-labels, or
corrections given as label files only), and training items as :class:`~dsnet_core.adapt.mixing.Cloud`.

:class:`LabelOverlay` reads a log's scans and poses and takes its labels from a folder in the
SemanticKITTI layout (``DIR/sequences/SS/labels/FRAME_ID.label``): the log's own labels (its
ground truth, if any) are never read through it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dsnet_core.adapt.mixing import Cloud
from dsnet_core.errors import LabelFormatError
from dsnet_core.io import kitti
from dsnet_core.io.reader import FrameRef, LogReader
from dsnet_core.labels import LabelMap
from dsnet_core.train.data import augment, load_sample


def label_file(root: Path, sequence: str, frame_id: str) -> Path:
    """Where :class:`LabelOverlay` looks for a frame's labels."""
    return Path(root) / "sequences" / sequence / "labels" / f"{frame_id}.label"


def write_labels(path: Path, label: np.ndarray) -> None:
    """Write a ``(N,) uint32`` label file (raw semantic | instance << 16) atomically."""
    kitti.write_label(path, label)


def read_labels(path: Path, n_points: int) -> np.ndarray:
    """Read a label file of ``n_points`` labels.

    Raises:
        LabelFormatError: naming the file, when its length differs.
    """
    return kitti.read_label(path, n_points)


class LabelOverlay:
    """``base``'s scans with labels read from ``labels_root`` (a :class:`LogReader`).

    Only frames with a label file carry ``label_path``; sequences without any are left out.

    Args:
        base: the log.
        labels_root: the labels' folder (``labels_root/sequences/SS/labels/ID.label``).
    """

    def __init__(self, base: LogReader, labels_root: str | Path) -> None:
        self.base, self.labels_root = base, Path(labels_root)
        self.root = base.root
        self.format = f"{base.format}+labels"
        self.label_map = base.label_map

    def sequences(self) -> list[str]:
        return [s for s in self.base.sequences() if (self.labels_root / "sequences" / s / "labels").is_dir()]

    def frames(self, sequence: str) -> list[FrameRef]:
        out = []
        for ref in self.base.frames(sequence):
            path = label_file(self.labels_root, sequence, ref.frame_id)
            out.append(
                FrameRef(
                    ref.sequence, ref.frame_id, ref.index, ref.scan_path, path if path.is_file() else None
                )
            )
        return out

    def scan(self, frame: FrameRef) -> np.ndarray:
        return self.base.scan(frame)

    def labels(self, frame: FrameRef) -> np.ndarray | None:
        """The overlay's label file, its length checked against the scan.

        Raises:
            LabelFormatError: naming the file, when its length is not the scan's point count.
        """
        if frame.label_path is None:
            return None
        return kitti.read_label(frame.label_path, int(self.base.scan(frame).shape[0]))

    def pose(self, frame: FrameRef) -> np.ndarray | None:
        return self.base.pose(frame)

    def poses(self, sequence: str) -> np.ndarray | None:
        return self.base.poses(sequence)

    def timestamp(self, frame: FrameRef) -> float | None:
        return self.base.timestamp(frame)

    def intensity_convention(self, sequence: str) -> str:
        return self.base.intensity_convention(sequence)


@dataclass(frozen=True)
class Item:
    """One training volume: its reader, its frames (the reference last) and its points' weight.

    Attributes:
        reader: where scans and labels come from.
        refs: the volume's frames (k consecutive ones, the reference last).
        weight: loss weight of its labelled points.
        kind: ``target`` (pseudo-labels), ``corrected`` (true labels) or ``source`` (true labels).
    """

    reader: LogReader
    refs: tuple[FrameRef, ...]
    weight: float
    kind: str

    @property
    def name(self) -> str:
        return f"{self.refs[-1].sequence}/{self.refs[-1].frame_id}"


def volumes(reader: LogReader, scans: int, weight: float, kind: str, sequences=None) -> list[Item]:
    """Every labelled frame of ``reader`` as the reference of a ``scans``-frame volume."""
    from dsnet_core.train.data import volume_refs

    seqs = reader.sequences() if sequences is None else sequences
    return [Item(reader, tuple(refs), weight, kind) for refs in volume_refs(reader, seqs, scans)]


def centres(xyz: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """``(N, 3) float32`` the middle of each instance's tight axis-aligned box (rows of points
    without an instance, ``keys == 0``, are 0): the centre the offset head is trained towards."""
    out = np.zeros((len(keys), 3), np.float32)
    valid = keys > 0
    if not valid.any():
        return out
    uniq, inv = np.unique(keys[valid], return_inverse=True)
    pts = np.asarray(xyz, np.float32)[valid]
    lo = np.full((uniq.size, 3), np.inf, np.float32)
    hi = np.full((uniq.size, 3), -np.inf, np.float32)
    np.minimum.at(lo, inv, pts)
    np.maximum.at(hi, inv, pts)
    out[valid] = ((lo + hi) * np.float32(0.5))[inv]
    return out


def load_cloud(item: Item, label_map: LabelMap, rng: np.random.Generator | None) -> Cloud:
    """Read ``item`` (aligned into its reference scan's frame), augment it when ``rng`` is given
    (yaw, flips, scale, translation), and compute its instance centres on the augmented points.

    Raises:
        LabelFormatError: a label file whose length is not its scan's point count.
    """
    s = load_sample(item.reader, list(item.refs), label_map)
    if s.sem.shape[0] != s.points.shape[0]:
        raise LabelFormatError(
            item.refs[-1].label_path or item.refs[-1].scan_path, "labels do not match the scan"
        )
    points = augment(s.points, rng) if rng is not None else s.points
    weight = np.where(s.sem > 0, np.float32(item.weight), np.float32(0.0)).astype(np.float32)
    return Cloud(points, s.sem, s.inst, centres(points[:, :3], s.inst), weight)
