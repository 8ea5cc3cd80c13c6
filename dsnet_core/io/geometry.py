"""Rigid transforms as logs store them: translation + unit quaternion, and interpolation in time.

Quaternions are ``(w, x, y, z)`` here (nuScenes' order); ROS and TUM store ``(x, y, z, w)`` and
their readers reorder. Matrices are float64 ``(4, 4)`` mapping child-frame points to the parent
frame (``p_parent = T @ p_child``).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


def quat_to_matrix(q_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrix float64 ``(..., 3, 3)`` of quaternions ``(..., 4)`` (w, x, y, z), normalised first
    (scipy's :class:`~scipy.spatial.transform.Rotation`)."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    flat = Rotation.from_quat(q.reshape(-1, 4), scalar_first=True).as_matrix()
    return flat.reshape(*q.shape[:-1], 3, 3)


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` with w ≥ 0 of a rotation matrix ``(3, 3)``."""
    return Rotation.from_matrix(np.asarray(r, dtype=np.float64)).as_quat(canonical=True, scalar_first=True)


def pose_matrix(translation: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
    """float64 ``(..., 4, 4)`` from translations ``(..., 3)`` (metres) and quaternions ``(..., 4)``."""
    t = np.asarray(translation, dtype=np.float64)
    r = quat_to_matrix(q_wxyz)
    out = np.zeros((*r.shape[:-2], 4, 4))
    out[..., :3, :3] = r
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def slerp(q0: np.ndarray, q1: np.ndarray, u: float) -> np.ndarray:
    """Spherical interpolation (the shorter arc) between unit quaternions (w, x, y, z), ``u`` in [0, 1]."""
    ends = Rotation.from_quat(np.stack([q0, q1]).astype(np.float64), scalar_first=True)
    return Slerp([0.0, 1.0], ends)([float(u)]).as_quat(scalar_first=True)[0]


def interpolate_pose(
    t0: float, p0: tuple[np.ndarray, np.ndarray], t1: float, p1: tuple[np.ndarray, np.ndarray], t: float
) -> np.ndarray:
    """The ``(4, 4)`` pose at ``t`` between (translation, quaternion wxyz) samples at ``t0 ≤ t ≤ t1``:
    translation linear, rotation spherical."""
    u = 0.0 if t1 == t0 else (t - t0) / (t1 - t0)
    trans = np.asarray(p0[0]) + u * (np.asarray(p1[0]) - np.asarray(p0[0]))
    return pose_matrix(trans, slerp(p0[1], p1[1], u))


def sample_trajectory(
    times: np.ndarray, translations: np.ndarray, quats_wxyz: np.ndarray, t: float, tolerance: float
) -> np.ndarray | None:
    """The pose at ``t`` of a trajectory sampled at sorted ``times`` (s), or None when ``t`` lies
    more than ``tolerance`` seconds outside it (inside that margin the end sample is used)."""
    n = len(times)
    if n == 0 or t < times[0] - tolerance or t > times[-1] + tolerance:
        return None
    j = int(np.searchsorted(times, t))
    if j < n and times[j] == t:
        return pose_matrix(translations[j], quats_wxyz[j])
    if j == 0:
        return pose_matrix(translations[0], quats_wxyz[0])
    if j >= n:
        return pose_matrix(translations[-1], quats_wxyz[-1])
    return interpolate_pose(
        times[j - 1],
        (translations[j - 1], quats_wxyz[j - 1]),
        times[j],
        (translations[j], quats_wxyz[j]),
        t,
    )
