"""Reader and writer for logs in the SemanticKITTI layout::

ROOT/sequences/SS/velodyne/NNNNNN.bin
ROOT/sequences/SS/labels/NNNNNN.label      (optional)
ROOT/sequences/SS/poses.txt + calib.txt    (optional, together)
ROOT/sequences/SS/times.txt                (optional)

Scans are the regular files ``velodyne/<digits>.bin``; the digits are the frame number, and row
``i`` of ``poses.txt``/``times.txt`` belongs to frame number ``i`` (KITTI's convention; a gap in
the numbering skips rows). Hidden entries of ``velodyne/`` (names starting with ``.``, such as
macOS ``._000001.bin``) and files not ending in ``.bin`` are ignored; any other ``*.bin`` entry
(``000001 (copy).bin``, a folder named ``000004.bin``) is a :class:`SequenceLayoutError` naming it.
"""

from __future__ import annotations

import os
import re
from functools import cache
from pathlib import Path

import numpy as np

from dsnet_core.errors import LabelFormatError, PoseFormatError, SequenceLayoutError
from dsnet_core.io import kitti
from dsnet_core.io.options import as_label_map
from dsnet_core.io.reader import FrameRef
from dsnet_core.labels import LabelMap


class SemanticKittiReader:
    """Reads ``ROOT/sequences/*`` and checks every file it hands out (format ``semantickitti``).

    Args:
        root: dataset root (the folder holding ``sequences/``).
        label_map: the labels' map (a LabelMap, a bundled map's name or a YAML path; default
            ``semantic-kitti``), used to reject raw semantic ids the map does not know.
        check_labels: validate raw semantic ids on read.
    """

    def __init__(
        self,
        root: str | Path,
        label_map: LabelMap | str | None = None,
        check_labels: bool = True,
    ) -> None:
        self.root = Path(root).resolve()
        self.format = "semantickitti"
        self.label_map = as_label_map(label_map, "semantic-kitti")
        self.check_labels = check_labels
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

    def intensity_convention(self, sequence: str) -> str:
        """SemanticKITTI remission is already the model's 0–1 convention."""
        return "unit"

    def sensor_fields(self, sequence: str) -> str:
        """The per-point fields of the source scans."""
        return "x y z remission (float32 N×4)"

    def pose_source(self, sequence: str) -> str | None:
        """Where the sequence's poses come from, or None without poses."""
        return "poses.txt (camera frame) ∘ calib.txt Tr" if self.has_poses(sequence) else None

    def labels(self, frame: FrameRef, n_points: int | None = None) -> np.ndarray | None:
        if frame.label_path is None:
            return None
        path = self._inside(frame.label_path)
        if n_points is None:
            n_points = self._scan_points(frame)
        label = kitti.read_label(path, n_points)
        if self.check_labels:
            check_raw_ids(path, label, self.label_map)
        return label

    def pose(self, frame: FrameRef) -> np.ndarray | None:
        """Row ``int(frame_id)`` of ``poses.txt`` as a LiDAR-frame pose.

        Raises:
            PoseFormatError: the file has no pose for this frame (short, or a blank line there).
        """
        table = self._poses(frame.sequence)
        if table is None:
            return None
        rows, tr = table
        cam = self._row(rows, frame, "poses.txt", "pose")
        return kitti.camera_to_lidar_poses(cam[None], tr)[0]

    def timestamp(self, frame: FrameRef) -> float | None:
        rows = self._times(frame.sequence)
        return None if rows is None else float(self._row(rows, frame, "times.txt", "timestamp"))

    # -- helpers --------------------------------------------------------------------------
    def seq_dir(self, sequence: str) -> Path:
        return self._inside(self.root / "sequences" / sequence)

    def has_poses(self, sequence: str) -> bool:
        return (self.seq_dir(sequence) / "poses.txt").is_file()

    def poses(self, sequence: str) -> np.ndarray | None:
        """float64 ``(F, 4, 4)`` LiDAR-frame poses of a sequence's frames (by frame number), or None.

        Raises:
            PoseFormatError: a frame has no row in ``poses.txt``.
        """
        if self._poses(sequence) is None:
            return None
        return np.stack([self.pose(f) for f in self._frames(sequence)])

    def _row(self, rows: list, frame: FrameRef, name: str, what: str):
        number = int(frame.frame_id)
        value = rows[number] if number < len(rows) else None
        if value is None:
            path = self.seq_dir(frame.sequence) / name
            where = f"line {number + 1} is blank" if number < len(rows) else f"it has {len(rows)} rows"
            raise PoseFormatError(
                path,
                f"no {what} for frame {frame.frame_id} ({frame.scan_path.name}): {where}, and row i "
                f"of {name} is frame i's {what}",
            )
        return value

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
        scans = _scan_files(velo) if velo.is_dir() else []
        if not scans:
            raise SequenceLayoutError(velo, "sequence has no scans (velodyne/*.bin)")
        label_dir = seq / "labels"
        labels = _file_names(label_dir)
        # the folder resolved once: an entry that is no link resolves to the folder's path + its name
        # (resolving every scan cost ~0.1 ms a frame, and a stage lists the frames in every block)
        velo_real = self._inside(velo)
        refs = []
        for i, scan in enumerate(scans):
            label = f"{scan.stem}.label"
            refs.append(
                FrameRef(
                    sequence=sequence,
                    frame_id=scan.stem,
                    index=i,
                    scan_path=self._inside(scan) if scan.is_symlink() else velo_real / scan.name,
                    label_path=label_dir / label if label in labels else None,
                )
            )
        return tuple(refs)

    def _load_poses(self, sequence: str) -> tuple[list[np.ndarray | None], np.ndarray] | None:
        """(camera-frame pose rows of ``poses.txt``, ``Tr``), or None without ``poses.txt``."""
        seq = self.seq_dir(sequence)
        if not (seq / "poses.txt").is_file():
            return None
        return kitti.read_pose_rows(seq / "poses.txt"), kitti.read_calib(seq / "calib.txt")

    def _load_times(self, sequence: str) -> list[float | None] | None:
        path = self.seq_dir(sequence) / "times.txt"
        return kitti.read_time_rows(path) if path.is_file() else None


