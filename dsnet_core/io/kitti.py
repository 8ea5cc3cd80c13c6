"""SemanticKITTI file formats: scans, labels, poses, calibration, timestamps.

Conventions:
    scan  ``velodyne/NNNNNN.bin``   float32 ``(N, 4)``: x, y, z (metres), remission.
    label ``labels/NNNNNN.label``   uint32 ``(N,)``: raw semantic | instance << 16.
    poses ``poses.txt``             one row-major 3×4 camera-frame pose per frame.
    calib ``calib.txt``             line ``Tr:`` is the 3×4 velodyne→camera transform.
    times ``times.txt``             one timestamp (s) per frame.
LiDAR-frame poses are ``Tr⁻¹ · P · Tr``.

Rows of ``poses.txt`` and ``times.txt`` are paired with scans by frame number, never by position:
row ``i`` (0-based, counting every line) belongs to scan ``i`` (``NNNNNN.bin`` with ``int(NNNNNN) = i``).
A gap in the scan numbering therefore skips rows, and a blank line inside the file is a frame
without a value (an error only when that frame's scan exists); blank lines at the end are ignored.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from dsnet_core.errors import LabelFormatError, PoseFormatError, ScanFormatError
from dsnet_core.io.checks import check_points

RIGID_TOL = 1e-3


def read_scan(path: str | Path) -> np.ndarray:
    """Read a ``.bin`` scan as float32 ``(N, 4)``.

    Raises:
        ScanFormatError: size not a multiple of 16 bytes, NaN/inf values, or coordinates beyond
            :data:`~dsnet_core.io.checks.MAX_COORD_M` (see :func:`~dsnet_core.io.checks.check_points`).
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:  # one read into the array (no bytes object, no copy)
            size = os.fstat(f.fileno()).st_size
            if size % 16:
                what = "is not a multiple of 16 (float32 x, y, z, remission): truncated?"
                raise ScanFormatError(path, f"size {size} bytes {what}")
            scan = np.empty((size // 16, 4), np.float32)
            got = f.readinto(memoryview(scan).cast("B")) if size else 0  # an empty scan: no view to cast
    except OSError as exc:
        raise ScanFormatError(path, f"cannot read scan: {exc.strerror or exc}") from exc
    if got != size:
        raise ScanFormatError(path, f"read {got} of its {size} bytes: the file changed while it was read")
    check_points(path, scan)
    return scan


def write_scan(path: str | Path, scan: np.ndarray) -> None:
    """Write float32 ``(N, 4)`` to a ``.bin`` file (atomically)."""
    scan = np.ascontiguousarray(scan, dtype=np.float32)
    if scan.ndim != 2 or scan.shape[1] != 4:
        raise ValueError(f"scan must be (N, 4), got {scan.shape}")
    _atomic_write_bytes(Path(path), scan.tobytes())


def read_label(path: str | Path, n_points: int | None = None) -> np.ndarray:
    """Read a ``.label`` file as uint32 ``(N,)``.

    Args:
        n_points: the scan's point count; a different length raises.

    Raises:
        LabelFormatError: size not a multiple of 4 bytes or length ≠ ``n_points``.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise LabelFormatError(path, f"cannot read labels: {exc.strerror or exc}") from exc
    if len(raw) % 4:
        raise LabelFormatError(path, f"size {len(raw)} bytes is not a multiple of 4 (uint32 labels)")
    label = np.frombuffer(raw, dtype=np.uint32).copy()
    if n_points is not None and label.shape[0] != n_points:
        raise LabelFormatError(path, f"has {label.shape[0]} labels but the scan has {n_points} points")
    return label


def write_label(path: str | Path, label: np.ndarray) -> None:
    """Write uint32 ``(N,)`` labels (atomically)."""
    label = np.ascontiguousarray(label, dtype=np.uint32)
    if label.ndim != 1:
        raise ValueError(f"label must be (N,), got {label.shape}")
    _atomic_write_bytes(Path(path), label.tobytes())


def split_label(label: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """uint32 ``(N,)`` -> (raw semantic ``(N,) uint32``, instance ``(N,) uint32``)."""
    label = np.asarray(label, dtype=np.uint32)
    return label & 0xFFFF, label >> 16


def join_label(semantic: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """(raw semantic, instance) -> uint32 ``semantic | instance << 16``."""
    sem = np.asarray(semantic, dtype=np.uint32)
    ins = np.asarray(instance, dtype=np.uint32)
    if sem.size and sem.max() > 0xFFFF:
        raise ValueError("semantic ids must fit in 16 bits")
    if ins.size and ins.max() > 0xFFFF:
        raise ValueError("instance ids must fit in 16 bits")
    return sem | (ins << 16)


def read_calib(path: str | Path) -> np.ndarray:
    """Read the ``Tr:`` line of ``calib.txt`` as a float64 ``(4, 4)`` velodyne→camera transform.

    Raises:
        PoseFormatError: file missing, ``Tr`` missing or malformed, or not rigid.
    """
    path = Path(path)
    if not path.is_file():
        raise PoseFormatError(path, "calib.txt is missing (needed to turn camera poses into LiDAR poses)")
    for line in _lines(path):
        key, _, values = line.partition(":")
        if key.strip() == "Tr":
            try:
                vals = np.array([float(v) for v in values.split()], dtype=np.float64)
            except ValueError as exc:
                raise PoseFormatError(path, f"line 'Tr:' is not numeric: {exc}") from exc
            if vals.size != 12:
                raise PoseFormatError(path, f"line 'Tr:' has {vals.size} values, expected 12")
            tr = _to_4x4(vals)
            _check_rigid(tr, path, "Tr")
            return tr
    raise PoseFormatError(path, "no 'Tr:' line (velodyne→camera transform)")


def write_calib(path: str | Path, tr: np.ndarray) -> None:
    """Write a ``calib.txt`` with the 3×4 ``Tr`` (and identity P0..P3 for compatibility)."""
    p = " ".join(f"{v:.12e}" for v in np.eye(4)[:3].reshape(-1))
    t = " ".join(f"{v:.12e}" for v in np.asarray(tr, dtype=np.float64)[:3].reshape(-1))
    lines = [f"P{i}: {p}" for i in range(4)] + [f"Tr: {t}"]
    _atomic_write_bytes(Path(path), ("\n".join(lines) + "\n").encode())


def read_pose_rows(path: str | Path) -> list[np.ndarray | None]:
    """Read ``poses.txt`` row by row: entry ``i`` is frame ``i``'s float64 ``(4, 4)`` camera-frame
    pose, or None where line ``i + 1`` is blank (trailing blank lines are dropped).

    Raises:
        PoseFormatError: file missing, a row not numeric or not 12 values, or a non-rigid rotation.
    """
    path = Path(path)
    if not path.is_file():
        raise PoseFormatError(path, "poses.txt is missing")
    rows: list[np.ndarray | None] = []
    for i, line in enumerate(_lines(path)):
        if not line.strip():
            rows.append(None)
            continue
        try:
            vals = np.array([float(v) for v in line.split()], dtype=np.float64)
        except ValueError as exc:
            raise PoseFormatError(path, f"row {i + 1} is not numeric: {exc}") from exc
        if vals.size != 12:
            raise PoseFormatError(path, f"row {i + 1} has {vals.size} values, expected 12 (3×4 matrix)")
        pose = _to_4x4(vals)
        _check_rigid(pose, path, f"row {i + 1}")
        rows.append(pose)
    return rows


def read_poses(path: str | Path, n_frames: int | None = None) -> np.ndarray:
    """Read ``poses.txt`` as float64 ``(F, 4, 4)`` camera-frame poses, row ``i`` = frame ``i``.

    Raises:
        PoseFormatError: as :func:`read_pose_rows`; also a blank line among the rows, or fewer
            rows than ``n_frames``.
    """
    path = Path(path)
    rows = read_pose_rows(path)
    blank = [i for i, r in enumerate(rows) if r is None]
    if blank:
        raise PoseFormatError(path, f"line {blank[0] + 1} is blank: row i is frame i's pose")
    if n_frames is not None and len(rows) < n_frames:
        raise PoseFormatError(path, f"has {len(rows)} poses but the sequence has {n_frames} frames")
    return np.stack(rows) if rows else np.zeros((0, 4, 4))


def write_poses(path: str | Path, poses: np.ndarray) -> None:
    """Write ``(F, 4, 4)`` camera-frame poses as row-major 3×4 rows."""
    poses = np.asarray(poses, dtype=np.float64)
    text = "".join(" ".join(f"{v:.12e}" for v in p[:3].reshape(-1)) + "\n" for p in poses)
    _atomic_write_bytes(Path(path), text.encode())


def read_time_rows(path: str | Path) -> list[float | None]:
    """Read ``times.txt`` row by row: entry ``i`` is frame ``i``'s time in seconds, or None where
    line ``i + 1`` is blank (trailing blank lines are dropped).

    Raises:
        PoseFormatError: a row that is not one number.
    """
    path = Path(path)
    rows: list[float | None] = []
    for i, line in enumerate(_lines(path)):
        if not line.strip():
            rows.append(None)
            continue
        try:
            (value,) = (float(v) for v in line.split())
        except ValueError as exc:
            raise PoseFormatError(path, f"row {i + 1} is not one number: {line.strip()[:40]!r}") from exc
        rows.append(value)
    return rows


def read_times(path: str | Path, n_frames: int | None = None) -> np.ndarray:
    """Read ``times.txt`` as float64 ``(F,)`` seconds, row ``i`` = frame ``i``.

    Raises:
        PoseFormatError: as :func:`read_time_rows`; also a blank line among the rows, or fewer
            rows than ``n_frames``.
    """
    path = Path(path)
    rows = read_time_rows(path)
    blank = [i for i, r in enumerate(rows) if r is None]
    if blank:
        raise PoseFormatError(path, f"line {blank[0] + 1} is blank: row i is frame i's timestamp")
    if n_frames is not None and len(rows) < n_frames:
        raise PoseFormatError(path, f"has {len(rows)} timestamps but the sequence has {n_frames} frames")
    return np.asarray(rows, dtype=np.float64)


def write_times(path: str | Path, times: np.ndarray) -> None:
    text = "".join(f"{t:.6e}\n" for t in np.asarray(times, dtype=np.float64))
    _atomic_write_bytes(Path(path), text.encode())


def camera_to_lidar_poses(poses_cam: np.ndarray, tr: np.ndarray) -> np.ndarray:
    """LiDAR-frame poses ``Tr⁻¹ · P · Tr`` from camera-frame poses. ``(F, 4, 4)`` float64."""
    return np.linalg.inv(tr)[None] @ poses_cam @ tr[None]


def lidar_to_camera_poses(poses_lidar: np.ndarray, tr: np.ndarray) -> np.ndarray:
    """Inverse of :func:`camera_to_lidar_poses`: ``Tr · Q · Tr⁻¹``."""
    return tr[None] @ poses_lidar @ np.linalg.inv(tr)[None]


def _lines(path: Path) -> list[str]:
    """The file's lines without trailing blank ones."""
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise PoseFormatError(path, f"cannot read: {exc}") from exc
    while lines and not lines[-1].strip():
        lines.pop()
    return lines


def _to_4x4(vals: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3] = vals.reshape(3, 4)
    return m


def _check_rigid(m: np.ndarray, path: Path, where: str) -> None:
    r = m[:3, :3]
    err = np.abs(r.T @ r - np.eye(3)).max()
    det = np.linalg.det(r)
    if not np.isfinite(m).all() or err > RIGID_TOL or abs(det - 1.0) > RIGID_TOL:
        raise PoseFormatError(
            path, f"{where} is not a rigid transform (|RᵀR − I| = {err:.2e}, det R = {det:.4f})"
        )


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_bytes(data)
    os.replace(tmp, path)
