"""Reader for folders of scan files (format ``folder``)::

ROOT/<scan>.{bin,npy,npz,pcd,ply,las,laz}    one scan per file (one suffix per folder)
ROOT/<scan>.label or ROOT/labels/<scan>.label (optional) SemanticKITTI-encoded uint32 labels
ROOT/poses.txt                                 (optional) KITTI 3×4 rows, or TUM rows
ROOT/poses.tum                                 (optional) TUM rows: t tx ty tz qx qy qz qw
ROOT/calib.txt                                 (optional) with KITTI poses.txt: camera-frame poses
ROOT/times.txt                                 (optional) one time (s) per scan, in name order

ROOT is one sequence (named after the folder) when it holds scans; otherwise each sub-folder
that holds scans is a sequence. Frames are ordered by name (natural order: ``scan2`` before
``scan10``) or, with ``order="time"``, by timestamp. Timestamps come from ``times.txt``, else
from the file names when every name is a number with at least 9 integer digits (Unix time in
s, ms, µs or ns by magnitude). KITTI ``poses.txt`` rows are the scans' sensor → world poses in
frame order (camera-frame poses converted as in SemanticKITTI when ``calib.txt`` is present);
TUM rows are interpolated at the frame timestamps (or taken row by row when the folder has no
timestamps and as many rows as scans). The intensity convention is decided per sequence on its
first scan (:func:`dsnet_core.io.intensity.infer_convention`) unless ``intensity`` states it.

Not supported (yet): several scan suffixes in one folder (choose one with ``suffix``); ``.bin``
scans other than float32 N×4 or N×5; sequences nested deeper than one sub-folder; per-point
timestamps (no motion compensation); labels other than SemanticKITTI-encoded ``.label`` files;
trajectories other than KITTI 3×4 rows and TUM rows.
"""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

import numpy as np

from dsnet_core.errors import DataFormatError, LabelFormatError, PoseFormatError, SequenceLayoutError
from dsnet_core.io import kitti
from dsnet_core.io.intensity import CONVENTIONS, infer_convention, normalise_intensity
from dsnet_core.io.options import as_label_map
from dsnet_core.io.pointfiles import SUFFIXES, bin_columns, read_points
from dsnet_core.io.reader import FrameRef
from dsnet_core.io.trajectory import read_tum, tum_poses_at
from dsnet_core.labels import LabelMap


def scan_files(folder: Path) -> dict[str, list[Path]]:
    """Scan files directly in ``folder``, grouped by (lower-case) suffix."""
    out: dict[str, list[Path]] = {}
    if folder.is_dir():
        for p in folder.iterdir():
            if p.is_file() and p.suffix.lower() in SUFFIXES and not p.name.startswith("."):
                out.setdefault(p.suffix.lower(), []).append(p)
    return out


def natural_key(name: str) -> list:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def stem_time(stem: str) -> float | None:
    """Seconds from a file stem that is a Unix time (≥ 9 integer digits; s/ms/µs/ns by magnitude)."""
    if not re.fullmatch(r"\d{9,}(\.\d+)?", stem):
        return None
    value = float(stem)
    for limit, scale in ((1e17, 1e-9), (1e14, 1e-6), (1e11, 1e-3)):
        if value >= limit:
            return value * scale
    return value


