"""Read throughput of every input format (points/s) next to the label stages' speed, same run.

Generates a 64-beam (hdl64) synthetic log, re-encodes it in every format the readers take
(with the test fixtures' independent writers: numpy, pypcd4, plyfile, laspy, rosbags, nuScenes
tables), and times a fresh reader over every frame: ``scan`` + ``pose`` + ``timestamp`` (+
``labels`` where the format has them), tables/index parsing included; best of ``--rounds``.
The label stages (ingest → align → infer → shift → fuse → stitch, k = 1, the ``tiny`` preset
with random weights, one torch thread) run on the same log through the plain runner, and each
format's throughput is printed as a multiple of theirs. Reading must be at least 10× faster so
that it is never the bottleneck; the script exits 1 otherwise.

Run: ``.venv/bin/python bench/bench_readers.py [--frames 5] [--rounds 2]``
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch

STAGES = ("ingest", "align", "infer", "shift", "fuse", "stitch")
MIN_RATIO = 10.0


def label_points_per_s(log: Path, tmp: Path) -> tuple[float, int]:
    """Points per second of the whole label pipeline (k = 1) on sequence 00, and its point count."""
    from bench.bench_label import random_tiny_checkpoint
    from storage.run import RunStore
    from tasks.methods import get_pipeline
    from tests.helpers.plain_runner import run_stage_plain

    pipeline = get_pipeline()  # the DS-Net stages

    ckpt = random_tiny_checkpoint(tmp / "tiny-random")
    store = RunStore(tmp / "run")
    run = {"data": str(log), "stages": {"align": {"scans": 1}, "infer": {"checkpoint": str(ckpt)}}}
    store.write_run_config("bench", run)
    t0 = time.perf_counter()
    for stage in STAGES:
        run_stage_plain(store, pipeline, "00", stage, run, "bench")
    seconds = time.perf_counter() - t0
    points = store.read_manifest("00", "ingest").counts["points"]
    return points / seconds, points


def encode_all(log: Path, out: Path) -> dict[str, tuple[Path, dict]]:
    """Every format of the log's sequence 00: name -> (root, reader options)."""
    from dsnet_core.io.semantickitti import SemanticKittiReader
    from tests.dsnet_core.io import encode

    ref = SemanticKittiReader(log)
    roots: dict[str, tuple[Path, dict]] = {"semantickitti": (log, {})}
    writers = {
        "bin (4 col)": lambda p: encode.write_bin(ref, p, labels=True),
        "bin (5 col)": lambda p: encode.write_bin(ref, p, columns=5),
        "npy": lambda p: encode.write_numpy(ref, p, "npy"),
        "npz": lambda p: encode.write_numpy(ref, p, "npz"),
        "pcd ascii": lambda p: encode.write_pcd(ref, p, "ascii"),
        "pcd binary": lambda p: encode.write_pcd(ref, p, "binary"),
        "pcd binary_compressed": lambda p: encode.write_pcd(ref, p, "binary_compressed"),
        "ply binary": lambda p: encode.write_ply(ref, p),
        "ply ascii": lambda p: encode.write_ply(ref, p, text=True),
        "las": lambda p: encode.write_las(ref, p, 0.001),
        "laz": lambda p: encode.write_las(ref, p, 0.001, laz=True),
        "rosbag mcap": lambda p: encode.write_bag(ref, p, "mcap"),
        "rosbag sqlite3": lambda p: encode.write_bag(ref, p, "sqlite3"),
    }
    for i, (name, write) in enumerate(writers.items()):
        roots[name] = (write(out / f"f{i:02d}"), {})
    encode.write_nuscenes(ref, out / "nuscenes")
    roots["nuscenes (keyframes)"] = (out / "nuscenes", {})
    return roots


def read_points_per_s(root: Path, options: dict, rounds: int) -> tuple[float, str]:
    """Best points/s over ``rounds`` fresh readers reading every frame; and the format name."""
    from dsnet_core.io.formats import open_log

    best, name = 0.0, ""
    for _ in range(rounds):
        t0 = time.perf_counter()
        reader = open_log(root, "auto", options)
        points = 0
        for seq in reader.sequences():
            for f in reader.frames(seq):
                points += len(reader.scan(f))
                reader.pose(f), reader.timestamp(f), reader.labels(f)
        best = max(best, points / (time.perf_counter() - t0))
        name = reader.format
    return best, name


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(1)

    from dsnet_core.synth import generate_log

    tmp = Path(tempfile.mkdtemp(prefix="bench-readers-"))
    log = tmp / "log"
    generate_log(log, sequences=1, frames=args.frames, seed=0, sensor="hdl64")
    label_rate, points = label_points_per_s(log, tmp)
    print(f"{args.frames} hdl64 frames, {points / args.frames:.0f} points per frame")
    print(f"label stages (k = 1, tiny, 1 thread): {label_rate / 1e3:.1f} k points/s")
    print(f"{'input':<24}{'format':<15}{'M points/s':>11}{'× label':>9}")
    failed = []
    for name, (root, options) in encode_all(log, tmp / "formats").items():
        rate, fmt = read_points_per_s(root, options, args.rounds)
        ratio = rate / label_rate
        print(f"{name:<24}{fmt:<15}{rate / 1e6:>11.2f}{ratio:>9.0f}")
        if ratio < MIN_RATIO:
            failed.append(name)
    if failed:
        print(f"FAIL: reading slower than {MIN_RATIO:.0f}× the label stages: {', '.join(failed)}")
        sys.exit(1)
    print(f"ok: every format reads at least {MIN_RATIO:.0f}× faster than the label stages")


if __name__ == "__main__":
    main()
