"""A copy of a SemanticKITTI-layout log turned by one global yaw: every scan rotated about the
sensor's z axis, the LiDAR poses compensated (``P' = P Rᵀ``) so the world is unchanged, labels,
calib and times copied. The rotation-robustness rows of the method benchmarks label it."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np


def yaw_matrix(deg: float) -> np.ndarray:
    """float64 ``(4, 4)`` rotation by ``deg`` degrees about z."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    r = np.eye(4)
    r[:2, :2] = [[c, -s], [s, c]]
    return r


def rotate_log(src: Path, dst: Path, deg: float) -> Path:
    """Write the log at ``src`` turned by ``deg`` degrees to ``dst`` (skipped when already there)."""
    from dsnet_core.io import kitti
    from dsnet_core.io.semantickitti import SemanticKittiReader

    stamp = dst / "rotated.json"
    want = {"source": str(Path(src).resolve()), "yaw_deg": deg}
    if stamp.exists() and json.loads(stamp.read_text()) == want:
        return dst
    reader = SemanticKittiReader(src)
    rot = yaw_matrix(deg)
    for seq in reader.sequences():
        out = dst / "sequences" / seq
        shutil.rmtree(out, ignore_errors=True)
        (out / "velodyne").mkdir(parents=True)
        (out / "labels").mkdir()
        for ref in reader.frames(seq):
            scan = reader.scan(ref).copy()
            scan[:, :3] = (scan[:, :3].astype(np.float64) @ rot[:3, :3].T).astype(np.float32)
            kitti.write_scan(out / "velodyne" / ref.scan_path.name, scan)
            if ref.label_path is not None:
                shutil.copyfile(ref.label_path, out / "labels" / ref.label_path.name)
        seq_dir = reader.seq_dir(seq)
        tr = kitti.read_calib(seq_dir / "calib.txt")
        poses = reader.poses(seq)
        if poses is not None:
            kitti.write_poses(out / "poses.txt", kitti.lidar_to_camera_poses(poses @ rot.T, tr))
        for name in ("calib.txt", "times.txt"):
            if (seq_dir / name).is_file():
                shutil.copyfile(seq_dir / name, out / name)
    stamp.write_text(json.dumps(want) + "\n")
    return dst
