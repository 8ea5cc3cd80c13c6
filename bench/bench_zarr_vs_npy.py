"""Store write throughput of per-point arrays: zarr (padded, one chunk per item, zstd 3) vs raw .npy.

Writes the align contract's arrays (points f32×4, source_frame i32, source_index i32, labels u32)
for N volumes of P points, once through StageArrays.write_item (with n_points and done flags) and
once as one ``.npy`` file per array and item; reports MB/s of raw array bytes and the ratio.

    .venv/bin/python bench/bench_zarr_vs_npy.py [--items 50] [--points 240000]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dsnet_core.temporal.align import build_volume
from storage.run import RunStore
from tests.logs import pose


def volumes(n_items: int, n_points: int):
    rng = np.random.default_rng(0)
    half = n_points // 2
    for i in range(n_items):
        scans = [
            np.c_[rng.normal(0, 15, (half, 3)), rng.uniform(0, 1, half)].astype(np.float32) for _ in range(2)
        ]
        labels = [rng.choice([40, 10 | (1 << 16), 50], half).astype(np.uint32) for _ in range(2)]
        v = build_volume(scans, [pose(i), pose(i + 1)], [i, i + 1], labels)
        yield {
            "points": v.points,
            "source_frame": v.source_frame,
            "source_index": v.source_index,
            "labels": v.labels,
        }


def du(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--items", type=int, default=50)
    ap.add_argument("--points", type=int, default=240_000)
    args = ap.parse_args()
    data = list(volumes(args.items, args.points))
    nbytes = sum(a.nbytes for d in data for a in d.values())
    tmp = Path(tempfile.mkdtemp(prefix="dsnet-bench-zarr-"))

    store = RunStore(tmp / "zarr")
    t = time.perf_counter()
    arrays = store.create_arrays("00", "align", args.items, args.points)
    for i, d in enumerate(data):
        arrays.write_item(i, d, len(d["points"]))
    t_zarr = time.perf_counter() - t

    npy = tmp / "npy"
    npy.mkdir()
    t = time.perf_counter()
    for i, d in enumerate(data):
        for name, a in d.items():
            np.save(npy / f"{name}-{i:05d}.npy", a)
    os.sync()
    t_npy = time.perf_counter() - t

    mb = nbytes / 1e6
    print(f"{args.items} volumes x {args.points} points, {mb:.0f} MB of arrays")
    print(f"zarr  {t_zarr:7.2f} s  {mb / t_zarr:7.1f} MB/s  on disk {du(tmp / 'zarr') / 1e6:7.1f} MB")
    print(f"npy   {t_npy:7.2f} s  {mb / t_npy:7.1f} MB/s  on disk {du(npy) / 1e6:7.1f} MB")
    print(f"ratio zarr/npy write time: x{t_zarr / t_npy:.2f}")


if __name__ == "__main__":
    main()
