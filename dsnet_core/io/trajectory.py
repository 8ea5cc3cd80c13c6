"""TUM trajectories (``t tx ty tz qx qy qz qw`` per line, ``#`` comments) and their sampling."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dsnet_core.errors import PoseFormatError
from dsnet_core.io.geometry import sample_trajectory

Trajectory = tuple[np.ndarray, np.ndarray, np.ndarray]  # times (s), translations (T, 3), quats wxyz (T, 4)


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory, sorted by time.

    Returns:
        times float64 ``(T,)`` seconds, translations ``(T, 3)`` metres, quaternions ``(T, 4)`` (w, x, y, z).

    Raises:
        PoseFormatError: a row without 8 numbers, a zero quaternion, or no rows.
    """
    path = Path(path)
    rows = []
    for i, line in enumerate(path.read_text().splitlines()):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            vals = [float(v) for v in line.replace(",", " ").split()]
        except ValueError as exc:
            raise PoseFormatError(path, f"row {i + 1} is not numeric: {exc}") from exc
        if len(vals) != 8:
            raise PoseFormatError(
                path, f"row {i + 1} has {len(vals)} values, expected 8 (t tx ty tz qx qy qz qw)"
            )
        rows.append(vals)
    if not rows:
        raise PoseFormatError(path, "has no trajectory rows")
    a = np.array(rows, dtype=np.float64)
    a = a[np.argsort(a[:, 0], kind="stable")]
    quats = a[:, [7, 4, 5, 6]]
    norms = np.linalg.norm(quats, axis=1)
    if not np.isfinite(a).all() or (norms < 1e-9).any():
        raise PoseFormatError(path, "holds a non-finite value or a zero quaternion")
    return a[:, 0], a[:, 1:4], quats / norms[:, None]


def tum_poses_at(traj: Trajectory, times: np.ndarray, path: str | Path, tolerance: float) -> np.ndarray:
    """float64 ``(F, 4, 4)`` poses of a trajectory at ``times`` (s), interpolated.

    Raises:
        PoseFormatError: a time more than ``tolerance`` seconds outside the trajectory.
    """
    out = []
    for t in np.asarray(times, dtype=np.float64):
        pose = sample_trajectory(*traj, float(t), tolerance)
        if pose is None:
            raise PoseFormatError(
                path, f"covers [{traj[0][0]:.6f}, {traj[0][-1]:.6f}] s, not the scan time {t:.6f} s"
            )
        out.append(pose)
    return np.stack(out)
