"""Stage ``ingest`` with ``estimate_poses`` on synthetic logs whose poses are withheld.

Per sensor and seed: the ingest time per frame with KISS-ICP pose estimation next to a plain ingest
of the same log (with its poses) in the same run, and the estimated trajectory's drift against the
generator's poses (read from the frame table, as the pipeline stores them).

Run: ``.venv/bin/python bench/bench_ingest_poses.py [--frames 50] [--seeds 0 1 2] [--sensors vlp32 hdl64]``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.synth import generate_log
from dsnet_core.temporal.odometry import trajectory_drift
from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.helpers.plain_runner import run_stage_plain

P = get_pipeline()  # the DS-Net stages


def _ingest(log: Path, store_root: Path, estimate: bool) -> tuple[float, np.ndarray | None]:
    store = RunStore(store_root)
    run = {"data": str(log), "stages": {"ingest": {"estimate_poses": estimate}}}
    store.write_run_config("bench", run)
    t0 = time.perf_counter()
    run_stage_plain(store, P, "00", "ingest", run, "bench")
    seconds = time.perf_counter() - t0
    poses = store.read_table("00", P["ingest"].table("frames"))["pose"].to_pylist()
    return seconds, None if poses[0] is None else np.reshape(poses, (-1, 4, 4))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--sensors", nargs="+", default=["vlp32", "hdl64"])
    args = ap.parse_args()
    print(
        f"{'sensor':7s} {'seed':>4s} {'path m':>7s} {'end t %':>8s} {'end r deg/m':>12s} {'max err m':>10s}"
        f" {'plain s/frame':>14s} {'estimate s/frame':>17s} {'ratio':>6s}"
    )
    for sensor in args.sensors:
        for seed in args.seeds:
            tmp = Path(tempfile.mkdtemp(prefix="bench-ingest-poses-"))
            try:
                generate_log(tmp / "full", sequences=1, frames=args.frames, seed=seed, sensor=sensor)
                reader = SemanticKittiReader(tmp / "full")
                truth = np.stack([reader.pose(f) for f in reader.frames("00")])
                shutil.copytree(tmp / "full", tmp / "withheld")
                for name in ("poses.txt", "calib.txt"):
                    (tmp / "withheld" / "sequences" / "00" / name).unlink()
                plain, _ = _ingest(tmp / "full", tmp / "run-plain", False)
                est_s, est = _ingest(tmp / "withheld", tmp / "run-est", True)
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
            d = trajectory_drift(est, truth)
            n = args.frames
            print(
                f"{sensor:7s} {seed:4d} {d['path_m']:7.1f} {d['end_translation_pct']:8.2f}"
                f" {d['end_rotation_deg_per_m']:12.4f} {d['max_position_error_m']:10.3f}"
                f" {plain / n:14.4f} {est_s / n:17.4f} {est_s / plain:6.1f}"
            )


if __name__ == "__main__":
    main()
