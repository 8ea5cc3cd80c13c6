"""Sensor estimation against a real or foreign log: estimate the card, render a log ``--like`` it
(the same number of scans), and print the earth mover's distance of the elevation histogram and
of the points-per-range curve, with both curves as a text table (docs/sensor.md). The log's scans
are compared in the sensor's frame (moved by the card's ``origin``: a log in a vehicle frame,
PandaSet's, is otherwise seen from the wrong point); ``--log-frame`` compares them as stored.

    python bench/bench_sensor.py LOG OUT [--frames N] [--curves]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from dsnet_core.io.formats import open_log
from dsnet_core.sensor import estimate_sensor
from dsnet_core.sensor.card import SensorOrigin
from dsnet_core.sensor.compare import emd, log_curves
from dsnet_core.sensor.origin import to_sensor_frame
from dsnet_core.synth import generate_log


def _scans(root: Path, frames: int, origin: SensorOrigin | None = None) -> list[np.ndarray]:
    reader = open_log(root)
    refs = [f for s in reader.sequences() for f in reader.frames(s)][:frames]
    scans = [reader.scan(f) for f in refs]
    if origin is None:
        return scans
    out = []
    for scan in scans:
        xyz = np.asarray(scan[:, :3], dtype=np.float64)
        keep = np.linalg.norm(xyz, axis=1) > 1e-3
        out.append(to_sensor_frame(xyz[keep], origin))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("log", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--curves", action="store_true")
    ap.add_argument("--log-frame", action="store_true", help="compare the log's scans as stored")
    args = ap.parse_args()
    t = time.perf_counter()
    est = estimate_sensor(open_log(args.log), args.log)
    took = time.perf_counter() - t
    card = est.card
    print(
        f"estimate ({est.frames_used} scans, {took:.1f} s): {card.beams} beams "
        f"{card.elevations_deg[0]:+.2f}..{card.elevations_deg[-1]:+.2f}°, {card.azimuth_steps} steps, "
        f"FOV {card.fov_deg:.0f}°, centre {card.origin.xyz_m} m roll {card.origin.roll_deg:+.2f}° "
        f"pitch {card.origin.pitch_deg:+.2f}°, height {card.mount_height_m:.3f} m, "
        f"drop {100 * card.ray_drop.rate:.2f} %, "
        f"noise {100 * card.range_noise_m:.2f} cm, {card.min_range_m:.2f}-{card.max_range_m:.1f} m, "
        f"{card.returns_per_scan:.0f} points/scan; not estimated: {card.not_estimated or 'nothing'}"
    )
    generate_log(args.out, sequences=1, frames=args.frames, seed=0, sensor_card=card, overwrite=True)
    origin = None if args.log_frame else card.origin
    real, like = log_curves(_scans(args.log, args.frames, origin)), log_curves(_scans(args.out, args.frames))
    print(f"EMD elevation histogram: {emd(real.elevation, like.elevation, 0.1):.3f}°")
    print(
        f"EMD points-per-range curve: {emd(real.per_range, like.per_range, 1.0):.2f} m; points per scan "
        f"{real.per_range.sum():.0f} real vs {like.per_range.sum():.0f} --like"
    )
    if args.curves:
        print("elevation (2° bins, % of points): deg real like")
        for k in range(0, real.elevation.size, 20):
            a, b = real.elevation[k : k + 20].sum(), like.elevation[k : k + 20].sum()
            if a + b > 0:
                print(f"{real.el_centres[k] - 0.05:+6.1f} {100 * a:6.2f} {100 * b:6.2f}")
        print("points per scan by range (10 m bins): m real like")
        for k in range(0, real.per_range.size, 10):
            print(f"{k:4d} {real.per_range[k : k + 10].sum():8.0f} {like.per_range[k : k + 10].sum():8.0f}")


if __name__ == "__main__":
    main()