_SCAN_NAME = re.compile(r"[0-9]+\.bin")


def _file_names(folder: Path) -> set[str]:
    """Names of the files (links to files included, as ``Path.is_file``) in ``folder``; empty when
    it is no folder."""
    try:
        with os.scandir(folder) as entries:
            return {e.name for e in entries if e.is_file()}
    except (FileNotFoundError, NotADirectoryError):
        return set()


def _scan_files(velo: Path) -> list[Path]:
    """The scans of a ``velodyne/`` folder, sorted by frame number (see the module's rule).

    Raises:
        SequenceLayoutError: a ``*.bin`` entry that is not a regular file named ``<digits>.bin``,
            or two names with the same frame number (``1.bin`` and ``000001.bin``).
    """
    scans: dict[int, Path] = {}
    for entry in sorted(velo.iterdir()):
        name = entry.name
        if name.startswith(".") or not name.endswith(".bin"):
            continue
        if not _SCAN_NAME.fullmatch(name):
            raise SequenceLayoutError(
                entry, "not a scan name: scans are <frame number>.bin (digits only); move it out of velodyne/"
            )
        if not entry.is_file():
            raise SequenceLayoutError(entry, "is not a regular file (scans are files <frame number>.bin)")
        number = int(entry.stem)
        if number in scans:
            raise SequenceLayoutError(entry, f"frame number {number} is also {scans[number].name}")
        scans[number] = entry
    return [scans[n] for n in sorted(scans)]


def check_raw_ids(path: str | Path, label: np.ndarray, label_map: LabelMap) -> None:
    """Refuse a label file holding raw semantic ids ``label_map`` does not know.

    Args:
        label: uint32 ``(N,)`` raw semantic | instance << 16.

    Raises:
        LabelFormatError: naming ``path``, up to ten unknown ids and the map.
    """
    bad = label_map.unknown_raw_ids(np.asarray(label, dtype=np.uint32) & 0xFFFF)
    if bad.size:
        raise LabelFormatError(
            path, f"raw semantic ids {bad[:10].tolist()} are not in the {label_map.name} label map"
        )


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
