"""LiDAR poses for logs without ``poses.txt``: KISS-ICP odometry, and trajectory drift metrics.

KISS-ICP (PyPI ``kiss-icp``, an optional extra: ``pip install 'dsnet-pipeline[odometry]'``)
registers each scan against a local voxel map. Its poses are LiDAR-frame poses (sensor → world)
with the world being the first scan's sensor frame, so ``calib.txt``'s ``Tr`` is the identity
for such logs. The package is imported only when poses are estimated.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from dsnet_core.errors import DsnetError

log = logging.getLogger(__name__)

INSTALL_HINT = "pip install 'dsnet-pipeline[odometry]'  (or: pip install kiss-icp)"


class OdometryError(DsnetError):
    """Poses cannot be estimated (the odometry package is missing, or the input is unusable)."""


@dataclass(frozen=True)
class OdometryConfig:
    """KISS-ICP settings.

    Attributes:
        max_range, min_range: points kept for registration, metres from the sensor.
        voxel_size: map voxel size, metres; None = ``max_range / 100`` (KISS-ICP's default).
        max_points_per_voxel: points kept per map voxel.
        threads: registration threads (1 on these shared machines; 0 = all cores).
    """

    max_range: float = 100.0
    min_range: float = 0.0
    voxel_size: float | None = None
    max_points_per_voxel: int = 20
    threads: int = 1


def _kiss_icp(config: OdometryConfig):
    try:
        from kiss_icp.config import KISSConfig
        from kiss_icp.config.config import DataConfig, MappingConfig, RegistrationConfig
        from kiss_icp.kiss_icp import KissICP
    except ImportError as exc:
        raise OdometryError(f"pose estimation needs KISS-ICP, not installed: {INSTALL_HINT}") from exc
    voxel = config.voxel_size if config.voxel_size is not None else config.max_range / 100.0
    cfg = KISSConfig(
        data=DataConfig(max_range=config.max_range, min_range=config.min_range, deskew=False),
        mapping=MappingConfig(voxel_size=voxel, max_points_per_voxel=config.max_points_per_voxel),
        registration=RegistrationConfig(max_num_threads=config.threads),
    )
    return KissICP(cfg)


class Odometry:
    """KISS-ICP over one sequence, one scan at a time in frame order (a local map, constant memory).

    A scan left out (e.g. a quarantined frame) is simply not registered: the next scan's initial
    guess is then one frame's motion short, which ICP absorbs at driving speeds.
    """

    def __init__(self, config: OdometryConfig | None = None) -> None:
        self._odom = _kiss_icp(config or OdometryConfig())

    def register(self, scan: np.ndarray, name: str = "scan") -> np.ndarray:
        """Register the next scan.

        Args:
            scan: ``(N, 3+)`` points in the sensor frame (metres); extra columns ignored.
            name: what error messages call the scan (an index or a file).

        Returns:
            ``(4, 4) float64`` sensor → world pose, the first registered scan's frame being the world.

        Raises:
            OdometryError: the scan has fewer than 3 points, or non-finite ones.
        """
        xyz = np.ascontiguousarray(np.asarray(scan)[:, :3], dtype=np.float64)
        if xyz.shape[0] < 3 or not np.isfinite(xyz).all():
            raise OdometryError(f"{name}: needs at least 3 finite points, got {xyz.shape[0]}")
        self._odom.register_frame(xyz, np.zeros(xyz.shape[0]))
        return np.array(self._odom.last_pose, dtype=np.float64)


def estimate_poses(scans: Iterable[np.ndarray], config: OdometryConfig | None = None) -> np.ndarray:
    """LiDAR-frame poses of a sequence by KISS-ICP, the first scan's frame being the world.

    Args:
        scans: per frame ``(N, 3+)`` points in the sensor frame (metres); extra columns ignored.
        config: odometry settings.

    Returns:
        ``(F, 4, 4) float64`` sensor → world poses; ``poses[0]`` is the identity.

    Raises:
        OdometryError: KISS-ICP is not installed, or a scan has fewer than 3 finite points.
    """
    odom = Odometry(config)
    poses = [odom.register(scan, f"scan {i}") for i, scan in enumerate(scans)]
    return np.stack(poses) if poses else np.zeros((0, 4, 4))


def _angle(r: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))


def trajectory_drift(estimated: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Compare an estimated trajectory with the true one, both expressed from their first pose.

    Args:
        estimated, truth: ``(F, 4, 4)`` sensor → world poses (any world frames).

    Returns:
        ``path_m``: true path length; ``end_translation_pct``: end-point position error over the
        path length (%); ``end_rotation_deg_per_m``: end-point heading error per metre;
        ``rpe_translation_pct``: mean frame-to-frame translation error over the mean step (%);
        ``rpe_rotation_deg``: mean frame-to-frame rotation error; ``max_position_error_m``.
    """
    est = np.linalg.inv(estimated[0]) @ estimated
    gt = np.linalg.inv(truth[0]) @ truth
    steps = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)
    path = float(steps.sum())
    end = np.linalg.inv(gt[-1]) @ est[-1]
    rel_e = np.linalg.inv(est[:-1]) @ est[1:]
    rel_g = np.linalg.inv(gt[:-1]) @ gt[1:]
    d = np.linalg.inv(rel_g) @ rel_e
    return {
        "path_m": path,
        "end_translation_pct": 100.0 * float(np.linalg.norm(end[:3, 3])) / max(path, 1e-12),
        "end_rotation_deg_per_m": _angle(end[:3, :3]) / max(path, 1e-12),
        "rpe_translation_pct": 100.0
        * float(np.linalg.norm(d[:, :3, 3], axis=1).mean())
        / max(float(steps.mean()), 1e-12),
        "rpe_rotation_deg": float(np.mean([_angle(x[:3, :3]) for x in d])),
        "max_position_error_m": float(np.linalg.norm(est[:, :3, 3] - gt[:, :3, 3], axis=1).max()),
    }
