"""Checks every reader applies to the points it hands out, whatever the log's format."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dsnet_core.errors import ScanFormatError

MAX_COORD_M = 1.0e4
"""Largest accepted ``|x|``, ``|y|``, ``|z|`` of a sensor-frame point, metres. LiDARs see a few
hundred metres; anything beyond 10 km is a corrupt value (a bit flip, an uninitialised buffer), and
values near float32's limit overflow to inf once transformed into the world frame."""


def drop_no_returns(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Drop the points a sensor reports without a return: NaN in x, y or z (organised PCD and
    PointCloud2 clouds keep their grid shape that way). Other bad values (inf, far coordinates) are
    not dropped here: :func:`check_points` refuses them.

    Args:
        xyz: float ``(M, 3)`` metres.

    Returns:
        ``(kept xyz (N, 3), keep)``: ``keep`` is bool ``(M,)`` over the source's points, or None when
        every point has a return (then ``xyz`` is returned as it is).
    """
    keep = ~np.isnan(xyz).any(axis=1)
    if keep.all():
        return xyz, None
    return xyz[keep], keep


def check_points(path: str | Path, scan: np.ndarray, max_coord: float = MAX_COORD_M) -> None:
    """Reject a scan holding NaN/inf values, coordinates beyond ``max_coord``, or two or more points
    that are all the same point (no LiDAR returns that: zeroed coordinates, a LAS scale of 0).

    Args:
        path: the file the scan came from (named in the error).
        scan: float32 ``(N, C)``, columns 0..2 are x, y, z in metres (sensor frame).
        max_coord: largest accepted absolute coordinate, metres.

    Raises:
        ScanFormatError: naming ``path``, the number of bad points and the first one's index (or
            the point every point is).
    """
    # whole-array reductions first (a scan is almost always fine): per-point ones only to name the
    # bad points (10x faster on a 124k-point scan)
    if not np.isfinite(scan).all():
        finite = np.isfinite(scan).all(axis=1)
        n_bad, first = int((~finite).sum()), int(np.argmin(finite))
        raise ScanFormatError(path, f"{n_bad} points have NaN or inf values (first: point {first})")
    if scan.shape[0] and np.abs(scan[:, :3]).max() > max_coord:
        far = (np.abs(scan[:, :3]) > max_coord).any(axis=1)
        first = int(np.argmax(far))
        raise ScanFormatError(
            path,
            f"{int(far.sum())} points lie beyond {max_coord:g} m of the sensor (first: point {first} at "
            f"{np.array2string(scan[first, :3], precision=3)}): corrupt coordinates",
        )
    if _all_the_same(scan[:, :3]):
        raise ScanFormatError(
            path,
            f"all {scan.shape[0]} points are the same point ({_xyz(scan[0, :3])}) m: "
            "a degenerate scan (zeroed coordinates or a broken scale)",
        )


def _all_the_same(xyz: np.ndarray) -> bool:
    """True for two or more points that are all equal (the second point decides most scans at once)."""
    if xyz.shape[0] < 2 or (xyz[1] != xyz[0]).any():
        return False
    return bool((xyz == xyz[0]).all())


def _xyz(point: np.ndarray) -> str:
    return ", ".join(f"{v:g}" for v in point.tolist())
