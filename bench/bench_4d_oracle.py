"""4D volumes + stitching vs single-scan clustering + the tracking baseline, on oracle inputs.

Ground-truth semantics and noisy ground-truth centres (``dsnet_core.oracle.inputs`` noise model) over
synthetic sequences with moving objects; the same BFS clusterer and fusion for every row:

- ``k=1 + tracking``: per scan → cluster → fuse → ego-compensated constant-velocity tracker;
- ``k=1 (no ids across frames)``: the same without tracking (every frame fresh ids), a floor;
- ``k=2/3/4``: k-scan volumes (stride k-1, one shared frame) → cluster → fuse → stitch.

Prints LSTQ, S_assoc, S_cls (``corrected`` mode), PQ and identity switches along ground-truth
tubes over all sequences, and the time per frame of the instance stage, of stitching and of
tracking (the speed ratio stitching/frame is the number to watch, not absolute times).

Run: ``.venv/bin/python bench/bench_4d_oracle.py [--frames 40] [--seeds 0 1 2] [--sensor vlp32]``.
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
from dsnet_core.labels import load_label_map
from dsnet_core.metrics import PanopticEvaluator
from dsnet_core.metrics.switches import SwitchCounter
from dsnet_core.oracle.labelling import oracle_volumes, stitch_sequence, track_sequence
from dsnet_core.synth import generate_log

LM = load_label_map("semantic-kitti")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--sensor", default="vlp32")
    ap.add_argument("--noise", type=float, default=1.0, help="scale of the centre-regression noise")
    args = ap.parse_args()

    rows = ["k=1 + tracking", "k=1 (no ids across frames)", "k=2", "k=3", "k=4"]
    evals = {r: PanopticEvaluator(LM, mode="corrected") for r in rows}
    switches = {r: SwitchCounter(LM) for r in rows}
    times = {r: [0.0, 0.0] for r in rows}  # instance stage, stitch/track
    n_frames = 0
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            seq = f"{seed:02d}"
            generate_log(
                Path(tmp), sequences=1, frames=args.frames, seed=seed, sensor=args.sensor, first_sequence=seed
            )
            reader = SemanticKittiReader(Path(tmp))
            frames = reader.frames(seq)
            scans = [reader.scan(f) for f in frames]
            gts = [reader.labels(f) for f in frames]
            poses = np.stack([reader.pose(f) for f in frames])
            n_frames += len(frames)
            for row in rows:
                t0 = time.perf_counter()
                k = 1 if row.startswith("k=1") else int(row[2])
                vols = oracle_volumes(scans, gts, poses, LM, k, noise_scale=args.noise)
                t1 = time.perf_counter()
                if row == "k=1 + tracking":
                    preds = track_sequence(vols, scans, poses, LM)
                else:
                    preds = stitch_sequence(vols, LM)
                t2 = time.perf_counter()
                times[row][0] += t1 - t0
                times[row][1] += t2 - t1
                for f, (gt, pred) in enumerate(zip(gts, preds, strict=True)):
                    evals[row].add(gt, pred, frame=f"{f:06d}", sequence=seq)
                    switches[row].add(gt, pred, sequence=seq)
            print(f"sequence {seq}: {len(frames)} frames, {np.mean([len(s) for s in scans]):.0f} points/scan")

    print(
        f"\n{len(args.seeds)} sequences × {args.frames} frames ({args.sensor}), "
        f"noise ×{args.noise}, corrected mode"
    )
    print(
        f"{'method':28s} {'LSTQ':>7s} {'S_assoc':>8s} {'S_cls':>7s} {'PQ':>7s} {'PQ_th':>7s} {'tubes':>6s}"
        f" {'id sw':>6s} {'inst ms/f':>10s} {'ids ms/f':>9s}"
    )
    for row in rows:
        res = evals[row].result()
        t = [1000 * x / n_frames for x in times[row]]
        print(
            f"{row:28s} {res.lstq.lstq:7.4f} {res.lstq.s_assoc:8.4f} {res.lstq.s_cls:7.4f} "
            f"{res.panoptic.pq:7.4f} {res.panoptic.pq_things:7.4f} {res.lstq.n_tubes:6d} "
            f"{switches[row].switches:6d} {t[0]:10.1f} {t[1]:9.2f}"
        )
    print("inst ms/f: align + oracle centres + clustering + fusion; ids ms/f: stitching or tracking")
    print("id sw: identity switches along ground-truth tubes (dsnet_core.metrics.switches)")


if __name__ == "__main__":
    main()
