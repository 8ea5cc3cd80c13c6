"""What accumulating past scans costs MOST: voxels and forward time against k = 1, same run.

For each k, the current scan of a synthetic HDL-64 sequence plus k − 1 past scans (aligned, the
relative time as the tenth feature) goes through an untrained ``tiny`` MOST network (the cost does
not depend on the weights); median of ``--repeats`` forward passes on one thread, as a ratio to
k = 1 measured in the same run.

Run: ``OMP_NUM_THREADS=1 .venv/bin/python bench/bench_most_scans.py [--scans 1,2,3,4,6,10]
[--repeats 3] --out DIR`` (writes ``DIR/bench_most_scans.md``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.model.cylinder import voxelize
from dsnet_core.most.config import MostConfig
from dsnet_core.most.data import frame_times, read_window, window
from dsnet_core.most.network import MostNet
from dsnet_core.synth import generate_log


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", default="1,2,3,4,6,10")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None, help="output folder (default: a new temporary folder)")
    args = ap.parse_args()
    args.out = args.out or Path(tempfile.mkdtemp(prefix="bench-most-scans-"))
    torch.set_num_threads(1)
    ks = [int(k) for k in args.scans.split(",")]
    log = args.out / "log"
    if not (log / "sequences" / "00").is_dir():
        generate_log(log, sequences=1, frames=max(ks), seed=7)
    reader = SemanticKittiReader(log)
    frames = reader.frames("00")
    torch.manual_seed(0)
    net = MostNet(MostConfig()).eval()
    rows = []
    for k in ks:
        refs = window(frames, len(frames) - 1, k)
        cloud, _ = read_window(reader, refs, frame_times(reader, refs))
        pts = torch.from_numpy(cloud)
        n_vox = voxelize([pts[:, :4]], net.config.backbone.grid).coords.shape[0]
        times = []
        with torch.inference_mode():
            net([pts])  # warm-up
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                net([pts])
                times.append(time.perf_counter() - t0)
        rows.append((k, len(cloud), n_vox, statistics.median(times)))
        print(rows[-1], flush=True)
    base = rows[0]
    lines = [
        "| k | points | voxels | voxels / k=1 | forward s | time / k=1 |",
        "|---|---|---|---|---|---|",
    ]
    for k, n, v, t in rows:
        lines.append(f"| {k} | {n} | {v} | {v / base[2]:.2f} | {t:.2f} | {t / base[3]:.2f} |")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_most_scans.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"wrote {args.out / 'bench_most_scans.md'}")


if __name__ == "__main__":
    main()
