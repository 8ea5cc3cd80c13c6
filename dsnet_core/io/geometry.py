"""Rigid transforms as logs store them: translation + unit quaternion, and interpolation in time.

Quaternions are ``(w, x, y, z)`` here (nuScenes' order); ROS and TUM store ``(x, y, z, w)`` and
their readers reorder. Matrices are float64 ``(4, 4)`` mapping child-frame points to the parent
frame (``p_parent = T @ p_child``).
"""

from __future__ import annotations

import numpy as np


def quat_to_matrix(q_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrix float64 ``(..., 3, 3)`` of quaternions ``(..., 4)`` (w, x, y, z), normalised first."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` with w ≥ 0 of a rotation matrix ``(3, 3)`` (Shepperd's method)."""
    r = np.asarray(r, dtype=np.float64)
    tr = np.trace(r)
    i = int(np.argmax([tr, r[0, 0], r[1, 1], r[2, 2]]))
    if i == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif i == 1:
        s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif i == 2:
        s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    return q if q[0] >= 0 else -q


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
    """Spherical interpolation between unit quaternions (w, x, y, z), ``u`` in [0, 1]."""
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    dot = float(q0 @ q1)
    if dot < 0:  # the shorter arc
        q1, dot = -q1, -dot
    if dot > 1 - 1e-12:
        q = q0 + u * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(min(dot, 1.0))
    return (np.sin((1 - u) * theta) * q0 + np.sin(u * theta) * q1) / np.sin(theta)


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