class FolderReader:
    """Reads folders of scan files (format ``folder``).

    Args:
        root: a sequence folder, or a folder of sequence folders.
        order: ``"name"`` or ``"time"``.
        intensity: ``"auto"`` or a convention (:data:`dsnet_core.io.intensity.CONVENTIONS`).
        intensity_field: the intensity field of named formats (default: first of the usual names).
        bin_columns: 4 or 5 for ``.bin`` scans; default by :func:`~dsnet_core.io.pointfiles.bin_columns`.
        suffix: the scan suffix when a folder holds several.
        label_map: the labels' map (a name, a YAML path or a LabelMap; default ``semantic-kitti``).
        pose_tolerance_s: how far outside a TUM trajectory a frame time may fall.
    """

    format = "folder"

    def __init__(
        self,
        root: str | Path,
        order: str = "name",
        intensity: str = "auto",
        intensity_field: str | None = None,
        bin_columns: int | None = None,
        suffix: str | None = None,
        label_map: LabelMap | str | None = None,
        pose_tolerance_s: float = 0.05,
    ) -> None:
        self.root = Path(root).resolve()
        if order not in ("name", "time"):
            raise SequenceLayoutError(self.root, f"order must be 'name' or 'time', got {order!r}")
        if intensity != "auto" and intensity not in CONVENTIONS:
            raise SequenceLayoutError(self.root, f"intensity must be 'auto' or one of {CONVENTIONS}")
        if bin_columns not in (None, 4, 5):
            raise SequenceLayoutError(self.root, f"bin_columns must be 4 or 5, got {bin_columns!r}")
        self.order, self._intensity = order, intensity
        self.intensity_field, self._bin_columns, self.suffix = intensity_field, bin_columns, suffix
        self.pose_tolerance_s = pose_tolerance_s
        self.label_map = as_label_map(label_map, "semantic-kitti")
        self._lut = self.label_map.lut()
        self._dirs = (
            {self.root.name: self.root}
            if scan_files(self.root)
            else {p.name: p for p in sorted(self.root.iterdir()) if p.is_dir() and scan_files(p)}
        )
        if not self._dirs:
            raise SequenceLayoutError(
                self.root, f"no scan files ({', '.join(SUFFIXES)}) here or in sub-folders"
            )
        self._frames = cache(self._list_frames)
        self._times = cache(self._load_times)
        self._poses = cache(self._load_poses)
        self._layout = cache(self._sequence_layout)
        # the last scan read: its path, its points in the file and its no-return mask (its labels
        # are checked against the count and masked by the mask without reading the scan again)
        self._last: tuple[Path, int, np.ndarray | None] | None = None

    # -- protocol ------------------------------------------------------------------------------
    def sequences(self) -> list[str]:
        return sorted(self._dirs)

    def frames(self, sequence: str) -> list[FrameRef]:
        return list(self._frames(sequence))

    def intensity_convention(self, sequence: str) -> str:
        """The source intensity convention of a sequence (stated, or inferred from its first scan)."""
        return self._layout(sequence)[1]

    def sensor_fields(self, sequence: str) -> str:
        """The fields read from the sequence's scans: x y z and the intensity field, by its first scan."""
        first = self._frames(sequence)[0].scan_path
        columns = self._layout(sequence)[0]
        pts = read_points(first, columns, self.intensity_field)
        kind = f"{first.suffix.lower()}" + (f" N×{columns}" if first.suffix.lower() == ".bin" else "")
        return f"x y z {pts.field or '(no intensity)'} ({kind})"

    def pose_source(self, sequence: str) -> str | None:
        """Where the sequence's poses come from, or None without poses."""
        folder = self._dir(sequence)
        if self._tum(sequence) is not None:
            name = "poses.tum" if (folder / "poses.tum").is_file() else "poses.txt"
            return f"{name} (TUM, at the frame times)"
        if (folder / "poses.txt").is_file():
            calib = " ∘ calib.txt Tr (camera frame)" if (folder / "calib.txt").is_file() else ""
            return f"poses.txt (KITTI 3×4){calib}"
        return None

    def scan(self, frame: FrameRef) -> np.ndarray:
        """float32 ``(N, 4)``: x, y, z (metres, sensor frame), remission 0–1."""
        columns, convention = self._layout(frame.sequence)
        pts = read_points(frame.scan_path, columns, self.intensity_field)
        out = np.empty((pts.xyz.shape[0], 4), dtype=np.float32)
        out[:, :3] = pts.xyz
        out[:, 3] = normalise_intensity(pts.intensity, convention, frame.scan_path, len(out))
        self._last = (frame.scan_path, *self._source_count(pts))
        return out

    def kept_points(self, frame: FrameRef) -> np.ndarray | None:
        """bool ``(M,)`` over the file's points: those :meth:`scan` hands out (None: all; points with
        NaN x/y/z are no returns, :func:`dsnet_core.io.checks.drop_no_returns`)."""
        return self._source(frame)[1]

    def dropped_points(self, frame: FrameRef) -> int:
        """Points without a return dropped from a frame's scan file."""
        keep = self.kept_points(frame)
        return 0 if keep is None else int(keep.size - keep.sum())

    @staticmethod
    def _source_count(pts) -> tuple[int, np.ndarray | None]:
        return (len(pts.xyz) if pts.keep is None else len(pts.keep)), pts.keep

    def _source(self, frame: FrameRef) -> tuple[int, np.ndarray | None]:
        """(points in the scan file, no-return mask or None), reading the file unless it was the last."""
        last = self._last
        if last is not None and last[0] == frame.scan_path:
            return last[1], last[2]
        pts = read_points(frame.scan_path, self._layout(frame.sequence)[0], self.intensity_field)
        self._last = (frame.scan_path, *self._source_count(pts))
        return self._last[1], self._last[2]

    def labels(self, frame: FrameRef, n_points: int | None = None) -> np.ndarray | None:
        if frame.label_path is None:
            return None
        count, keep = self._source(frame)
        label = kitti.read_label(frame.label_path, count)  # one per point of the file, no returns too
        if keep is not None:
            label = label[keep]
        sem = (label & 0xFFFF).astype(np.int64)
        bad = sem > self.label_map.max_raw_id
        bad[~bad] = self._lut[sem[~bad]] < 0
        if bad.any():
            ids = np.unique(sem[bad])[:10].tolist()
            raise LabelFormatError(
                frame.label_path, f"raw semantic ids {ids} are not in the {self.label_map.name} label map"
            )
        return label

    def pose(self, frame: FrameRef) -> np.ndarray | None:
        poses = self._poses(frame.sequence)
        return None if poses is None else poses[frame.index]

    def poses(self, sequence: str) -> np.ndarray | None:
        return self._poses(sequence)

    def timestamp(self, frame: FrameRef) -> float | None:
        times = self._times(frame.sequence)
        return None if times is None else float(times[frame.index])

    # -- helpers -------------------------------------------------------------------------------
    def _dir(self, sequence: str) -> Path:
        if sequence not in self._dirs:
            raise SequenceLayoutError(self.root / sequence, "no such sequence folder with scans")
        return self._dirs[sequence]

    def _named_files(self, sequence: str) -> list[Path]:
        """The sequence's scans in name order."""
        folder = self._dir(sequence)
        groups = scan_files(folder)
        if self.suffix:
            key = self.suffix.lower() if self.suffix.startswith(".") else f".{self.suffix.lower()}"
            files = groups.get(key, [])
        elif len(groups) > 1:
            counts = ", ".join(f"{len(v)} {k}" for k, v in sorted(groups.items()))
            raise SequenceLayoutError(
                folder, f"holds scans of several kinds ({counts}); choose one with suffix="
            )
        else:
            files = next(iter(groups.values()), [])
        if not files:
            raise SequenceLayoutError(folder, "holds no scans")
        return sorted(files, key=lambda p: natural_key(p.name))

    def _name_times(self, sequence: str) -> np.ndarray | None:
        """Times of the scans in name order (times.txt, else the file names), or None."""
        files = self._named_files(sequence)
        path = self._dir(sequence) / "times.txt"
        if path.is_file():
            return kitti.read_times(path, n_frames=len(files))[: len(files)]
        stamps = [stem_time(p.name.split(".")[0]) for p in files]
        return None if any(s is None for s in stamps) else np.array(stamps, dtype=np.float64)

    def _list_frames(self, sequence: str) -> tuple[FrameRef, ...]:
        files = self._named_files(sequence)
        if self.order == "time":
            times = self._name_times(sequence)
            if times is None:
                raise SequenceLayoutError(
                    self._dir(sequence), "order='time' needs times.txt or scans named by Unix time"
                )
            files = [files[i] for i in np.argsort(times, kind="stable")]
        refs = []
        for i, scan in enumerate(files):
            stem = scan.name[: -len(scan.suffix)]
            label = next(
                (
                    p
                    for p in (scan.with_suffix(".label"), scan.parent / "labels" / f"{stem}.label")
                    if p.is_file()
                ),
                None,
            )
            refs.append(FrameRef(sequence, stem, i, scan, label))
        return tuple(refs)

    def _load_times(self, sequence: str) -> np.ndarray | None:
        times = self._name_times(sequence)
        if times is not None and self.order == "time":
            times = np.sort(times, kind="stable")
        if times is None:
            tum = self._tum(sequence)
            if tum is not None and len(tum[0]) == len(self._frames(sequence)):
                return tum[0]
        return times

    def _tum(self, sequence: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        folder = self._dir(sequence)
        for name in ("poses.tum", "poses.txt"):
            path = folder / name
            if path.is_file() and (name.endswith(".tum") or _row_width(path) == 8):
                return read_tum(path)
        return None

    def _load_poses(self, sequence: str) -> np.ndarray | None:
        folder = self._dir(sequence)
        n = len(self._frames(sequence))
        tum = self._tum(sequence)
        if tum is not None:
            path = folder / ("poses.tum" if (folder / "poses.tum").is_file() else "poses.txt")
            times = self._name_times(sequence)
            if times is None:
                if len(tum[0]) != n:
                    raise PoseFormatError(
                        path, f"has {len(tum[0])} TUM rows for {n} scans and the scans have no timestamps"
                    )
                return tum_poses_at(tum, tum[0], path, 0.0)
            if self.order == "time":
                times = np.sort(times, kind="stable")
            return tum_poses_at(tum, times, path, self.pose_tolerance_s)
        path = folder / "poses.txt"
        if not path.is_file():
            return None
        poses = kitti.read_poses(path, n_frames=n)[:n]
        if (folder / "calib.txt").is_file():
            poses = kitti.camera_to_lidar_poses(poses, kitti.read_calib(folder / "calib.txt"))
        return poses

    def _sequence_layout(self, sequence: str) -> tuple[int, str]:
        """(.bin columns, intensity convention) of a sequence, decided once on its first scan that
        reads: a bad first scan is that frame's problem (quarantined alone with ``--on-error skip``),
        not every frame's. With no readable scan, the first scan's error."""
        first = self._frames(sequence)[0].scan_path
        columns = self._bin_columns or 4
        if first.suffix.lower() == ".bin" and self._bin_columns is None:
            files = [f.scan_path for f in self._frames(sequence)]
            columns = bin_columns([p.stat().st_size for p in files], first.read_bytes())
        if self._intensity != "auto":
            return columns, self._intensity
        first_error: DataFormatError | None = None
        for frame in self._frames(sequence):
            path = frame.scan_path
            try:
                intensity = read_points(path, columns, self.intensity_field).intensity
                return columns, infer_convention(intensity, path)
            except DataFormatError as exc:
                first_error = first_error or exc
        assert first_error is not None  # a sequence has at least one scan
        raise first_error


def _row_width(path: Path) -> int:
    for line in path.read_text().splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            return len(line.split())
    return 0
