"""4D volumes: k consecutive scans moved into the reference scan's sensor frame (4D-DS-Net eq. 7).

Eq. 7 in row-vector form, ``P' = ((P R_src⁻¹ + T_src) − T_ref) R_ref``, is, with 4×4 LiDAR-frame
poses ``M = [R | t]`` (sensor → world, column-vector form), ``p' = M_ref⁻¹ · M_src · p``: to the
world with the scan's own pose, then into the reference scan's frame.

A window of k scans ends at its reference scan (the newest): past scans are brought forward.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def plan_windows(n_frames: int, scans: int, stride: int) -> list[tuple[int, ...]]:
    """Windows of ``scans`` consecutive positions with step ``stride``, covering every position.

    The last window is moved to end at the last position when the stride does not land there;
    with fewer frames than ``scans`` one window holds them all.

    Returns:
        tuples of positions ``0..n_frames-1``; the last of each is the reference.
    """
    if scans < 1 or stride < 1:
        raise ValueError(f"scans ({scans}) and stride ({stride}) must be ≥ 1")
    if stride > scans:
        raise ValueError(f"stride {stride} > scans {scans} would skip frames")
    if n_frames <= 0:
        return []
    if n_frames <= scans:
        return [tuple(range(n_frames))]
    starts = list(range(0, n_frames - scans + 1, stride))
    if starts[-1] + scans < n_frames:
        starts.append(n_frames - scans)
    return [tuple(range(s, s + scans)) for s in starts]


def relative_transform(pose_src: np.ndarray, pose_ref: np.ndarray) -> np.ndarray:
    """float64 ``(4, 4)`` taking points of the source scan into the reference scan's frame."""
    return np.linalg.solve(np.asarray(pose_ref, np.float64), np.asarray(pose_src, np.float64))


def to_reference(xyz: np.ndarray, pose_src: np.ndarray, pose_ref: np.ndarray) -> np.ndarray:
    """Eq. 7: ``(N, 3)`` points (m, source sensor frame) -> float64 ``(N, 3)`` in the reference frame."""
    m = relative_transform(pose_src, pose_ref)
    return np.asarray(xyz, np.float64) @ m[:3, :3].T + m[:3, 3]


@dataclass(frozen=True)
class Volume:
    """k aligned scans concatenated.

    Attributes:
        points: float32 ``(P, 4)``: x, y, z (m, reference frame), remission.
        source_frame: int32 ``(P,)``: frame index (in the sequence) of each point.
        source_index: int32 ``(P,)``: index of the point in its source scan.
        labels: uint32 ``(P,)`` ground truth travelling with the points, or None.
    """

    points: np.ndarray
    source_frame: np.ndarray
    source_index: np.ndarray
    labels: np.ndarray | None = None


def build_volume(
    scans: list[np.ndarray],
    poses: list[np.ndarray],
    frame_indices: list[int],
    labels: list[np.ndarray] | None = None,
) -> Volume:
    """Concatenate scans in the frame of the last one.

    Args:
        scans: float32 ``(N_i, 4)`` per scan (x, y, z in its sensor frame, remission).
        poses: float64 ``(4, 4)`` LiDAR-frame pose per scan.
        frame_indices: the scans' frame indices in the sequence; the last is the reference.
        labels: uint32 ``(N_i,)`` per scan, or None.
    """
    if not (len(scans) == len(poses) == len(frame_indices)) or not scans:
        raise ValueError("scans, poses and frame_indices must be non-empty and of equal length")
    ref = poses[-1]
    points, src_f, src_i = [], [], []
    for scan, pose, f in zip(scans, poses, frame_indices, strict=True):
        out = np.empty((scan.shape[0], 4), np.float32)
        out[:, :3] = to_reference(scan[:, :3], pose, ref)
        out[:, 3] = scan[:, 3]
        points.append(out)
        src_f.append(np.full(scan.shape[0], f, np.int32))
        src_i.append(np.arange(scan.shape[0], dtype=np.int32))
    lab = None
    if labels is not None:
        if [len(x) for x in labels] != [s.shape[0] for s in scans]:
            raise ValueError("labels and scans differ in length")
        lab = np.concatenate(labels).astype(np.uint32)
    return Volume(np.concatenate(points), np.concatenate(src_f), np.concatenate(src_i), lab)


def split_volume(
    values: np.ndarray, source_frame: np.ndarray, source_index: np.ndarray
) -> dict[int, np.ndarray]:
    """Split per-point ``values`` ``(P, ...)`` of a volume back into its scans, in scan order.

    Returns:
        ``{frame index: values of that scan (N_f, ...)}`` with ``out[f][source_index] = values``.
    """
    out: dict[int, np.ndarray] = {}
    for f in np.unique(source_frame):
        sel = source_frame == f
        idx = source_index[sel]
        if idx.size and (np.sort(idx) != np.arange(idx.size)).any():
            raise ValueError(f"source indices of frame {int(f)} are not a permutation of 0..{idx.size - 1}")
        part = np.empty((idx.size, *values.shape[1:]), dtype=values.dtype)
        part[idx] = values[sel]
        out[int(f)] = part
    return out
