"""KISS-ICP poses for synthetic logs whose poses are withheld: drift against the true trajectory.

For each seed and sensor: generate a sequence, estimate LiDAR-frame poses from the scans alone
(``dsnet_core.temporal.odometry.estimate_poses``), and compare with the generator's poses: end-point
translation drift (% of path), heading drift (deg/m), mean frame-to-frame errors and the worst
position error; plus the odometry time per scan next to the time to read a scan from disk.

Run: ``.venv/bin/python bench/bench_odometry.py [--frames 50] [--seeds 0 1 2] [--sensors vlp32 hdl64]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.synth import generate_log
from dsnet_core.temporal.odometry import estimate_poses, trajectory_drift


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--sensors", nargs="+", default=["vlp32", "hdl64"])
    args = ap.parse_args()
    print(
        f"{'sensor':7s} {'seed':>4s} {'path m':>7s} {'end t %':>8s} {'end r deg/m':>12s} {'rpe t %':>8s}"
        f" {'rpe r deg':>10s} {'max err m':>10s} {'icp ms/scan':>12s} {'read ms/scan':>13s}"
    )
    summary: dict[str, list[float]] = {}
    for sensor in args.sensors:
        for seed in args.seeds:
            with tempfile.TemporaryDirectory() as tmp:
                generate_log(Path(tmp), sequences=1, frames=args.frames, seed=seed, sensor=sensor)
                reader = SemanticKittiReader(Path(tmp))
                frames = reader.frames("00")
                t0 = time.perf_counter()
                scans = [reader.scan(f) for f in frames]
                t1 = time.perf_counter()
                truth = np.stack([reader.pose(f) for f in frames])
            est = estimate_poses(scans)
            t2 = time.perf_counter()
            d = trajectory_drift(est, truth)
            summary.setdefault(sensor, []).append(d["end_translation_pct"])
            print(
                f"{sensor:7s} {seed:4d} {d['path_m']:7.1f} {d['end_translation_pct']:8.2f}"
                f" {d['end_rotation_deg_per_m']:12.4f} {d['rpe_translation_pct']:8.2f}"
                f" {d['rpe_rotation_deg']:10.3f} {d['max_position_error_m']:10.3f}"
                f" {1000 * (t2 - t1) / len(frames):12.1f} {1000 * (t1 - t0) / len(frames):13.2f}"
            )
    for sensor, v in summary.items():
        print(f"{sensor}: mean end-point translation drift {np.mean(v):.2f} % over {len(v)} sequences")


if __name__ == "__main__":
    main()
