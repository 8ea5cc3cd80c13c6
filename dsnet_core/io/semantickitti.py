"""Reader and writer for logs in the SemanticKITTI layout::

ROOT/sequences/SS/velodyne/NNNNNN.bin
ROOT/sequences/SS/labels/NNNNNN.label      (optional)
ROOT/sequences/SS/poses.txt + calib.txt    (optional, together)
ROOT/sequences/SS/times.txt                (optional)
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np

from dsnet_core.errors import LabelFormatError, SequenceLayoutError
from dsnet_core.io import kitti
from dsnet_core.io.reader import FrameRef
from dsnet_core.labels import LabelMap, load_label_map


class SemanticKittiReader:
    """Reads ``ROOT/sequences/*`` and checks every file it hands out (format ``semantickitti``).

    Args:
        root: dataset root (the folder holding ``sequences/``).
        label_map: used to reject raw semantic ids the map does not know.
        check_labels: validate raw semantic ids on read.
    """

    def __init__(
        self,
        root: str | Path,
        label_map: LabelMap | None = None,
        check_labels: bool = True,
    ) -> None:
        self.root = Path(root).resolve()
        self.format = "semantickitti"
        self.label_map = label_map or load_label_map("semantic-kitti")
        self.check_labels = check_labels
        self._lut = self.label_map.lut()
        if not (self.root / "sequences").is_dir():
            raise SequenceLayoutError(self.root, "no 'sequences/' folder (expected the SemanticKITTI layout)")
        self._poses = cache(self._load_poses)
        self._times = cache(self._load_times)
        self._frames = cache(self._list_frames)

    # -- protocol -------------------------------------------------------------------------
    def sequences(self) -> list[str]:
        return sorted(p.name for p in (self.root / "sequences").iterdir() if p.is_dir())

    def frames(self, sequence: str) -> list[FrameRef]:
        return list(self._frames(sequence))

    def scan(self, frame: FrameRef) -> np.ndarray:
        return kitti.read_scan(self._inside(frame.scan_path))

    def labels(self, frame: FrameRef, n_points: int | None = None) -> np.ndarray | None:
        if frame.label_path is None:
            return None
        path = self._inside(frame.label_path)
        if n_points is None:
            n_points = self._scan_points(frame)
        label = kitti.read_label(path, n_points)
        if self.check_labels:
            sem = (label & 0xFFFF).astype(np.int64)
            bad = sem > self.label_map.max_raw_id
            bad[~bad] = self._lut[sem[~bad]] < 0
            if bad.any():
                ids = np.unique(sem[bad])[:10].tolist()
                raise LabelFormatError(
                    path, f"raw semantic ids {ids} are not in the {self.label_map.name} label map"
                )
        return label

    def pose(self, frame: FrameRef) -> np.ndarray | None:
        poses = self._poses(frame.sequence)
        return None if poses is None else poses[frame.index]

    def timestamp(self, frame: FrameRef) -> float | None:
        times = self._times(frame.sequence)
        return None if times is None else float(times[frame.index])

    # -- helpers --------------------------------------------------------------------------
    def seq_dir(self, sequence: str) -> Path:
        return self._inside(self.root / "sequences" / sequence)

    def has_poses(self, sequence: str) -> bool:
        return (self.seq_dir(sequence) / "poses.txt").is_file()

    def poses(self, sequence: str) -> np.ndarray | None:
        """float64 ``(F, 4, 4)`` LiDAR-frame poses of a sequence, or None."""
        return self._poses(sequence)

    def _inside(self, path: Path) -> Path:
        resolved = Path(path).resolve()
        if not resolved.is_relative_to(self.root):
            raise SequenceLayoutError(path, f"path is outside the dataset root {self.root}")
        return resolved

    def _scan_points(self, frame: FrameRef) -> int:
        size = self._inside(frame.scan_path).stat().st_size
        return size // 16

    def _list_frames(self, sequence: str) -> tuple[FrameRef, ...]:
        seq = self.seq_dir(sequence)
        if not seq.is_dir():
            raise SequenceLayoutError(seq, "sequence folder does not exist")
        velo = seq / "velodyne"
        scans = sorted(velo.glob("*.bin")) if velo.is_dir() else []
        if not scans:
            raise SequenceLayoutError(velo, "sequence has no scans (velodyne/*.bin)")
        label_dir = seq / "labels"
        refs = []
        for i, scan in enumerate(scans):
            label = label_dir / f"{scan.stem}.label"
            refs.append(
                FrameRef(
                    sequence=sequence,
                    frame_id=scan.stem,
                    index=i,
                    scan_path=self._inside(scan),
                    label_path=label if label.is_file() else None,
                )
            )
        return tuple(refs)

    def _load_poses(self, sequence: str) -> np.ndarray | None:
        seq = self.seq_dir(sequence)
        if not (seq / "poses.txt").is_file():
            return None
        n = len(self._frames(sequence))
        cam = kitti.read_poses(seq / "poses.txt", n_frames=n)
        tr = kitti.read_calib(seq / "calib.txt")
        return kitti.camera_to_lidar_poses(cam[:n], tr)

    def _load_times(self, sequence: str) -> np.ndarray | None:
        path = self.seq_dir(sequence) / "times.txt"
        if not path.is_file():
            return None
        return kitti.read_times(path, n_frames=len(self._frames(sequence)))


def write_sequence_meta(
    seq_dir: str | Path, poses_lidar: np.ndarray, tr: np.ndarray, times: np.ndarray
) -> None:
    """Write ``poses.txt`` (camera frame), ``calib.txt`` and ``times.txt`` of a sequence.

    Args:
        poses_lidar: float64 ``(F, 4, 4)`` LiDAR-frame poses.
        tr: float64 ``(4, 4)`` velodyne→camera transform.
        times: float64 ``(F,)`` seconds.
    """
    seq_dir = Path(seq_dir)
    kitti.write_poses(seq_dir / "poses.txt", kitti.lidar_to_camera_poses(poses_lidar, tr))
    kitti.write_calib(seq_dir / "calib.txt", tr)
    kitti.write_times(seq_dir / "times.txt", times)


def write_frame(
    seq_dir: str | Path, frame_id: str, scan: np.ndarray, label: np.ndarray | None = None
) -> None:
    """Write one frame's scan (and label) into a sequence folder."""
    seq_dir = Path(seq_dir)
    kitti.write_scan(seq_dir / "velodyne" / f"{frame_id}.bin", scan)
    if label is not None:
        kitti.write_label(seq_dir / "labels" / f"{frame_id}.label", label)
